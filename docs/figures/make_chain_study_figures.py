"""The shipped chain studies' figures in docs/chains.md.

Writes ``docs/figures/chain-cells-map.png`` and ``docs/figures/chain-graded.png``::

    python docs/figures/make_chain_study_figures.py [--data-dir DIR]

It runs ``chain-cells``, ``chain-graded`` and ``chain-uniform-gaps`` (``service.local.run``;
about three minutes on two cores, nothing when their results are in ``DIR`` already) and
prints the figures' numbers: where Γ_N < 0 starts for each N with and without stops, the
largest impact effect, and the attenuation per cell inside the lattice's stop band.

``chain-cells-map.png``: Γ_N over γ_r × N (left), the impact effect Γ_N − Γ_N,lin (right);
the infinite lattice's stop band edge is the dashed line. ``chain-graded.png``: Γ_5 of the
graded chain (gaps 0.05 … 0.25 from the base) against uniform chains of five cells at 0.05,
0.1, 0.15 and 0.25, and the chain without stops.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py), as the service does

# isort: split
import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.colors import TwoSlopeNorm  # noqa: E402

from service.local import run  # noqa: E402

HERE = Path(__file__).resolve().parent


def edge_lines(ax: plt.Axes, ds: xr.Dataset) -> None:
    """The lattice's stop bands (``lattice_stop_bands``) as dashed edges."""
    for k, (lo, hi) in enumerate(json.loads(ds.attrs["lattice_stop_bands"])):
        for edge in (lo, hi):
            if edge is not None and 0 < edge <= float(ds.gamma_r.max()):
                ax.axvline(edge, color="k", ls="--", lw=0.8,
                           label="stop band edge (N → ∞)" if k == 0 else None)  # fmt: skip


def map_figure(ds: xr.Dataset, out: Path) -> None:
    """Γ_N and the impact effect over γ_r × N."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    g, n = ds.gamma_r.values, ds.cells.values
    im = left.pcolormesh(g, n, ds.transmittance_db.values, shading="nearest", cmap="viridis",
                         vmin=-60, vmax=20)  # fmt: skip
    fig.colorbar(im, ax=left, label="Γ_N (dB)", extend="min")
    left.contour(g, n, ds.transmittance_db.values, levels=[0.0], colors="w", linewidths=0.8)
    left.contour(g, n, ds.transmittance_linear_db.values, levels=[0.0], colors="w",
                 linewidths=0.8, linestyles="--")  # fmt: skip
    left.set(xlabel="γ_r", ylabel="cells N",
             title="Γ_N at the last cell (white: 0 dB; dashed: without stops)")  # fmt: skip
    eff = ds.impact_effect_db.values
    im = right.pcolormesh(g, n, eff, shading="nearest", cmap="RdBu_r",
                          norm=TwoSlopeNorm(0.0, vmin=-15, vmax=10))  # fmt: skip
    fig.colorbar(im, ax=right, label="Γ_N − Γ_N,lin (dB)")
    edge_lines(right, ds)
    right.set(xlabel="γ_r", title="what the stops change (blue: more attenuation)")
    right.legend(fontsize=7, loc="upper right")
    for ax in (left, right):
        ax.title.set_fontsize(9)
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    print(f"wrote {out}")


def graded_figure(graded: xr.Dataset, uniform: xr.Dataset, cells: xr.Dataset, out: Path) -> None:
    """Γ_5 of the graded chain against uniform chains of five cells."""
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    g = graded.gamma_r.values
    curves = {0.05: uniform.sel(gap=0.05), 0.1: cells.sel(cells=5),
              0.15: uniform.sel(gap=0.15), 0.25: uniform.sel(gap=0.25)}  # fmt: skip
    cmap = matplotlib.colormaps["viridis"]
    for k, (gap, ds) in enumerate(curves.items()):
        ax.plot(g, ds.transmittance_db.values, lw=0.9, color=cmap(k / 4),
                label=f"uniform, gap {gap:g}")  # fmt: skip
    ax.plot(g, graded.transmittance_db.values, lw=1.6, color="C3", marker=".", ms=3,
            label="graded, gaps 0.05 … 0.25")  # fmt: skip
    ax.plot(g, graded.transmittance_linear_db.values, lw=0.8, ls="--", color="0.3",
            label="without stops")  # fmt: skip
    edge_lines(ax, graded)
    ax.axhline(0.0, color="k", lw=0.6, ls=":")
    ax.set(xlabel="γ_r", ylabel="Γ_5 (dB)", ylim=(-80, 25),
           title="five cells: a graded chain and uniform ones")  # fmt: skip
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    print(f"wrote {out}")


def report(ds: xr.Dataset) -> None:
    """Where Γ_N < 0 starts, the largest impact effect and the decay per cell."""
    g = ds.gamma_r.values
    for n in ds.cells.values:
        row = ds.sel(cells=n)
        t, lin, eff = (row[v].values for v in ("transmittance_db", "transmittance_linear_db",
                                                "impact_effect_db"))  # fmt: skip
        k = int(np.nanargmin(eff))
        print(f"N = {int(n):2d}: Γ_N < 0 from γ_r {g[t < 0].min():.2f} ({g[lin < 0].min():.2f} "
              f"without stops); largest drop {eff[k]:+.1f} dB at γ_r {g[k]:.2f}")  # fmt: skip
    per = ds.cell_transmittance_db.sel(cells=10, gamma_r=2.5, method="nearest").values
    print(f"N = 10, γ_r 2.5 (inside the stop band): Γ_j - Γ_(j-1) = "
          f"{np.round(np.diff(per), 1).tolist()} dB")  # fmt: skip


def main() -> None:
    """Run the studies (or read their results) and draw the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, default=Path("data"))
    args = ap.parse_args()
    cells, graded, uniform = (run(name, data_dir=args.data_dir, progress=True)
                              for name in ("chain-cells", "chain-graded",
                                           "chain-uniform-gaps"))  # fmt: skip
    report(cells)
    map_figure(cells, HERE / "chain-cells-map.png")
    graded_figure(graded, uniform, cells, HERE / "chain-graded.png")


if __name__ == "__main__":
    main()
