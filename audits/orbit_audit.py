"""Is every reported orbit the one plain iteration reaches, with its own period?

    python audits/orbit_audit.py [--study paper-fig5-gaps] [--max 0] [--plain]
                                     [--tol 1e-12] [--budget 20000] [--out audits/results]
    python audits/orbit_audit.py --random 300 --seed 4

Every point of a shipped grid study (with ``--study``; ``nightly/NAME`` for one of the nightly
suite), of N random cells over wide ranges (``--random N``, ``common.random_points``)
or else of the three spectra of ``point_engine.py`` that its own settings (with ``--plain``:
extrapolation off, plain iteration) report ``periodic`` is checked twice:

- against plain iteration (``extrapolate`` off) to ``periodicity_tol`` ``--tol`` with a budget
  of ``--budget`` periods: the same outcome and period, and |ΔΓ| (the target: within 1e-6 dB);
- against itself: the orbit integrated from its reported start (``final_state``, the states at
  its period ends from a recorded history) must not repeat after a proper divisor q of its
  period p to 1000 times its ``periodicity_tol`` of the state's size (1e-6 by default): such
  an orbit is a period-q orbit reported with a multiple of its period, while the states of a
  period-p orbit converged to ``periodicity_tol`` stay farther apart (docs/solvers.md, "How a
  point ends": a shorter period still being approached).

``--max`` N checks the first N periodic points (0: all). Writes ``orbit_audit[_<study>].md``
and ``.csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
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

from audits.common import (  # noqa: E402
    RESULTS,  # noqa: E402
    chosen_points,
    selection_options,
    write_results,  # noqa: E402
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import PointResult, SolverSettings, simulate_point, warm_up  # noqa: E402

DIVISOR_FACTOR = 1e3  # a proper divisor's repeat within this many periodicity_tol: shorter
TARGET_DB = 1e-6
LISTED_DB = 1e-8  # the table lists points off by more (the CSV has every point)


def divisor_repeat(p: CellParams, settings: SolverSettings, r: PointResult) -> float | None:
    """The smallest distance (relative to the states' size) between the reported orbit's start
    and its state after q periods, q a proper divisor of its period; None for period 1."""
    period = r.response_period
    qs = [q for q in range(1, period) if period % q == 0]
    if not qs:
        return None
    again = simulate_point(p, settings, history_periods=period)
    if again.outcome != "periodic" or again.response_period != period:
        return math.nan  # not reproducible: reported as such
    T = 2.0 * math.pi / p.gamma_r
    h = again.history
    # the history starts one sub-grid interval into the orbit; final_state is its start
    ends = [again.final_state] + [
        h["state"][np.flatnonzero(np.isclose(h["tau"], k * T, rtol=0.0, atol=1e-9 * T))[-1]]
        for k in range(1, period)
    ]
    scale = max(float(np.max(np.abs(ends))), 1e-300)
    return min(float(np.max(np.abs(ends[q] - ends[0]))) / scale for q in qs)


def audit(
    points: list[tuple[str, float, CellParams]],
    audited: SolverSettings,
    reference: SolverSettings,
    most: int = 0,
) -> list[dict]:
    """A row for each of the (first ``most``, 0: all) points ``audited`` reports periodic: its
    orbit, the reference's answer, and the orbit's closest repeat after a proper divisor of its
    period (:func:`divisor_repeat`)."""
    rows = []
    for case, g, p in points:
        if most and len(rows) >= most:
            break
        r = simulate_point(p, audited)
        if r.outcome != "periodic":
            continue
        ref = simulate_point(p, reference)
        same = ref.outcome == "periodic" and ref.response_period == r.response_period
        rows.append(dict(
            case=case, gamma_r=g, period=r.response_period, db=r.transmittance_db,
            multiplier=r.floquet_multiplier, periods=r.periods, ref_outcome=ref.outcome,
            ref_period=ref.response_period, ref_db=ref.transmittance_db, ref_periods=ref.periods,
            same_period=same,
            diff_db=abs(ref.transmittance_db - r.transmittance_db) if same else None,
            divisor_repeat=divisor_repeat(p, audited, r),
        ))  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    selection_options(ap)
    ap.add_argument("--max", type=int, default=0, help="periodic points to check (0: all)")
    ap.add_argument("--plain", action="store_true", help="audit plain iteration itself")
    ap.add_argument("--tol", type=float, default=1e-12, help="the reference's periodicity_tol")
    ap.add_argument("--budget", type=int, default=20000, help="the reference's max_periods")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.max < 0:
        ap.error(f"--max must be 0 (all) or more, got {args.max}")
    if not 0.0 < args.tol < 1e-2:
        ap.error(f"--tol must be in (0, 1e-2), got {args.tol:g}")
    if args.budget < 2:
        ap.error(f"--budget must be at least 2, got {args.budget}")
    points, audited = chosen_points(ap, args)
    t0 = time.perf_counter()
    if args.plain:
        audited = dataclasses.replace(audited, extrapolate=False)
    reference = dataclasses.replace(audited, extrapolate=False, periodicity_tol=args.tol,
                                    max_periods=args.budget)  # fmt: skip
    warm_up(audited.method)
    rows = audit(points, audited, reference, args.max)
    n = len(rows)
    same = [r for r in rows if r["same_period"]]
    diffs = sorted(r["diff_db"] for r in same)
    # (a NaN, an orbit the recorded run did not reproduce, counts)
    close = DIVISOR_FACTOR * audited.periodicity_tol
    multiple = [r for r in rows if r["divisor_repeat"] is not None
                and not r["divisor_repeat"] > close]  # fmt: skip
    mode = "plain iteration (extrapolate off)" if args.plain else "its own settings"
    mode += f" (`{audited.method}`, periodicity_tol {audited.periodicity_tol:g})"
    # the 1e-6 dB target is the default's; a looser periodicity_tol bounds the state's
    # distance to the orbit only to itself, Γ to about 20/ln 10 ≈ 8.7 dB times that
    loose = audited.periodicity_tol > SolverSettings().periodicity_tol
    if args.random:
        source = f"--random {args.random} --seed {args.seed}"
        where = f"{args.random} random cells (seed {args.seed})"
    elif args.study:
        source, where = f"--study {args.study}", f"`{args.study}`"
    else:
        source, where = f"--points {args.points}", "the three spectra"
    command = source + (
        f" --max {args.max}" + (" --plain" if args.plain else "")
        + f" --tol {args.tol:g} --budget {args.budget}"
    )  # fmt: skip
    worst = max(diffs) if diffs else math.nan
    lines = [
        "# Orbit audit: every reported orbit against plain iteration, and against its own period",
        "",
        f"`python audits/orbit_audit.py {command}` ({(time.perf_counter() - t0) / 60:.1f} "
        f"min, one core). {n} points of {where} reported `periodic` by {mode}; the reference "
        f"is plain iteration to periodicity_tol {args.tol:g} within {args.budget} periods.",
        "",
        f"**Same outcome and period as the reference: {len(same)} of {n}.** Over those, "
        f"|ΔΓ| max {worst:.3g} dB, median "
        + (f"{diffs[len(diffs) // 2]:.3g}" if diffs else "–")
        + f" dB (target {TARGET_DB:g}: {'met' if worst <= TARGET_DB else 'NOT met'}"
        + (
            f"; the target is the default periodicity_tol's, this study asks for "
            f"{audited.periodicity_tol:g}"
            if loose
            else ""
        )
        + ").",
        "",
        f"**Orbits that repeat after a proper divisor of their period (to {close:g} of the "
        f"state, or not reproduced): {len(multiple)}.**",
        "",
        "| case | γ_r | period | Γ dB | periods | reference | period | periods | |ΔΓ| dB | "
        "divisor repeat |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["same_period"] and (r["diff_db"] or 0.0) <= LISTED_DB and r not in multiple:
            continue  # the table lists what is worth a look
        lines.append(
            f"| {r['case']} | {r['gamma_r']:.4g} | {r['period']} | {r['db']:.9g} | "
            f"{r['periods']} | {r['ref_outcome']} | {r['ref_period']} | {r['ref_periods']} | "
            + ("–" if r["diff_db"] is None else f"{r['diff_db']:.3g}")
            + " | "
            + ("–" if r["divisor_repeat"] is None else f"{r['divisor_repeat']:.3g}")
            + " |"
        )
    lines += ["", f"(The table lists the points off by more than {LISTED_DB:g} dB, of another "
              "period, or repeating early; the CSV has every point.)"]  # fmt: skip
    suffix = (
        ("_" + args.study.replace("/", "-") if args.study else "")
        + (f"_random{args.seed}" if args.random else "")
        + ("_plain" if args.plain else "")
    )
    write_results(args.out, f"orbit_audit{suffix}", lines, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
