"""Are the standard errors of irregular points honest? Re-run them with ten times the budget.

    python benchmarks/irregular_budget.py [--points 40] [--max 25] [--out benchmarks/results]
    python benchmarks/irregular_budget.py --study paper-fig5-gaps [--max 0]
    python benchmarks/irregular_budget.py --study nightly/irregular [--max 0]
    python benchmarks/irregular_budget.py --random 1500 --seed 11 --max 0

The three spectra of ``point_engine.py`` (γ_r 0.3–6) run with the default settings (or, with
``--study``, every point of a shipped grid study with its own settings, or with ``--random N``
N random cells over wide ranges, :func:`random_points`; ``--max 0``: re-run every irregular
point; the files are then named ``irregular_budget_<study>`` or
``irregular_budget_random<seed>``); up to ``--max`` points that end ``irregular`` are run again
with ``max_periods`` ten times the periods the first run used and a standard-error target so
small that the statistics run to that budget. A reported standard error is honest if the
longer run's Γ lies within 3 of them of the first run's Γ (the target: at least 90 % of the
points). A longer run that ends ``linear`` or ``periodic`` shows that the first run saw
transient chaos: it counts as a miss, and the first run's ``reason`` says whether it was
labelled as possibly transient.

Writes ``irregular_budget.md`` and ``irregular_budget.csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.point_engine import SPECTRA, cell, write_results  # noqa: E402
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402


def spectra_points(n: int) -> tuple[list[tuple[str, float, CellParams]], SolverSettings]:
    """The three spectra's points (case, γ_r, cell), n per spectrum, and the default settings."""
    pts = [(case, float(g), cell(case, g)) for case in SPECTRA for g in np.linspace(0.3, 6.0, n)]
    return pts, SolverSettings()


def study_points(name: str) -> tuple[list[tuple[str, float, CellParams]], SolverSettings]:
    """Every point of a shipped grid study (its coordinates but γ_r as the case) and its
    settings; ``nightly/NAME`` names a study of the nightly suite."""
    from service.regression.suite import load_suite
    from service.studies.schema import load_study
    from service.studies.shipped import resolve_study_file

    if name.startswith("nightly/"):
        entries = {e.stem: e for e in load_suite()}
        stem = name.removeprefix("nightly/")
        if stem not in entries:
            raise SystemExit(f"--study {name}: the nightly suite has {', '.join(entries)}")
        study = entries[stem].study
    else:
        study = load_study(resolve_study_file(name))
    grid = study.points(0, study.size, grid=True)
    # the case: the coordinates other than γ_r that vary over the study
    varying = [k for k in grid[0] if k != "gamma_r" and len({str(kw[k]) for kw in grid}) > 1]
    pts = []
    for kw in grid:
        where = ", ".join(f"{k} {kw[k]:g}" for k in varying)
        pts.append((where, float(kw["gamma_r"]), CellParams(**kw)))
    return pts, study.solver.settings()


def random_points(n: int, seed: int) -> list[tuple[str, float, CellParams]]:
    """n random cells (case: their parameters as JSON): θ 0.01–10, σ 0.003–1, γ_s 0.2–5,
    ξ 0.001–0.3, g1 0.001–5 (log-uniform; g2 = g1, or for 30 % g1 times 0.3–3), γ_r 0.2–6,
    1–10 modes, either coupling."""
    rng = np.random.default_rng(seed)

    def log_uniform(a: float, b: float) -> float:
        return float(np.exp(rng.uniform(np.log(a), np.log(b))))

    pts = []
    for _ in range(n):
        g1 = log_uniform(0.001, 5.0)
        g2 = g1 * (log_uniform(0.3, 3.0) if rng.random() < 0.3 else 1.0)
        kw = dict(theta=log_uniform(0.01, 10.0), sigma=log_uniform(0.003, 1.0),
                  gamma_s=log_uniform(0.2, 5.0), xi=log_uniform(0.001, 0.3), g1=g1, g2=g2,
                  gamma_r=log_uniform(0.2, 6.0), coupling=str(rng.choice(["paper", "full"])),
                  modes=int(rng.integers(1, 11)))  # fmt: skip
        pts.append((json.dumps(kw), kw["gamma_r"], CellParams(**kw)))
    return pts


def chosen_points(
    ap: argparse.ArgumentParser, args: argparse.Namespace
) -> tuple[list[tuple[str, float, CellParams]], SolverSettings]:
    """The points ``--random``/``--seed``, ``--study`` or else ``--points`` name, and their
    settings (``ap.error`` for ``--random`` below 0 or with ``--study``)."""
    if args.random < 0 or (args.random and args.study):
        ap.error(f"--random must be 0 (off) or more, and not with --study; got {args.random}")
    if args.random:
        return random_points(args.random, args.seed), SolverSettings()
    if args.study:
        return study_points(args.study)
    return spectra_points(args.points)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=40, help="points per spectrum")
    ap.add_argument("--max", type=int, default=25, help="irregular points to re-run")
    ap.add_argument("--factor", type=int, default=10, help="budget multiple of the re-run")
    ap.add_argument("--study", help="a shipped grid study instead of the three spectra")
    ap.add_argument("--random", type=int, default=0, help="N random cells instead (--seed)")
    ap.add_argument("--seed", type=int, default=4, help="the random cells' seed")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args(argv)
    points, default = chosen_points(ap, args)
    t0 = time.perf_counter()
    warm_up(default.method)
    found = []
    for case, g, p in points:
        r = simulate_point(p, default)
        if r.outcome == "irregular":
            found.append((case, g, p, r))
    picked = found[: args.max] if args.max > 0 else found
    rows = []
    for case, g, p, r in picked:
        longer = dataclasses.replace(default, max_periods=args.factor * r.periods, stat_tol_db=1e-9)
        t1 = time.perf_counter()
        lr = simulate_point(p, longer)
        dt = time.perf_counter() - t1
        diff = None if lr.transmittance_db is None else lr.transmittance_db - r.transmittance_db
        z = None if diff is None else abs(diff) / r.transmittance_db_se
        rows.append(dict(
            case=case, gamma_r=g, db=r.transmittance_db, se=r.transmittance_db_se,
            periods=r.periods, long_outcome=lr.outcome, long_db=lr.transmittance_db,
            long_se=lr.transmittance_db_se, long_periods=lr.periods,
            long_period=lr.response_period, diff_db=diff,
            z=z, within=bool(z is not None and z <= 3.0
                             and lr.outcome in ("irregular", "unsettled")),
            labelled_transient="may be transient" in r.reason, long_s=dt,
        ))  # fmt: skip
    n = len(rows)
    ok = sum(r["within"] for r in rows)
    settled = [r for r in rows if r["long_outcome"] in ("periodic", "linear")]
    loose = sum(r["z"] is not None and r["z"] <= 3.0 for r in rows)
    frac = ok / n if n else math.nan
    loose_frac = loose / n if n else math.nan
    if args.random:
        command = f"--random {args.random} --seed {args.seed} --max {args.max}"
        where = f"random cells (seed {args.seed})"
    elif args.study:
        command = f"--study {args.study} --max {args.max}"
        where = f"points of `{args.study}`"
    else:
        command = f"--points {args.points} --max {args.max}"
        where = "points of the three spectra"
    labelled = sum(r["labelled_transient"] for r in rows if not r["within"])
    lines = [
        "# Irregular points: reported standard error against a ten times longer run",
        "",
        f"`python benchmarks/irregular_budget.py {command}` "
        f"({(time.perf_counter() - t0) / 60:.1f} min, one core). {len(found)} of "
        f"{len(points)} {where} ended irregular; {n} re-run with "
        f"{args.factor}× the periods they used.",
        "",
        f"**The longer run's Γ within 3 reported standard errors: {loose} of {n} "
        f"({100 * loose_frac:.0f} %; target ≥ 90 %: {'met' if loose_frac >= 0.9 else 'NOT met'}).**"
        f" Counted strictly, with the longer run still irregular or unsettled: {ok} of {n} "
        f"({100 * frac:.0f} %).",
        "",
        f"Longer runs that settled on an orbit: {len(settled)}"
        + (
            f" (period {', '.join(str(r['long_period']) for r in settled)} after "
            f"{', '.join(str(r['long_periods']) for r in settled)} periods): the short run's "
            "irregular claim was transient chaos."
            if settled
            else "."
        )
        + f" Of the {n - ok} counted strictly as misses, {labelled} carried the note that the "
        "impact-free response is admissible (the motion may be transient).",
        "",
        "| case | γ_r | Γ dB | SE dB | periods | longer run | Γ dB | SE dB | periods | |ΔΓ|/SE |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['gamma_r']:.3f} | {r['db']:.3f} | {r['se']:.3g} | "
            f"{r['periods']} | {r['long_outcome']} | "
            + ("–" if r["long_db"] is None else f"{r['long_db']:.3f}")
            + f" | {r['long_se'] if r['long_se'] is None else format(r['long_se'], '.3g')} | "
            f"{r['long_periods']} | " + ("–" if r["z"] is None else f"{r['z']:.2f}") + " |"
        )
    name = "irregular_budget" + (f"_random{args.seed}" if args.random else "")
    if args.study:
        name += "_" + args.study.replace("/", "-")
    write_results(args.out, name, lines, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
