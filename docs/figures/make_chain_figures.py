"""The figure of docs/chains.md: chains of N cells, linear and impacting.

Writes ``docs/figures/chain-stop-bands.png``::

    python docs/figures/make_chain_figures.py [--num 40]

Left: Γ_N,lin over γ_r for N = 1, 2, 5, 10 (closed forms, ``full`` coupling, the paper's cell
θ 0.3, σ 0.05, γ_s 1, ξ 0.05) with the infinite lattice's stop bands shaded. Right: the
impacting chain (method ``euler``, gap 0.1 in every cell) against its Γ_N,lin for N = 1 and
N = 3 at ``--num`` frequencies. Under a minute on one core once the kernels are compiled; it
prints what the right panel shows (where and by how much the impacts lower Γ_N).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py), as the service does

# isort: split
import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402

from worker.model import CellParams  # noqa: E402
from worker.model.chain import (  # noqa: E402
    ChainParams,
    chain_linear_transmittance_db,
    stop_bands,
)
from worker.simulate import SolverSettings, simulate_chain_point  # noqa: E402

HERE = Path(__file__).resolve().parent
GAMMA_R = (0.3, 3.0)
#: The paper's cell (Section 4), in ``full`` coupling; gap 0.1 for the impacting chains.
CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, xi=0.05, g1=0.1, g2=0.1,
                  coupling="full")  # fmt: skip
#: Outcome of a point -> marker (impact-free points carry none).
MARKERS = {"irregular": "x", "unsettled": "s"}


def chain(n: int, gamma_r: float) -> ChainParams:
    """N copies of :data:`CELL` at frequency ``gamma_r``."""
    return ChainParams(dataclasses.replace(CELL, gamma_r=gamma_r), n)


def shade_bands(ax: Axes) -> None:
    """The infinite lattice's stop bands inside the plotted range, in grey."""
    for k, (lo, hi) in enumerate(stop_bands(CELL)):
        if hi > GAMMA_R[0] and lo < GAMMA_R[1]:
            ax.axvspan(max(lo, GAMMA_R[0]), min(hi, GAMMA_R[1]), color="0.88", lw=0,
                       label="stop bands (N → ∞)" if k == 0 else None)  # fmt: skip


def linear_panel(ax: Axes) -> None:
    """Γ_N,lin over γ_r for N = 1, 2, 5, 10."""
    x = np.linspace(*GAMMA_R, 600)
    shade_bands(ax)
    cmap = matplotlib.colormaps["viridis"]
    for k, n in enumerate((1, 2, 5, 10)):
        y = [chain_linear_transmittance_db(chain(n, float(g)))[-1] for g in x]
        ax.plot(x, y, lw=1.0, color=cmap(k / 3 * 0.9), label=f"N = {n}")
    ax.set(xlabel="γ_r", ylabel="Γ_N,lin (dB)", title="linear chains (closed form)")
    ax.legend(fontsize=7, loc="lower left")


def impact_panel(ax: Axes, num: int) -> None:
    """The impacting chain (euler, gap 0.1) against Γ_N,lin for N = 1 and N = 3."""
    x = np.linspace(*GAMMA_R, num)
    settings = SolverSettings(method="euler")
    shade_bands(ax)
    for n, color in ((1, "C0"), (3, "C3")):
        t0 = time.perf_counter()
        rs = [simulate_chain_point(chain(n, float(g)), settings) for g in x]
        wall = time.perf_counter() - t0
        y = np.array([np.nan if r.failed else r.transmittance_db for r in rs])
        lin = np.array([chain_linear_transmittance_db(chain(n, float(g)))[-1] for g in x])
        ax.plot(x, lin, lw=0.8, ls="--", color=color, label=f"N = {n}, no stops")
        ax.plot(x, y, lw=1.0, marker=".", ms=3, color=color, label=f"N = {n}, gap 0.1")
        for outcome, marker in MARKERS.items():
            k = np.array([r.outcome == outcome for r in rs])
            ax.plot(x[k], y[k], ls="none", marker=marker, ms=4, mew=0.6, mfc="none", color=color)
        report(n, x, y, lin, rs, wall)
    ax.set(xlabel="γ_r", ylabel="Γ_N (dB)", title="impacting chains (euler, gap 0.1)")
    ax.legend(fontsize=7, loc="lower left")


def report(n: int, x: np.ndarray, y: np.ndarray, lin: np.ndarray, rs: list, wall: float) -> None:
    """Print where the impacts lower Γ_N below the linear chain, and by how much."""
    effect = y - lin
    failed = sum(r.failed for r in rs)
    outcomes = {o: sum(r.outcome == o for r in rs) for o in ("linear", "periodic", "irregular",
                                                            "unsettled")}  # fmt: skip
    print(f"N = {n}: {len(x)} points in {wall:.1f} s, {failed} failed, outcomes {outcomes}")
    for g, e, yy, ll, r in zip(x, effect, y, lin, rs, strict=True):
        if abs(e) > 0.05:
            print(f"  γ_r {g:.3f}: Γ_N {yy:8.3f}  Γ_N,lin {ll:8.3f}  effect {e:+7.3f} dB  "
                  f"({r.outcome})")  # fmt: skip
    k = int(np.nanargmin(effect))
    print(f"  largest drop: {effect[k]:+.2f} dB at γ_r {x[k]:.3f}; largest rise "
          f"{np.nanmax(effect):+.2f} dB at γ_r {x[int(np.nanargmax(effect))]:.3f}")  # fmt: skip


def main() -> None:
    """Draw the figure."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num", type=int, default=40, help="frequencies of the impacting chains")
    ap.add_argument("--out", type=Path, default=HERE / "chain-stop-bands.png")
    args = ap.parse_args()
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8))
    linear_panel(left)
    impact_panel(right, args.num)
    fig.tight_layout()
    fig.savefig(args.out, dpi=130)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
