"""The linear tail as the engine uses it: the proof from a state (``linear.LinearTail``), the
``linear`` or undamped outcome it gives, and the linear reference Γ_lin every result carries.
"""

from __future__ import annotations

import math

import numpy as np

from worker.model import SteadyState
from worker.solvers.engine import config as cfg
from worker.solvers.linear import LinearTail
from worker.solvers.settings import PointResult


class TailProof:
    """The engine's linear tail proof (a mixin of ``loop._Engine``)."""

    def _linear_or_undamped(self) -> tuple[str, object]:
        if self.tail.damped:
            return "linear", None
        return "failed", _undamped_reason(self.tail, self.period)

    def _proves(self, x: np.ndarray) -> bool:
        """The linear tail proof from x (when the settings allow it)."""
        T = 2.0 * math.pi / self.p.gamma_r
        return self.s.linear_tail and self.tail.proves(x, cfg.TAIL_HORIZON * T)


def _undamped_reason(tail: LinearTail, period: int) -> str:
    return (
        f"no steady state: the cell is undamped (largest Re λ = {tail.max_re:.3g}) and from "
        f"period {period} on the tip provably never reaches a stop, so its free vibration "
        "never decays"
    )


def _finite_or_none(v: float | None) -> float | None:
    return v if v is not None and math.isfinite(v) else None


def linear_reference_db(steady: SteadyState | None) -> float | None:
    """Γ_lin: the closed-form transmittance of the cell without stops, or ``None`` where there
    is none (an undamped resonance, or no forcing: a zero amplitude has no dB value)."""
    if steady is None:
        return None
    amp = steady.amplitude
    if not (math.isfinite(amp) and amp > 0.0):
        return None
    return _finite_or_none(steady.transmittance_db)


def _with_reference(res: PointResult, tail: LinearTail) -> PointResult:
    """``res`` with Γ_lin and the impact effect Γ − Γ_lin filled in."""
    lin = linear_reference_db(tail.steady)
    res.transmittance_linear_db = lin
    if lin is None or res.transmittance_db is None:
        res.impact_effect_db = None
    elif res.outcome == "linear":
        res.impact_effect_db = 0.0  # Γ is the closed form itself: exactly no effect
    else:
        res.impact_effect_db = _finite_or_none(res.transmittance_db - lin)
    return res
