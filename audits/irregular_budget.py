"""Are the standard errors of irregular points honest? Re-run them with ten times the budget.

    python audits/irregular_budget.py [--points 40] [--max 25] [--out audits/results]
    python audits/irregular_budget.py --study paper-fig5-gaps [--max 0]
    python audits/irregular_budget.py --study nightly/irregular [--max 0]
    python audits/irregular_budget.py --random 1500 --seed 11 --max 0

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

``--transient-guard G`` asks another question of the same points: what the solver setting
``transient_guard`` does to the claims that carry the note (the impact-free response is
admissible too, so the motion may be transient chaos that dies out). Each such claim is run
again with ``transient_guard`` G (and ``max_periods`` at least G; every other setting as
before): how many then settle on the linear response or an orbit, and how far their Γ was off;
how many stay irregular, and how far their Γ moves; and what the setting costs (a rerun repeats
its first run's periods to the bit and goes on, so the reruns' time less the first runs' is
what the setting adds to the study; against the whole first pass, one core). Writes
``irregular_noted[_<study>|_random<seed>]`` ``.md`` and ``.csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
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
    RESULTS,
    chosen_points,
    results_name,
    selection,
    selection_options,
    write_results,
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402
from worker.solvers.engine import TRANSIENT_NOTE  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    selection_options(ap)
    ap.add_argument("--max", type=int, default=25, help="irregular points to re-run")
    ap.add_argument("--factor", type=int, default=10, help="budget multiple of the re-run")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument(
        "--transient-guard", type=int, default=0, metavar="G",
        help="instead: run the claims that carry the may-be-transient note again with the "
             "solver setting transient_guard G (later than their own earliest claim)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    points, default = chosen_points(ap, args)
    if args.transient_guard and args.transient_guard <= default.max_periods // 4:
        ap.error(
            f"--transient-guard must be later than the points' own earliest claim (period "
            f"{default.max_periods // 4}); got {args.transient_guard}"
        )
    t0 = time.perf_counter()
    warm_up(default.method)
    found = []
    first_s = 0.0  # the first pass over every point, one core
    for case, g, p in points:
        t1 = time.perf_counter()
        r = simulate_point(p, default)
        dt = time.perf_counter() - t1
        first_s += dt
        if r.outcome == "irregular":
            found.append((case, g, p, r, dt))
    if args.transient_guard:
        rows = noted_rows(found, default, args.transient_guard)
        lines = noted_lines(rows, len(points), first_s, args, time.perf_counter() - t0)
        write_results(args.out, results_name("irregular_noted", args), lines, rows)
        return 0
    picked = found[: args.max] if args.max > 0 else found
    rows = []
    for case, g, p, r, _ in picked:
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
            labelled_transient=r.may_be_transient, long_s=dt,
        ))  # fmt: skip
    n = len(rows)
    ok = sum(r["within"] for r in rows)
    settled = [r for r in rows if r["long_outcome"] in ("periodic", "linear")]
    loose = sum(r["z"] is not None and r["z"] <= 3.0 for r in rows)
    frac = ok / n if n else math.nan
    loose_frac = loose / n if n else math.nan
    where, chosen = selection(args)
    command = f"{chosen} --max {args.max}"
    labelled = sum(r["labelled_transient"] for r in rows if not r["within"])
    lines = [
        "# Irregular points: reported standard error against a ten times longer run",
        "",
        f"`python audits/irregular_budget.py {command}` "
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
            _both_runs(r)
            + f" | {r['long_se'] if r['long_se'] is None else format(r['long_se'], '.3g')} | "
            f"{r['long_periods']} | " + ("–" if r["z"] is None else f"{r['z']:.2f}") + " |"
        )
    write_results(args.out, results_name("irregular_budget", args), lines, rows)
    return 0


def _both_runs(r: dict[str, Any]) -> str:
    """A table row's first cells: the point, its first run, the second run's outcome and Γ."""
    return (
        f"| {r['case']} | {r['gamma_r']:.3f} | {r['db']:.3f} | {r['se']:.3g} | "
        f"{r['periods']} | {r['long_outcome']} | "
        + ("–" if r["long_db"] is None else f"{r['long_db']:.3f}")
    )


def noted_rows(
    found: list[tuple[str, float, CellParams, Any, float]], settings: SolverSettings, guard: int
) -> list[dict[str, Any]]:
    """The irregular claims among ``found`` (case, γ_r, cell, result, its time) whose reason
    carries the may-be-transient note, each run again with ``transient_guard`` ``guard`` (and
    ``max_periods`` at least that): a row per claim, both runs' outcome, Γ, standard error,
    periods and time."""
    longer = dataclasses.replace(
        settings, max_periods=max(settings.max_periods, guard), transient_guard=guard
    )
    rows = []
    for case, g, p, r, dt in found:
        if not r.may_be_transient:
            continue
        t1 = time.perf_counter()
        lr = simulate_point(p, longer)
        ls = time.perf_counter() - t1
        diff = None if lr.transmittance_db is None else lr.transmittance_db - r.transmittance_db
        rows.append(dict(
            case=case, gamma_r=g, db=r.transmittance_db, se=r.transmittance_db_se,
            periods=r.periods, s=dt, long_outcome=lr.outcome, long_db=lr.transmittance_db,
            long_se=lr.transmittance_db_se, long_periods=lr.periods,
            long_period=lr.response_period, diff_db=diff,
            z=None if diff is None else abs(diff) / r.transmittance_db_se, long_s=ls,
        ))  # fmt: skip
    return rows


def _spread(values: list[float]) -> str:
    """``median x, at most y dB`` of the absolute values (``–`` for none)."""
    if not values:
        return "–"
    a = [abs(v) for v in values]
    return f"median {statistics.median(a):.3g}, at most {max(a):.3g} dB"


def noted_lines(
    rows: list[dict[str, Any]], n_points: int, first_s: float, args: argparse.Namespace,
    wall_s: float,
) -> list[str]:  # fmt: skip
    """The ``--transient-guard`` report: what the setting did to the noted claims, and what
    it costs against the first pass."""
    guard = args.transient_guard
    where, command = selection(args)
    settled = [r for r in rows if r["long_outcome"] in ("linear", "periodic")]
    died = [r for r in settled if r["long_outcome"] == "linear"]
    kept = [r for r in rows if r["long_outcome"] == "irregular"]
    unsettled = [r for r in rows if r["long_outcome"] == "unsettled"]
    other = len(rows) - len(settled) - len(kept) - len(unsettled)
    within = sum(r["z"] is not None and r["z"] <= 3.0 for r in kept)
    rerun_s = sum(r["long_s"] for r in rows)
    own_s = sum(r["s"] for r in rows)
    share = 100.0 * (rerun_s - own_s) / first_s if first_s > 0 else math.nan
    ends = sorted({r["long_periods"] for r in settled})
    span = "–" if not ends else f"{ends[0]}" if len(ends) == 1 else f"{ends[0]}–{ends[-1]}"
    lines = [
        "# Irregular claims that may be transient, run again with a transient guard",
        "",
        f"`python audits/irregular_budget.py {command} --transient-guard {guard}` "
        f"({wall_s / 60:.1f} min, one core). Of {n_points} {where}, {len(rows)} end irregular "
        f'with the note that the impact-free response is admissible too ("{TRANSIENT_NOTE}"); '
        f"each is run again from the same start with the solver setting `transient_guard` "
        f"{guard} (such a claim waits until period {guard}; `max_periods` at least that), "
        "every other setting as before.",
        "",
        f"- **Settled: {len(settled)}** ({len(died)} on the impact-free response, "
        f"{len(settled) - len(died)} on an orbit), after {span} periods. The first claim's Γ "
        f"was off by {_spread([r['diff_db'] for r in settled])} (the impact-free ones: "
        f"{_spread([r['diff_db'] for r in died])}).",
        f"- Still irregular: {len(kept)}, Γ moved by {_spread([r['diff_db'] for r in kept])};"
        f" {within} within 3 of the first claim's standard errors.",
        f"- Unsettled (the statistics not converged by the budget's end, or still approaching "
        f"an orbit): {len(unsettled)}" + (f"; other outcomes: {other}" if other else "") + ".",
        f"- Cost: the reruns took {rerun_s:.1f} s, these claims' first runs {own_s:.1f} s and "
        f"the whole first pass {first_s:.1f} s. A rerun repeats its first run's periods to the "
        f"bit and goes on, so the setting adds {rerun_s - own_s:.1f} s to these points: "
        f"{share:.0f} % of the first pass. (Raising `max_periods` instead moves every "
        "irregular claim, not only these.)",
        "",
        "| case | γ_r | Γ dB | SE dB | periods | with the guard | Γ dB | periods | ΔΓ dB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            _both_runs(r)
            + f" | {r['long_periods']} | "
            + ("–" if r["diff_db"] is None else f"{r['diff_db']:+.3f}")
            + " |"
        )
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
