"""How far is `exponential`'s orbit from the cell's? Its step error at a study's periodic points.

    python audits/step_check.py --study nightly/full-gaps [--tol 1e-3] [--out DIR]
    python audits/step_check.py --random 300 --seed 4 --method exponential

`exponential` reports no error estimate of its own (docs/solvers.md), and its error is second
order in its fine step (docs/accuracy.md, known limits). Every point of a shipped grid study
(``--study``; ``nightly/NAME`` for the nightly suite), of N random cells (``--random N``) or
else of the three spectra of ``point_engine.py`` that ``exponential`` reports ``periodic`` (with
the study's settings; ``--method exponential`` runs random cells or the spectra with it) is run
again at twice its ``steps_per_period``, from the orbit's reported start (``final_state``): the
finer discretization's orbit nearby, found in a few periods. Where both have the same period,
(Γ at N − Γ at 2N)·4/3 estimates the error of the reported Γ (the ``estimate_db`` column);
where the finer run ends on another period, the coarse step has moved a bifurcation across
the point (``event``, which has no step, is the judge of which is the cell's). Reports the
estimates' distribution, how many exceed ``--tol``, the period changes, and the check's time
against the first pass (one core). Writes ``step_check[_<study>|_random<seed>]`` ``.md`` and
``.csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
from audits.common import (  # noqa: E402
    RESULTS,  # noqa: E402
    chosen_points,
    results_name,
    selection,
    selection_options,
    write_results,  # noqa: E402
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402

METHOD = "exponential"
ORDER = 2  # exponential's error falls fourfold with each doubling of its fine steps


def check(
    points: list[tuple[str, float, CellParams]], settings: SolverSettings
) -> tuple[list[dict[str, Any]], float]:
    """A row per point that ``settings`` report periodic (its orbit, and the orbit of twice
    the fine steps from its start) and the first pass's time over every point."""
    rows = []
    first_s = 0.0
    for case, g, p in points:
        t0 = time.perf_counter()
        r = simulate_point(p, settings)
        first_s += time.perf_counter() - t0
        if r.outcome != "periodic":
            continue
        finer = dataclasses.replace(settings, steps_per_period=2 * r.steps_per_period)
        t1 = time.perf_counter()
        f = simulate_point(p, finer, initial_state=r.final_state)
        dt = time.perf_counter() - t1
        same = f.outcome == "periodic" and f.response_period == r.response_period
        diff = None if f.transmittance_db is None else r.transmittance_db - f.transmittance_db
        rows.append(dict(
            case=case, gamma_r=g, steps_per_period=r.steps_per_period, period=r.response_period,
            db=r.transmittance_db, finer_outcome=f.outcome, finer_period=f.response_period,
            finer_db=f.transmittance_db, finer_periods=f.periods, diff_db=diff,
            estimate_db=abs(diff) / (1.0 - 2.0**-ORDER) if same and diff is not None else None,
            check_s=dt,
        ))  # fmt: skip
    return rows, first_s


def lines_of(
    rows: list[dict[str, Any]], n_points: int, first_s: float, args: argparse.Namespace,
    wall_s: float,
) -> list[str]:  # fmt: skip
    """The report: the estimates, the period changes, the cost."""
    where, command = selection(args)
    if args.random or not args.study:
        command += f" --method {args.method}"
    est = [r["estimate_db"] for r in rows if r["estimate_db"] is not None]
    over = [r for r in rows if r["estimate_db"] is not None and r["estimate_db"] > args.tol]
    moved = [r for r in rows if r["estimate_db"] is None]
    check_s = sum(r["check_s"] for r in rows)
    spread = f"median {statistics.median(est):.2g} dB, at most {max(est):.2g} dB" if est else "none"
    lines = [
        f"# `{METHOD}`'s step error at periodic points: twice the fine steps, from the orbit",
        "",
        f"`python audits/step_check.py {command} --tol {args.tol:g}` ({wall_s / 60:.1f} "
        f"min, one core). Of {n_points} {where}, {len(rows)} are `periodic` with `{METHOD}`; "
        "each is run again at twice its fine steps from its orbit's start. Estimated error of "
        f"the reported Γ, (Γ at N − Γ at 2N)·4/3, where both have the same period: {spread}.",
        "",
        f"- **Above {args.tol:g} dB: {len(over)}** of {len(est)}.",
        f"- **Another outcome or period at twice the steps: {len(moved)}** (the coarse step moves "
        "a bifurcation across the point; `event` tells which is the cell's).",
        f"- Cost: the checks took {check_s:.1f} s against {first_s:.1f} s for the first pass.",
        "",
        "| case | γ_r | period | Γ dB | twice the steps | period | Γ dB | periods | estimate dB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(over + moved, key=lambda r: (r["case"], r["gamma_r"])):
        lines.append(
            f"| {r['case']} | {r['gamma_r']:.3f} | {r['period']} | {r['db']:.6f} | "
            f"{r['finer_outcome']} | {r['finer_period']} | "
            + ("–" if r["finer_db"] is None else f"{r['finer_db']:.6f}")
            + f" | {r['finer_periods']} | "
            + ("–" if r["estimate_db"] is None else f"{r['estimate_db']:.2g}")
            + " |"
        )
    lines += ["", "The table lists the points above the tolerance or with another period; the "
              "CSV has every periodic point."]  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    selection_options(ap)
    ap.add_argument(
        "--method", default=None, help=f"the method of random cells or the spectra ({METHOD})"
    )
    ap.add_argument("--tol", type=float, default=1e-3, help="error estimate to count (dB)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if not args.tol > 0.0:
        ap.error(f"--tol must be > 0 dB, got {args.tol:g}")
    points, settings = chosen_points(ap, args)
    if args.study:
        if args.method is not None:
            ap.error("--method: a study runs with its own settings; leave it out")
    else:
        if args.method not in (None, METHOD):
            ap.error(f"--method must be {METHOD} (its error is second order), got {args.method}")
        args.method = METHOD
        settings = dataclasses.replace(settings, method=METHOD)
    if settings.method != METHOD:
        ap.error(f"the study runs method {settings.method!r}; this checks {METHOD!r} only")
    t0 = time.perf_counter()
    warm_up(METHOD)
    rows, first_s = check(points, settings)
    lines = lines_of(rows, len(points), first_s, args, time.perf_counter() - t0)
    write_results(args.out, results_name("step_check", args), lines, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
