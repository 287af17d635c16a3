"""What a chain's point costs against N, and what each chain method costs at equal accuracy.

    python benchmarks/chain_cost.py [--out DIR] [--n20-periods 400] [--quick]

The paper's cell (θ 0.3, σ 0.05, γ_s 1, ξ 0.05, 5 modes, gap 0.1 at every stop) in ``full``
coupling, as in docs/chains.md's figure, at γ_r = 1.9, where chains of 1 … 10 cells end periodic
(period 1) with several cells impacting (N = 20 too with ``exponential``; ``euler`` is still
unsettled at its budget).

1. Cost against N: one point from rest for N in (1, 2, 5, 10, 20), methods ``euler`` and
   ``exponential`` at their default steps per period (N = 1 is the unit cell's
   ``simulate_point``). N = 20 runs with a smaller ``max_periods`` (``--n20-periods``; the
   table says so; the engine's extrapolation and confirmation runs may add periods beyond it,
   the periods column counts them all). The growth exponent is the least-squares slope of
   log(ms per period) on log N over N ≥ 2 (per period, so the budgeted N = 20 run counts
   alike; per point as well).
2. Accuracy at N = 5 on a few periodic points: the reference is ``exponential`` at a tight
   step (``REF_STEPS`` per period). For each method the steps per period double from the
   ladder's start until Γ_N is within ``TOL_DB`` of the reference with the reference's impacts
   per period (the cheapest such step on the ladder); the table gives both methods' time there
   and the ratio euler / exponential.

Writes ``chain_cost.md`` to ``--out`` (default ``benchmarks/results``). One core, a few minutes.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from worker.model import CellParams  # noqa: E402
from worker.model.chain import ChainParams  # noqa: E402
from worker.simulate import PointResult, SolverSettings, simulate_chain_point  # noqa: E402

CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.9, xi=0.05, g1=0.1, g2=0.1,
                  modes=5, coupling="full")  # fmt: skip
CELLS = (1, 2, 5, 10, 20)
METHODS = ("euler", "exponential")
MAX_PERIODS = 2000
# accuracy comparison (N = 5)
ACC_CELLS = 5
ACC_GAMMAS = (1.9, 2.0, 2.2)
TOL_DB = 0.01
REF_STEPS = 8192
LADDER = {"euler": (1024, 65536), "exponential": (32, 8192)}


def run(n_cells: int, method: str, gamma_r: float, spp: int | None = None,
        max_periods: int = MAX_PERIODS) -> tuple[PointResult, float]:  # fmt: skip
    """One point from rest and its wall time (s)."""
    cell = dataclasses.replace(CELL, gamma_r=gamma_r)
    s = SolverSettings(method=method, steps_per_period=spp, max_periods=max_periods)
    t0 = time.perf_counter()
    r = simulate_chain_point(ChainParams(cell=cell, n_cells=n_cells), s)
    return r, time.perf_counter() - t0


def slope(ns: list[int], ys: list[float]) -> float:
    """Least-squares slope of log y on log N."""
    return float(np.polyfit(np.log(ns), np.log(ys), 1)[0])


def impacts(r: PointResult) -> str:
    return "—" if r.impacts_per_period is None else "+".join(f"{v:g}" for v in r.impacts_per_period)


def cost_table(n20_periods: int, cells: tuple[int, ...]) -> list[str]:
    rows = ["| N | method | ms / point | periods | ms / period | outcome | impacts / period "
            "| steps / period | Γ_N (dB) |", "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    per_period: dict[str, list[float]] = {m: [] for m in METHODS}
    per_point: dict[str, list[float]] = {m: [] for m in METHODS}
    for n in cells:
        for m in METHODS:
            budget = n20_periods if n == 20 else MAX_PERIODS
            r, wall = run(n, m, CELL.gamma_r, max_periods=budget)
            outcome = r.outcome + (f" (max_periods {budget})" if n == 20 else "")
            gamma = "—" if r.transmittance_db is None else f"{r.transmittance_db:.4f}"
            rows.append(f"| {n} | {m} | {1e3 * wall:.0f} | {r.periods} | "
                        f"{1e3 * wall / max(r.periods, 1):.3f} | {outcome} | {impacts(r)} | "
                        f"{r.steps_per_period} | {gamma} |")  # fmt: skip
            print(rows[-1], flush=True)
            if n >= 2:
                per_period[m].append(wall / max(r.periods, 1))
                per_point[m].append(wall)
    ns = [n for n in cells if n >= 2]
    rows.append("")
    if len(ns) >= 2:
        for m in METHODS:
            rows.append(f"- growth exponent, `{m}` (N = {', '.join(map(str, ns))}): "
                        f"{slope(ns, per_period[m]):.2f} per period, "
                        f"{slope(ns, per_point[m]):.2f} per point")  # fmt: skip
    return rows


def ladder(method: str, gamma_r: float, ref: PointResult) -> tuple[int, PointResult, float]:
    """The cheapest steps per period on the method's doubling ladder within ``TOL_DB`` of the
    reference, with its impacts per period (the last rung if none is)."""
    lo, hi = LADDER[method]
    spp = lo
    while True:
        r, wall = run(ACC_CELLS, method, gamma_r, spp)
        ok = (r.outcome == "periodic" and r.impacts_per_period == ref.impacts_per_period
              and abs(r.transmittance_db - ref.transmittance_db) <= TOL_DB)  # fmt: skip
        print(f"  {method} γ_r {gamma_r} spp {r.steps_per_period}: {r.outcome}, "
              f"{r.transmittance_db}, {impacts(r)}, {wall:.2f} s", flush=True)  # fmt: skip
        if ok or 2 * spp > hi:
            return (r.steps_per_period if ok else -r.steps_per_period), r, wall
        spp *= 2


def accuracy_table(gammas: tuple[float, ...]) -> list[str]:
    rows = ["| γ_r | reference Γ_5 (dB), impacts | euler: steps / period | Γ_5 − ref | ms "
            "| exponential: steps / period | Γ_5 − ref | ms | time ratio euler / exponential |",
            "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    ratios = []
    for g in gammas:
        ref, wall = run(ACC_CELLS, "exponential", g, REF_STEPS)
        print(f"reference γ_r {g}: {ref.outcome}, {ref.transmittance_db}, {impacts(ref)}, "
              f"{wall:.1f} s", flush=True)  # fmt: skip
        if ref.outcome != "periodic":
            rows.append(f"| {g} | {ref.outcome}: not used | | | | | | | |")
            continue
        cells = [f"| {g} | {ref.transmittance_db:.5f}, {impacts(ref)} "]
        walls = []
        for m in METHODS:
            spp, r, w = ladder(m, g, ref)
            walls.append(w)
            mark = str(spp) if spp > 0 else f"none up to {-spp}"
            cells.append(f"| {mark} | {r.transmittance_db - ref.transmittance_db:+.2e} "
                         f"| {1e3 * w:.0f} ")  # fmt: skip
        ratio = walls[0] / walls[1]
        ratios.append(ratio)
        cells.append(f"| {ratio:.1f} |")
        rows.append("".join(cells))
        print(rows[-1], flush=True)
    if ratios:
        rows += ["", f"- geometric mean of the time ratio: {math.exp(np.mean(np.log(ratios))):.1f}"]
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run both parts and write the markdown."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--n20-periods", type=int, default=400,
                    help="period budget of the N = 20 points (default 400)")  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="N up to 5, one accuracy point")
    args = ap.parse_args(argv)
    cells = CELLS[:3] if args.quick else CELLS
    gammas = ACC_GAMMAS[:1] if args.quick else ACC_GAMMAS
    t0 = time.perf_counter()
    for m in METHODS:  # compile (or load) outside the timings
        run(2, m, CELL.gamma_r, max_periods=30)
        run(1, m, CELL.gamma_r, max_periods=30)
    lines = [
        "# Chain cost: euler and exponential against N",
        "",
        f"`python benchmarks/chain_cost.py`; {platform.processor() or platform.machine()}, "
        f"Python {platform.python_version()}, one point at a time on one core.",
        "",
        "The paper's cell (θ 0.3, σ 0.05, γ_s 1, ξ 0.05, 5 modes, `full` coupling, gap 0.1 at "
        f"every stop), γ_r = {CELL.gamma_r}, every point from rest, default settings but "
        f"`max_periods` {MAX_PERIODS}, N = 20 `max_periods` {args.n20_periods} (the periods column "
        "counts every period run, with the engine's confirmation runs, which may pass it).",
        "",
        "## Time per point against N (default steps per period)",
        "",
        *cost_table(args.n20_periods, cells),
        "",
        f"## Equal accuracy at N = {ACC_CELLS}",
        "",
        f"Reference: `exponential` at {REF_STEPS} steps per period. Each method's cheapest "
        f"steps per period on a doubling ladder ({LADDER['euler'][0]}… for euler, "
        f"{LADDER['exponential'][0]}… for exponential) that ends periodic with the reference's "
        f"impacts per period and Γ_5 within {TOL_DB} dB of it.",
        "",
        *accuracy_table(gammas),
        "",
        f"Total run time {time.perf_counter() - t0:.0f} s.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "chain_cost.md").write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
