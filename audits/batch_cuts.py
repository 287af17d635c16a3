"""Does the machine's load change what a point reports? Every batch one period against none cut.

    python audits/batch_cuts.py [--study NAME | --random N [--seed S]] [--max 0]
                                    [--out audits/results]

The engine advances a point in batches of periods and shortens them when periods are slow
(``loop._Engine._pace``, by the clock: under load, or at costly points), so that limits and cancel
are seen often enough. Where the clock cuts must change nothing a point reports. Each point is
run twice in this process: as it comes (on an idle machine no batch of these points is cut) and
with ``cfg.BATCH_S`` at 0, so that every batch is one period, the most cuts there can be.
Every field of the two results but ``wall_s`` is compared, to the bit.

Points: by default the 600 of the killed-worker topology test (``tests/test_topology.py``:
θ 0.3, σ 0.05, γ_s 1, ξ 0.05, gaps 0.1, 0.3, 0.5, 0.7, γ_r 0.5 … 3 in 150 steps; solver
``max_periods`` 100, ``periodicity_tol`` 1e-13, ``window`` 5), where periodic points reach
pending orbits near batch ends; ``--study`` a shipped grid study's (its settings),
``--random N`` random cells (``common.random_points``). ``--max`` N runs the first N
(0: all).

Writes ``batch_cuts[_<study>].md`` and ``.csv`` (the points that differ, each with the fields
that do and their two values).
"""

from __future__ import annotations

import argparse
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

from audits.common import (  # noqa: E402
    RESULTS,
    chosen_points,
    write_results,
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import SOLVER_VERSION, SolverSettings, simulate_point, warm_up  # noqa: E402
from worker.solvers.engine import config as cfg  # noqa: E402

# tests/service/helpers.FAST_SOLVER with test_topology.KILL_SOLVER (steps_per_period is for the
# stepping methods; the default event method does not look at it)
TOPOLOGY_SOLVER = SolverSettings(max_periods=100, periodicity_tol=1e-13, window=5)


def topology_points() -> list[tuple[str, float, CellParams]]:
    """The killed-worker topology test's 600 points, labelled by their gap."""
    return [
        (f"gap {g:g}", float(x), CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=g,
                                            g2=g, gamma_r=float(x)))
        for g in (0.1, 0.3, 0.5, 0.7)
        for x in np.linspace(0.5, 3.0, 150)
    ]  # fmt: skip


def differences(a: dict, b: dict) -> dict[str, tuple]:
    """The fields (but ``wall_s``) whose values differ between two results, with both values."""
    keys = (set(a) | set(b)) - {"wall_s"}
    return {k: (a.get(k), b.get(k)) for k in sorted(keys) if _text(a.get(k)) != _text(b.get(k))}


def _text(v: object) -> str:
    # repr compares floats to the bit and arrays (final_state, history) element by element
    return repr(v.tolist()) if isinstance(v, np.ndarray) else repr(v)


def compare(points: list[tuple[str, float, CellParams]], settings: SolverSettings) -> list[dict]:
    """Each point as it comes, then with every batch one period; one row per point that
    differs."""
    ref = [simulate_point(p, settings).as_dict() for _, _, p in points]
    saved = cfg.BATCH_S
    cfg.BATCH_S = 0.0  # every batch "slow": one period each
    try:
        cut = [simulate_point(p, settings).as_dict() for _, _, p in points]
    finally:
        cfg.BATCH_S = saved
    rows = []
    for (case, g, _), a, b in zip(points, ref, cut, strict=True):
        diff = differences(a, b)
        if diff:
            rows.append({
                "case": case, "gamma_r": g, "outcome": a.get("outcome"),
                "fields": " ".join(diff),
                "as_it_comes": "; ".join(f"{k}={v[0]!r}" for k, v in diff.items()),
                "one_period_batches": "; ".join(f"{k}={v[1]!r}" for k, v in diff.items()),
            })  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", help="a shipped grid study instead of the topology test's")
    ap.add_argument("--random", type=int, default=0, help="N random cells instead (--seed)")
    ap.add_argument("--seed", type=int, default=4, help="the random cells' seed")
    ap.add_argument("--max", type=int, default=0, help="run the first N points (0: all)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.max < 0:
        ap.error(f"--max must be 0 (all) or more, got {args.max}")
    if args.study or args.random:
        points, settings = chosen_points(ap, args)
    else:
        points, settings = topology_points(), TOPOLOGY_SOLVER
    points = points[: args.max] if args.max else points
    warm_up(settings.method)
    t0 = time.perf_counter()
    rows = compare(points, settings)
    what = args.study or (f"{args.random} random cells (seed {args.seed})" if args.random else
                          "the killed-worker topology test's points")  # fmt: skip
    lines = [
        f"Every batch one period (`cfg.BATCH_S` = 0) against batches as they come, solver "
        f"version {SOLVER_VERSION}: {what}, {len(points)} points, every field but `wall_s` "
        f"compared to the bit.",
        "",
        f"**{len(rows)} of {len(points)} points differ** ({time.perf_counter() - t0:.0f} s).",
        "",
    ]
    if rows:
        lines += ["| case | γ_r | outcome | fields | as it comes | one-period batches |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        lines += [f"| {r['case']} | {r['gamma_r']:.4f} | {r['outcome']} | {r['fields']} | "
                  f"{r['as_it_comes']} | {r['one_period_batches']} |" for r in rows]  # fmt: skip
    cmd = " ".join(["python audits/batch_cuts.py", *(sys.argv[1:] if argv is None else argv)])
    lines += ["", f"Generated by `{cmd}`."]
    name = "batch_cuts" + (f"_{args.study.replace('/', '-')}" if args.study else
                           f"_random{args.seed}" if args.random else "")  # fmt: skip
    write_results(args.out, name, lines, rows)
    return 1 if rows else 0


if __name__ == "__main__":
    sys.exit(main())
