"""The point-engine benchmark's three spectra and the paper's scheme as published, shared by the
asv suite and ``benchmarks/point_engine.py`` (no timing here)."""

from __future__ import annotations

import math

import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
from worker.model import CellParams
from worker.simulate import SolverSettings

#: Three spectra (σ 0.05, γ_s 1, 5 modes; γ_r varies): cells the README's speed figures use.
SPECTRA = {
    "A": dict(coupling="paper", theta=0.3, xi=0.05, g1=0.1, g2=0.1),
    "B": dict(coupling="paper", theta=1.0, xi=0.02, g1=0.5, g2=0.5),
    "C": dict(coupling="full", theta=0.3, xi=0.05, g1=0.3, g2=0.3),
}
#: The paper's scheme: semi-implicit Euler with Lemke's algorithm, Δτ 1e-3, a fixed budget.
PAPER_DT = 1e-3
PAPER_PERIODS = 150
PAPER_WINDOW = 20


def cell(case: str, gamma_r: float) -> CellParams:
    """The cell of spectrum ``case`` at ``gamma_r``."""
    return CellParams(sigma=0.05, gamma_s=1.0, gamma_r=float(gamma_r), modes=5, **SPECTRA[case])


def paper_settings(gamma_r: float) -> SolverSettings:
    """The paper's scheme as published at ``gamma_r`` (its step fixed in time, not per period)."""
    spp = round(2.0 * math.pi / gamma_r / PAPER_DT)
    return SolverSettings(
        method="euler", lcp="lemke", steps_per_period=spp, max_periods=PAPER_PERIODS,
        window=PAPER_WINDOW, early_stop=False,
    )  # fmt: skip
