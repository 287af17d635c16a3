"""Time per point: the default solver and the paper's scheme over samples of the three spectra
(what the README's "ms per point" and the ratio between the two measure), and the work the
default does (periods, deterministic: a change of it is a change of the engine, not noise)."""

from __future__ import annotations

import dataclasses
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402

from .cases import SPECTRA, cell, paper_settings  # noqa: E402

#: γ_r of each spectrum's sample: linear, periodic and irregular points among them.
GAMMAS = tuple(float(g) for g in np.linspace(0.3, 6.0, 8))


class DefaultSolver:
    """``event`` with the default settings, every sample point of one spectrum."""

    params = (sorted(SPECTRA),)
    param_names = ["spectrum"]
    timeout = 600

    def setup(self, spectrum: str) -> None:
        warm_up("event", quiet=True)
        self.cells = [cell(spectrum, g) for g in GAMMAS]
        self.settings = SolverSettings()

    def time_points(self, spectrum: str) -> None:
        for p in self.cells:
            simulate_point(p, self.settings)

    def track_periods(self, spectrum: str) -> int:
        return sum(simulate_point(p, self.settings).periods for p in self.cells)

    track_periods.unit = "periods"  # type: ignore[attr-defined]


class PaperScheme:
    """The paper's scheme as published (euler + Lemke, Δτ 1e-3, 150 periods) at three points
    of one spectrum: the reference the default's speed is compared with."""

    params = (sorted(SPECTRA),)
    param_names = ["spectrum"]
    timeout = 600

    def setup(self, spectrum: str) -> None:
        warm_up("euler", quiet=True)
        warm = dataclasses.replace(paper_settings(6.0), max_periods=3, window=1)
        simulate_point(cell(spectrum, 6.0), warm)  # compiles the Lemke path
        self.runs = [(cell(spectrum, g), paper_settings(g)) for g in GAMMAS[1::3]]

    def time_points(self, spectrum: str) -> None:
        for p, s in self.runs:
            simulate_point(p, s)
