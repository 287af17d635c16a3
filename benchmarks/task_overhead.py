"""What a chunk task costs beyond its points: dask's part, and storing the chunk.

    python benchmarks/task_overhead.py [--tasks 300] [--workers 2] [--sizes 32,96] [--out DIR]

Two measurements, which together set the runner's ``DEFAULT_CHUNK_SIZE``:

1. **dask**: ``--tasks`` chunk tasks of one point each (a point that is linear at once, well
   under a millisecond) on the embedded cluster the runner makes (``make_client``), at most 8
   in flight, as the runner keeps them. Reported: the CPU per task of this process (scheduler,
   nannies, client: ``getrusage``) and of the workers (``time.process_time`` in each, before
   and after).
2. **storing**: ``StudyRun.finished`` (the chunk file, written and fsynced, and the points and
   links in a SQLite point store) for chunks of each of ``--sizes`` points, with real records
   of ``studies/paper-fig5-gaps.yaml`` computed here. Reported: CPU and wall per chunk.

Writes ``task_overhead.md`` to ``--out`` (default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.point_engine import write_results  # noqa: E402
from service.api.catalogue import Catalogue  # noqa: E402
from service.api.points import SqlPointStore  # noqa: E402
from service.studies.runner import StudyRun, make_client  # noqa: E402
from service.studies.schema import Study, load_study  # noqa: E402
from service.studies.tasks import chunk_task  # noqa: E402
from worker.simulate import simulate_chunk  # noqa: E402

# no stop within reach: the point is proven linear before its first period
CHEAP_POINT = {"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, "gamma_r": 1.3, "g1": 1e6, "g2": 1e6}
IN_FLIGHT = 8


def _own_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def dask_cost(tasks: int, workers: int) -> dict[str, float]:
    """CPU per task (ms) of this process and of the workers, and the wall time (s)."""
    client, cluster = make_client(None, workers)
    try:
        event = "impactcell-task-overhead"  # never set: the tasks' cancel probe finds it clear

        def submit():
            return client.submit(chunk_task, [CHEAP_POINT], {}, {}, event, False, pure=False)

        client.gather([submit() for _ in range(2 * workers)])  # kernels loaded, imports done
        w0 = sum(client.run(time.process_time).values())
        c0 = _own_cpu()
        t0 = time.perf_counter()
        futures = []
        for _ in range(tasks):
            futures.append(submit())
            if len(futures) >= IN_FLIGHT:
                futures.pop(0).result()
        client.gather(futures)
        wall = time.perf_counter() - t0
        own = _own_cpu() - c0
        w1 = sum(client.run(time.process_time).values())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return {"own_ms": 1e3 * own / tasks, "workers_ms": 1e3 * (w1 - w0) / tasks, "wall_s": wall}


def store_cost(study: Study, sizes: list[int], chunks: int, tmp: Path) -> list[dict[str, float]]:
    """CPU and wall (ms) per ``StudyRun.finished`` call, for chunks of each size (at most the
    study's points)."""
    records = simulate_chunk(study.points(0, max(sizes)), study.solver.settings().__dict__, {})
    out = []
    for size in sizes:
        cat = Catalogue(f"sqlite:///{tmp / f'store-{size}.db'}")
        try:
            run = StudyRun(study, tmp / f"data-{size}", points=SqlPointStore(cat.engine))
            cpu = wall = 0.0
            n = min(chunks, study.size // size)
            for i in range(n):
                start = i * size
                recs = [dict(r) for r in records[:size]]
                c0, t0 = time.process_time(), time.perf_counter()
                run.finished(start, start + size, recs, False)
                cpu += time.process_time() - c0
                wall += time.perf_counter() - t0
        finally:
            cat.close()
        out.append({"size": size, "cpu_ms": 1e3 * cpu / n, "wall_ms": 1e3 * wall / n})
    return out


def main(argv: list[str] | None = None) -> int:
    """Run both measurements and print/save the tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", type=int, default=300, help="tasks to time (default 300)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--sizes", default="32,96", help="chunk sizes to store (default 32,96)")
    ap.add_argument("--chunks", type=int, default=30, help="chunks stored per size (default 30)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",")]
    except ValueError:
        ap.error(f"--sizes must be comma-separated integers, got {args.sizes!r}")
    for name in ("tasks", "workers", "chunks"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    study = load_study(ROOT / "studies" / "paper-fig5-gaps.yaml")
    if not all(1 <= n <= study.size for n in sizes):
        ap.error(
            f"--sizes must all be from 1 to {study.size} (Figure 5's points), got {args.sizes!r}"
        )
    d = dask_cost(args.tasks, args.workers)
    with tempfile.TemporaryDirectory(prefix="impactcell-store-") as tmp:
        s = store_cost(study, sizes, args.chunks, Path(tmp))
    lines = [
        f"What a chunk task costs beyond its points ({platform.machine()}, Python "
        f"{platform.python_version()}, {args.workers} worker processes).",
        "",
        f"dask, {args.tasks} tasks of one point (≤ {IN_FLIGHT} in flight): "
        f"**{d['own_ms']:.1f} ms** of CPU per task in the command's process and "
        f"**{d['workers_ms']:.1f} ms** in the workers ({d['wall_s']:.2f} s of wall in all).",
        "",
        "| chunk size | store CPU ms/chunk | store wall ms/chunk | CPU ms/point |",
        "|---|---|---|---|",
        *(
            f"| {r['size']} | {r['cpu_ms']:.1f} | {r['wall_ms']:.1f} | "
            f"{r['cpu_ms'] / r['size']:.3f} |"
            for r in s
        ),
        "",
        "Storing: `StudyRun.finished` (chunk file with fsync, points and links in a SQLite point "
        f"store), {args.chunks} chunks per size of real Figure-5 records.",
        "",
        f"Generated by `python benchmarks/task_overhead.py --tasks {args.tasks} --workers "
        f"{args.workers} --sizes {args.sizes} --chunks {args.chunks}`.",
    ]
    write_results(args.out, "task_overhead", lines, [])
    return 0


if __name__ == "__main__":
    sys.exit(main())
