"""Make docs/figures/table1-gamma.png: our Γ(f) for the Table 1 cell (docs/experiment.md).

    python docs/figures/make_table1_gamma.py [--results results.nc] [--out docs/figures]

Runs the shipped study ``experiment-table1`` (60 points, seconds once the kernels are
compiled) in this process, or reads its results file (``impactcell run experiment-table1``
writes one), and plots the transmittance against frequency for the three assumed base
amplitudes, with the outer mass's resonance f_m and, when the dataset has it, the impact-free
reference Γ_lin. Points that did not end in a proven steady state (irregular: a mean over
windows; unsettled) are drawn hollow, so that a jump there is not read as a clean feature.
The paper's measured Figure 4 points are not plotted: the paper does not publish them.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from service.studies.dataset import open_results  # noqa: E402
from service.studies.runner import run_study  # noqa: E402
from service.studies.schema import load_study  # noqa: E402
from service.studies.shipped import resolve_study_file  # noqa: E402
from service.studies.variables import outcome_names  # noqa: E402
from worker.physical import PhysicalCell  # noqa: E402

HERE = Path(__file__).resolve().parent


def results(path: Path | None) -> xr.Dataset:
    """The study's dataset: read from ``path``, or computed now in this process."""
    if path is not None:
        return open_results(path)
    study = load_study(resolve_study_file("experiment-table1"))
    with tempfile.TemporaryDirectory() as root:
        summary = run_study(study, root, serial=True)
        return open_results(summary.path)


def plot(ds: xr.Dataset, out: Path) -> Path:
    """Γ(f), one curve per base amplitude; hollow markers where no steady state was proven."""
    fig, ax = plt.subplots(figsize=(7.0, 4.2), constrained_layout=True)
    outcomes = outcome_names(ds["outcome"])
    colors = ("tab:blue", "tab:orange", "tab:green")
    f = ds["frequency_hz"].values
    for i, u in enumerate(ds["base_amplitude_m"].values):
        g = ds["transmittance_db"].isel(base_amplitude_m=i).values
        kind = outcomes[i]
        proven = np.isin(kind, ("linear", "periodic"))
        c = colors[i % len(colors)]
        g_tilde = float(np.atleast_1d(ds["g1"].isel(base_amplitude_m=i).values)[0])
        label = f"U_g = {u * 1e3:g} mm (g̃ = {g_tilde:.2f})"
        ax.plot(f, g, "-", color=c, lw=1.2, label=label)
        ax.plot(f[proven], g[proven], "o", color=c, ms=4)
        ax.plot(f[~proven], g[~proven], "o", mfc="none", color=c, ms=5)
    if "transmittance_linear_db" in ds:
        lin = ds["transmittance_linear_db"].isel(base_amplitude_m=0).values
        ax.plot(f, lin, "k--", lw=1.0, label="no stops (Γ_lin)")
    cell = PhysicalCell.table1(damping_ratio=0.03, base_amplitude_m=1e-3)
    ax.axvline(cell.f_m_hz, color="0.6", lw=0.8, ls=":")
    ax.text(cell.f_m_hz, ax.get_ylim()[0], f" f_m = {cell.f_m_hz:.2f} Hz", color="0.4",
            va="bottom", fontsize=8)  # fmt: skip
    ax.plot([], [], "o", mfc="none", color="0.3", label="irregular/unsettled (hollow)")
    ax.axhline(0.0, color="0.8", lw=0.6)
    ax.set_xlabel("excitation frequency f (Hz)")
    ax.set_ylabel("transmittance Γ (dB)")
    ax.set_title("Table 1 cell, ξ = 0.03 (assumed), gap 1 mm: study experiment-table1",
                 fontsize=10)  # fmt: skip
    ax.legend(fontsize=8)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "table1-gamma.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    """Command line: ``--results`` to reuse a results file, ``--out`` for the folder."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, help="results.nc of experiment-table1")
    ap.add_argument("--out", type=Path, default=HERE, help="output folder")
    args = ap.parse_args(argv)
    print(plot(results(args.results), args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
