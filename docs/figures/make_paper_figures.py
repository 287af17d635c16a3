"""Figures 5 and 6 of the paper made from this project's shipped studies.

Runs (or reuses, from the data folder) ``paper-fig5-theta1``, ``paper-fig5-second-band``,
``paper-fig6-effective-mass`` and ``paper-fig6-theta-sweep`` and writes
``docs/figures/paper-fig5.png`` and ``docs/figures/paper-fig6.png`` (docs/paper-comparison.md)::

    python docs/figures/make_paper_figures.py [--data DIR] [--workers N]

About two minutes on two cores serially (the default; results already in the data root, e.g.
from ``impactcell run``, are reused); ``--workers N`` runs the studies on an embedded dask
cluster instead. Irregular, may-be-transient and unsettled points are marked, so jumps in the
curves can be told from data.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py), as the service does

# isort: split
import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402

from service.studies.runner import run_study  # noqa: E402
from service.studies.schema import load_study  # noqa: E402
from service.studies.shipped import shipped_studies  # noqa: E402

HERE = Path(__file__).resolve().parent

#: The paper's Figure 6 values (Section 4.3): γ_r → average θ_eff.
PAPER_FIG6 = {0.85: 0.5213, 2.35: 1.1072, 3.9: -1.9462, 4.15: -0.1826, 5.8: -0.1424}
#: The paper's "second propagation band" (Section 4.2).
PAPER_BAND = (2.2, 3.0)
#: Outcome flags of a results dataset (``outcome`` is a CF flag variable).
IRREGULAR, UNSETTLED = 2, 3


def results(name: str, data: Path, workers: int | None) -> xr.Dataset:
    """The results dataset of a shipped study, computed into ``data`` unless already there."""
    study = load_study(shipped_studies()[name])
    summary = run_study(study, data, serial=workers is None, workers=workers)
    print(f"{name}: {summary.points} points, {summary.wall_s:.1f} s, {summary.path}")
    return xr.load_dataset(summary.path).squeeze(drop=True)


def mark_outcomes(
    ax: Axes, x: np.ndarray, y: np.ndarray, outcome: np.ndarray, color: str,
    transient: np.ndarray | None = None,
) -> None:  # fmt: skip
    """Irregular points as crosses, unsettled ones as open squares, points whose impacts may
    still die out (the ``may_be_transient`` flag) circled, in the line's colour."""
    for flag, marker, mfc in ((IRREGULAR, "x", color), (UNSETTLED, "s", "none")):
        k = outcome == flag
        ax.plot(x[k], y[k], ls="none", marker=marker, ms=2.5, mew=0.6, mfc=mfc, color=color)
    if transient is not None:
        k = transient.astype(bool)
        ax.plot(x[k], y[k], ls="none", marker="o", ms=5, mew=0.6, mfc="none", color=color)


def fig5_panel(ax: Axes, ds: xr.Dataset, title: str) -> None:
    """Γ over γ_r for every gap, the impact-free reference, the paper's second band."""
    x = ds.gamma_r.values
    ax.axvspan(*PAPER_BAND, color="0.85", lw=0, label="paper: 2nd propagation band")
    cmap = matplotlib.colormaps["viridis"]
    for k, gap in enumerate(ds.gap.values):
        p = ds.sel(gap=gap)
        color = cmap(k / max(ds.sizes["gap"] - 1, 1) * 0.9)
        g = p.transmittance_db.values
        ax.plot(x, g, lw=1.0, color=color, label=f"g̃ = {gap:g}")
        flag = p.may_be_transient.values if "may_be_transient" in p else None
        mark_outcomes(ax, x, g, p.outcome.values, color, flag)
        impacting = np.flatnonzero(p.outcome.values != 0)
        if impacting.size:  # last frequency with impacts: beyond it the curves coincide
            ax.axvline(x[impacting.max()], color=color, lw=0.6, ls=":")
    lin = ds.sel(gap=ds.gap.values[0]).transmittance_linear_db.values
    ax.plot(x, lin, color="k", lw=0.8, ls="--", label="no stops (closed form)")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.plot([], [], "kx", ms=3, label="irregular")
    ax.plot([], [], "ks", ms=3, mfc="none", label="unsettled")
    ax.plot([], [], "ko", ms=5, mfc="none", mew=0.6, label="may be transient")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("γ_r = Ω/ω_b")
    ax.set_ylabel("transmittance Γ (dB)")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize=6.5, loc="upper right", ncols=2)


def figure5(theta1: xr.Dataset, second: xr.Dataset, out: Path) -> None:
    """Figure 5(a) for the Figure 6 cell (σ 0.05) and the σ 0.02 variant, side by side."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True, layout="constrained")
    fig5_panel(axes[0], theta1, "θ = 1, σ = 0.05, ξ = 0.015 (the Figure 6 cell)")
    fig5_panel(axes[1], second, "θ = 1, σ = 0.02, ξ = 0.015 (softer beam)")
    fig.suptitle(
        "Figure 5(a) from paper-fig5-theta1 and paper-fig5-second-band (γ_s = 1, paper coupling, "
        "5 modes); dotted: last γ_r with impacts",
        fontsize=9,
    )
    fig.savefig(out, dpi=130)
    plt.close(fig)


def figure6(curve: xr.Dataset, sweep: xr.Dataset, out: Path) -> None:
    """θ_eff over γ_r at θ = 1 (with θ_ps) and the paper's five values; θ_eff over θ at those
    five."""
    fig, (ax, bx) = plt.subplots(
        1, 2, figsize=(11, 4.2), layout="constrained", gridspec_kw={"width_ratios": [3, 2]}
    )
    x = curve.gamma_r.values
    h, s = curve.theta_eff.values, curve.theta_eff_slope.values
    ax.plot(x, h, color="C0", lw=1.1, label="θ_eff, effective mass (first harmonic, Eq. 35)")
    ax.plot(x, s, color="C1", lw=0.9, ls="--", label="θ_ps, phase-portrait slope (all harmonics)")
    mark_outcomes(ax, x, h, curve.outcome.values, "C0")
    ax.plot(list(PAPER_FIG6), list(PAPER_FIG6.values()), "r*", ms=9, label="paper (average)")
    for g, v in PAPER_FIG6.items():
        ax.annotate(f"{v:+.4f}", (g, v), textcoords="offset points", xytext=(4, -10),
                    fontsize=7, color="r")  # fmt: skip
    ax.axhline(0.0, color="k", lw=0.6)
    ax.plot([], [], "kx", ms=3, label="irregular")
    ax.set_xlabel("γ_r = Ω/ω_b")
    ax.set_ylabel("effective mass ratio θ_eff")
    ax.set_title("paper-fig6-effective-mass: θ = 1, ξ = 0.015, σ = 0.05, g̃ = 0.1", fontsize=9)
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize=7, loc="upper right")

    theta = sweep.theta.values
    for k, g in enumerate(sweep.gamma_r.values):
        bx.plot(theta, sweep.theta_eff.sel(gamma_r=g).values, marker="o", ms=3, color=f"C{k}",
                label=f"γ_r = {g:g}")  # fmt: skip
        bx.plot([1.0], [PAPER_FIG6[round(float(g), 2)]], "*", ms=9, color=f"C{k}")
    bx.axhline(0.0, color="k", lw=0.6)
    bx.set_xlabel("mass ratio θ")
    bx.set_ylabel("effective mass θ_eff (first harmonic)")
    bx.set_title("paper-fig6-theta-sweep (stars: the paper at θ = 1)", fontsize=9)
    bx.grid(True, lw=0.4, alpha=0.5)
    bx.legend(fontsize=7, loc="lower left")
    fig.savefig(out, dpi=130)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    """Run the studies (or reuse their results) and write both figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        type=Path,
        default=Path("data"),
        help="data root of the runs, as `impactcell run --out` (default: %(default)s)",
    )
    ap.add_argument(
        "--workers",
        type=int,
        default=None,
        help="run on an embedded dask cluster of N workers (default: serial)",
    )
    ap.add_argument("--out", type=Path, default=HERE, help="folder of the PNGs")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    figure5(
        results("paper-fig5-theta1", args.data, args.workers),
        results("paper-fig5-second-band", args.data, args.workers),
        args.out / "paper-fig5.png",
    )
    figure6(
        results("paper-fig6-effective-mass", args.data, args.workers),
        results("paper-fig6-theta-sweep", args.data, args.workers),
        args.out / "paper-fig6.png",
    )
    print(f"wrote {args.out / 'paper-fig5.png'} and {args.out / 'paper-fig6.png'}")


if __name__ == "__main__":
    main()
