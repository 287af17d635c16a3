"""The point store at scale: storing, assembling and querying a 1M-point study, and what storing
adds to a real study's run time.

    python benchmarks/point_store.py [--points 1000000] [--database URL ...] [--end-to-end]

Two measurements:

1. **Scale** (per database: SQLite in a temporary folder, and every ``--database`` URL, e.g. a
   PostgreSQL server): a study of ``--points`` points (γ_r × gap × θ × σ) whose records are real
   worker records (a few hundred points computed here, cycled over the grid; each stored point
   has its own key and parameters). It times

   * *store*: what the runner does when a chunk finishes (``StudyRun.finished``: the points'
     rows and the study's links, one transaction per chunk of the runner's ``DEFAULT_CHUNK_SIZE``
     points), for the whole study;
   * *assemble*: a renamed copy of the study taken whole from the store (``StudyRun``: keys,
     lookups, the chunk files) and collated into its NetCDF file (``collate``);
   * *query*: ``GET /points``' query for θ = …, gap = …, γ_r in a range (a selective question:
     one line of the grid), and for one σ over everything (10 % of the points, first page).

2. **End to end** (``--end-to-end``): ``studies/paper-fig5-gaps.yaml`` on the embedded cluster
   (one worker per core) with and without the point store (SQLite), and again renamed (every
   point from the store). The storing overhead is the difference of the first two.

Writes ``point_store.json`` to ``--out`` (default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from service.api.catalogue import Catalogue  # noqa: E402
from service.api.points import PointQuery, SqlPointStore  # noqa: E402
from service.studies.runner import DEFAULT_CHUNK_SIZE, StudyRun, run_study  # noqa: E402
from service.studies.schema import Study, load_study  # noqa: E402
from worker.simulate import simulate_chunk  # noqa: E402


def grid_study(points: int, name: str) -> Study:
    """γ_r (n) × 10 gaps × 10 θ × 10 σ, n = points / 1000."""
    n = max(1, points // 1000)
    return Study.model_validate({
        "name": name,
        "grid": {
            "gamma_r": {"start": 0.2, "stop": 6.0, "num": n},
            "gap": {"start": 0.1, "stop": 1.0, "num": 10},
            "theta": {"start": 0.1, "stop": 1.0, "num": 10},
            "sigma": {"start": 0.01, "stop": 0.1, "num": 10},
            "gamma_s": 1.0,
        },
    })  # fmt: skip


def real_records(study: Study, n: int = 200) -> list[dict[str, Any]]:
    """``n`` records computed here from points spread over the study."""
    step = max(1, study.size // n)
    pts = [study.points(i, i + 1)[0] for i in range(0, study.size, step)][:n]
    return simulate_chunk(pts, study.solver.settings().__dict__, {})


def scale(url: str, label: str, points: int, tmp: Path) -> dict[str, Any]:
    """Store, assemble and query a ``points``-point study on the catalogue at ``url``."""
    cat = Catalogue(url)
    store = SqlPointStore(cat.engine)
    study = grid_study(points, f"store-{points}")
    records = real_records(study)
    cycle = itertools.cycle(records)
    root = tmp / label
    run = StudyRun(study, root, points=store)
    t_keys = time.perf_counter()
    run.keys(0, min(study.size, 100_000))
    keys_per_point = (time.perf_counter() - t_keys) / min(study.size, 100_000)

    # 1. what the runner does per finished chunk: the store's part of StudyRun.finished
    t_store = 0.0
    for start in range(0, study.size, DEFAULT_CHUNK_SIZE):
        stop = min(start + DEFAULT_CHUNK_SIZE, study.size)
        recs = [dict(next(cycle)) for _ in range(stop - start)]
        keys = run.keys(start, stop)
        pts = study.points(start, stop)
        t0 = time.perf_counter()
        store.save(
            list(zip(keys, pts, recs, strict=True)),
            run._solver_doc,
            link=(study.id, list(enumerate(keys, start=start))),
        )
        t_store += time.perf_counter() - t0
    n_stored = store.count()

    # 2. a renamed copy, whole from the store, and its NetCDF file
    copy = Study.model_validate({**study.canonical(), "name": f"{study.name} renamed"})
    t0 = time.perf_counter()
    again = StudyRun(copy, root, points=store)
    t_take = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = again.collate(0)
    t_collate = time.perf_counter() - t0

    # 3. queries
    def timed(q: PointQuery) -> tuple[float, int]:
        best = float("inf")
        n = 0
        for _ in range(3):
            t = time.perf_counter()
            rows, _ = store.query(q)
            best = min(best, time.perf_counter() - t)
            n = len(rows)
        return best, n

    sel_s, sel_n = timed(
        PointQuery(values={"theta": 0.3, "gap": 0.2}, ranges={"gamma_r": (1.0, 2.0)}, limit=10_000)
    )
    wide_s, wide_n = timed(PointQuery(values={"sigma": 0.05}, limit=10_000))
    cat.close()
    return {
        "database": label,
        "points": study.size,
        "stored": n_stored,
        "store_s": round(t_store, 2),
        "store_ms_per_point": round(1e3 * t_store / study.size, 4),
        "key_us_per_point": round(1e6 * keys_per_point, 2),
        "assemble_take_from_store_s": round(t_take, 2),
        "assemble_collate_s": round(t_collate, 2),
        "assembled_computed": summary.computed,
        "assembled_reused": summary.reused,
        "query_selective_s": round(sel_s, 4),
        "query_selective_points": sel_n,
        "query_one_sigma_first_page_s": round(wide_s, 4),
        "query_one_sigma_page_points": wide_n,
    }


def end_to_end(tmp: Path, rounds: int = 2) -> dict[str, Any]:
    """paper-fig5-gaps.yaml with and without the point store (alternating, ``rounds`` times
    each, fastest kept: the machine's noise is larger than the difference), then renamed (all
    points from the store)."""
    study = load_study(ROOT / "studies" / "paper-fig5-gaps.yaml")
    out: dict[str, Any] = {"study": "paper-fig5-gaps.yaml", "points": study.size}
    run_study(study, tmp / "warm")  # numba's cache and the OS's file cache, before timing
    plain: list[float] = []
    stored: list[float] = []
    for k in range(rounds):
        t0 = time.perf_counter()
        run_study(study, tmp / f"plain{k}")
        plain.append(time.perf_counter() - t0)
        cat = Catalogue(f"sqlite:///{tmp / f'e2e{k}.sqlite'}")
        t0 = time.perf_counter()
        s = run_study(study, tmp / f"stored{k}", points=SqlPointStore(cat.engine))
        stored.append(time.perf_counter() - t0)
        assert s.computed == study.size
        if k == rounds - 1:
            renamed = Study.model_validate({**study.canonical(), "name": "fig5 renamed"})
            t0 = time.perf_counter()
            r = run_study(renamed, tmp / f"stored{k}", points=SqlPointStore(cat.engine))
            out["renamed_s"] = round(time.perf_counter() - t0, 2)
            out["renamed_computed"] = r.computed
            out["renamed_reused"] = r.reused
        cat.close()
    out["without_store_s"] = [round(t, 2) for t in plain]
    out["with_store_s"] = [round(t, 2) for t in stored]
    out["store_overhead"] = round(min(stored) / min(plain) - 1.0, 4)
    return out


def main() -> None:
    """Run the measurements, print them and write ``point_store.json``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--database", action="append", default=[],
                    help="another catalogue URL (PostgreSQL): its tables are emptied")  # fmt: skip
    ap.add_argument("--no-sqlite", action="store_true", help="skip the SQLite measurement")
    ap.add_argument("--end-to-end", action="store_true", help="also the fig-5 study run")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args()
    result: dict[str, Any] = {"scale": []}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        targets = [] if args.no_sqlite else [(f"sqlite:///{tmp / 'scale.sqlite'}", "sqlite")]
        targets += [(u, u.split(":", 1)[0].split("+")[0]) for u in args.database]
        for url, label in targets:
            if label.startswith("postgresql"):
                _empty(url)
            r = scale(url, label, args.points, tmp)
            print(json.dumps(r), flush=True)
            result["scale"].append(r)
        if args.end_to_end:
            result["end_to_end"] = end_to_end(tmp)
            print(json.dumps(result["end_to_end"]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "point_store.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.update({k: v for k, v in result.items() if v})
    path.write_text(json.dumps(old, indent=1) + "\n")


def _empty(url: str) -> None:
    """Drop the catalogue's tables on a throwaway server (the benchmark's own database)."""
    from sqlalchemy import create_engine, text

    from service.api.catalogue import metadata

    engine = create_engine(url)
    metadata.drop_all(engine)
    with engine.begin() as conn:
        conn.execute(text("DROP TABLE IF EXISTS alembic_version"))
    engine.dispose()


if __name__ == "__main__":
    main()
