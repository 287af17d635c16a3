"""Do irregular points' error bars hold? Random irregular cells against runs 20 times longer.

    python audits/irregular_error_bars.py [--cells 100] [--seed 1] [--undamped 0.4]
                                              [--factor 20] [--out audits/results]

Draws random cells over the wide ranges of ``common.random_points`` (both couplings),
a seeded share ``--undamped`` of them made undamped (ξ = 0, so the beam's ξ_b = 0 too), runs
each with the default settings until ``--cells`` of them end ``irregular``, and runs each of
those again from the same start with ``max_periods`` ``--factor`` times the periods its claim
used and a standard-error target so small that the statistics run to that budget (a response
that settles on an orbit or the impact-free response ends there). A reported standard error
holds if the longer run's Γ lies within 2 (3) of them of the claim's Γ; the target is 90 %
(98 %) of the cells. A longer run that settles shows transient chaos: it counts as a miss.
The table splits the cells by coupling and damping, and by whether the claim's reason says its
error bar cannot be trusted (``engine.UNTRUSTED_NOTE``) or that the motion may be transient.

Writes ``irregular_error_bars[_seed<seed>].md`` and ``.csv``.

    python audits/irregular_error_bars.py --orbits paper-fig5-gaps

instead relates the two definitions of Γ (docs/model.md §6) on a shipped study's orbits of
period 2 or more: how far the orbit's Γ (its extremes over all p periods) lies above the
cycle-by-cycle Γ of the same orbit (the mean of its periods' half-ranges), which an irregular
response reports. Prints the distribution.
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
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from audits.common import (  # noqa: E402
    RESULTS,
    random_points,
    write_results,
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402
from worker.solvers.engine import TRANSIENT_NOTE, UNTRUSTED_NOTE  # noqa: E402

DRAW = 50  # cells drawn at a time (the seed fixes the whole stream)
XI_BANDS = ((0.001, 0.003), (0.003, 0.01), (0.01, 0.03), (0.03, 0.3))  # the damped cells' ξ


def cells(seed: int, undamped: float):
    """An endless seeded stream of random cells (``random_points``' ranges), a share
    ``undamped`` of them with ξ = 0: (case, γ_r, cell)."""
    rng = np.random.default_rng([seed, 1])
    for batch in range(10**6):
        for case, g, p in random_points(DRAW, seed * 10**6 + batch):
            if rng.random() < undamped:
                p = dataclasses.replace(p, xi=0.0, xi_b=None)
                case = json.dumps({**json.loads(case), "xi": 0.0})
            yield case, g, p


def rerun(p: CellParams, r: Any, default: SolverSettings, factor: int) -> tuple[Any, float]:
    """The same cell ``factor`` times longer than ``r``'s claim, to the budget's end unless it
    settles; with its time."""
    longer = dataclasses.replace(default, max_periods=factor * r.periods, stat_tol_db=1e-12)
    t = time.perf_counter()
    lr = simulate_point(p, longer)
    return lr, time.perf_counter() - t


def row(case: str, p: CellParams, r: Any, lr: Any, dt: float, long_s: float) -> dict[str, Any]:
    """A cell's row: its class, both runs, and how many claimed standard errors apart."""
    diff = None if lr.transmittance_db is None else lr.transmittance_db - r.transmittance_db
    z = math.inf if diff is None else abs(diff) / r.transmittance_db_se
    return dict(
        case=case, coupling=p.coupling, damped=p.xi > 0.0, xi=p.xi, db=r.transmittance_db,
        se=r.transmittance_db_se, periods=r.periods, untrusted=UNTRUSTED_NOTE in r.reason,
        transient_note=TRANSIENT_NOTE in r.reason, long_outcome=lr.outcome,
        long_db=lr.transmittance_db, long_se=lr.transmittance_db_se, long_periods=lr.periods,
        diff_db=diff, z=z, s=dt, long_s=long_s, reason=r.reason,
    )  # fmt: skip


def share(rows: list[dict[str, Any]], k: float) -> str:
    """``a of n (p %)`` of rows within ``k`` standard errors."""
    n = len(rows)
    a = sum(r["z"] <= k for r in rows)
    return f"{a} of {n} ({100 * a / n:.0f} %)" if n else "–"


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The within-2/3-SE table, by class."""
    classes = [("all", rows)]
    for coupling in ("paper", "full"):
        for damped in (True, False):
            sel = [r for r in rows if r["coupling"] == coupling and r["damped"] == damped]
            classes.append((f"{coupling}, {'damped' if damped else 'undamped'}", sel))
    damped = [r for r in rows if r["damped"]]
    classes += [
        ("error bar trusted", [r for r in rows if not r["untrusted"]]),
        ("error bar not trusted (reason says so)", [r for r in rows if r["untrusted"]]),
        ("damped, trusted", [r for r in damped if not r["untrusted"]]),
        ("damped, trusted, no transient note",
         [r for r in damped if not r["untrusted"] and not r["transient_note"]]),
    ]  # fmt: skip
    for lo, hi in XI_BANDS:
        sel = [r for r in damped if lo <= r["xi"] < hi]
        classes.append((f"damped, ξ {lo:g}–{hi:g}", sel))
    lines = [
        "| cells | n | within 2 SE | within 3 SE | longer run settled |",
        "|---|---|---|---|---|",
    ]
    for name, sel in classes:
        settled = sum(r["long_outcome"] in ("periodic", "linear") for r in sel)
        lines.append(f"| {name} | {len(sel)} | {share(sel, 2)} | {share(sel, 3)} | {settled} |")
    return lines


def orbit_spread(study: str) -> list[tuple[int, float]]:
    """(period, orbit Γ − cycle-by-cycle Γ in dB) of every reported orbit of period ≥ 2 of a
    shipped study, read from the rows the engine measured the orbit with."""
    from audits.common import study_points
    from worker.solvers import measure as ms
    from worker.solvers.engine import loop

    got: list[tuple[int, float]] = []
    classify = loop._Engine._classify_orbit

    def measured(self: Any, orbit: Any) -> tuple[str, object]:
        out = classify(self, orbit)
        if out[0] == "periodic" and orbit.p >= 2:
            rows = orbit.rows
            whole = 0.5 * (rows[:, ms.M_SMAX].max() - rows[:, ms.M_SMIN].min())
            cycle = float(np.mean(0.5 * (rows[:, ms.M_SMAX] - rows[:, ms.M_SMIN])))
            got.append((orbit.p, 20.0 * math.log10(whole / cycle)))
        return out

    loop._Engine._classify_orbit = measured  # type: ignore[method-assign]
    try:
        points, settings = study_points(study)
        warm_up(settings.method)
        for _, _, p in points:
            simulate_point(p, settings)
    finally:
        loop._Engine._classify_orbit = classify  # type: ignore[method-assign]
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=100, help="irregular cells to check")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--undamped", type=float, default=0.4, help="share of cells with ξ = 0")
    ap.add_argument("--factor", type=int, default=20, help="budget multiple of the re-run")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--orbits", metavar="STUDY", help="instead: the two Γ on a study's orbits")
    args = ap.parse_args(argv)
    if args.orbits:
        spread = orbit_spread(args.orbits)
        d = np.array([x for _, x in spread])
        if not len(d):
            print(f"{args.orbits}: no orbits of period 2 or more")
            return 0
        print(
            f"{args.orbits}: {len(d)} orbits of period 2-{max(p for p, _ in spread)}; orbit Γ "
            f"above the cycle-by-cycle Γ by a median of {np.median(d):.3g} dB (90th "
            f"percentile {np.quantile(d, 0.9):.3g}, at most {d.max():.3g}); by more than "
            f"0.01 dB at {100 * np.mean(d > 0.01):.0f} %, never below: {bool(d.min() >= 0)}"
        )
        return 0
    if args.cells < 1 or not 0.0 <= args.undamped <= 1.0 or args.factor < 2:
        ap.error("--cells must be >= 1, --undamped in [0, 1] and --factor >= 2")
    default = SolverSettings()
    t0 = time.perf_counter()
    warm_up(default.method)
    rows: list[dict[str, Any]] = []
    drawn = 0
    for case, _, p in cells(args.seed, args.undamped):
        drawn += 1
        t = time.perf_counter()
        r = simulate_point(p, default)
        dt = time.perf_counter() - t
        if r.outcome != "irregular":
            continue
        lr, long_s = rerun(p, r, default, args.factor)
        rows.append(row(case, p, r, lr, dt, long_s))
        print(f"{len(rows):4d}/{drawn}: z {rows[-1]['z']:.2f} {p.coupling} ξ {p.xi:.3g}",
              flush=True)  # fmt: skip
        if len(rows) >= args.cells:
            break
    n = len(rows)
    within2 = sum(r["z"] <= 2 for r in rows) / n
    within3 = sum(r["z"] <= 3 for r in rows) / n
    command = (f"python audits/irregular_error_bars.py --cells {args.cells} --seed "
               f"{args.seed} --undamped {args.undamped:g} --factor {args.factor}")  # fmt: skip
    worst = sorted(rows, key=lambda r: -r["z"])[:10]
    lines = [
        f"# Irregular points: reported standard errors against runs {args.factor} times longer",
        "",
        f"`{command}` ({(time.perf_counter() - t0) / 60:.1f} min, one core). {n} of {drawn} "
        f"random cells ended irregular with the default settings; each ran again "
        f"{args.factor}× as long (settled ones stop where they settle).",
        "",
        f"**Within 2 reported standard errors: {100 * within2:.0f} % (target ≥ 90 %: "
        f"{'met' if within2 >= 0.9 else 'NOT met'}); within 3: {100 * within3:.0f} % "
        f"(target ≥ 98 %: {'met' if within3 >= 0.98 else 'NOT met'}).**",
        "",
        *table(rows),
        "",
        "Worst cells:",
        "",
        "| case | Γ dB | SE dB | periods | reason | longer run | Γ dB | periods | \\|ΔΓ\\|/SE |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in worst:
        long_db = "–" if r["long_db"] is None else f"{r['long_db']:.3f}"
        lines.append(
            f"| {r['case']} | {r['db']:.3f} | {r['se']:.3g} | {r['periods']} | "
            f"{r['reason'] or '–'} | {r['long_outcome']} | {long_db} | {r['long_periods']} | "
            f"{r['z']:.2f} |"
        )
    name = "irregular_error_bars" + (f"_seed{args.seed}" if args.seed != 1 else "")
    write_results(args.out, name, lines, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
