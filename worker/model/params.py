"""The non-dimensional parameters of one point (docs/model.md §3)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from worker.checks import check_fields

__all__ = ["COUPLINGS", "MAX_MODES", "CellParams"]

MAX_MODES = 30
COUPLINGS = ("paper", "full")


# Field metadata (worker.checks): the allowed values, written once, read by the validation
# below and by the study schema (which shows them as JSON Schema bounds). ``gt``/``ge`` 0 is
# where the model is defined; the other bounds are the range the project supports: wide enough
# for every shipped study and test, narrow enough that a typo (1e308 for 1.3) is refused instead
# of run. Each ``why`` says how the range was chosen (the study schema shows it).
def _bounds(lo: float, hi: float, why: str, *, zero: bool = False) -> dict[str, Any]:
    if zero:  # zero is meaningful (no damping, a pinned tip)
        return {"ge": 0.0, "le": hi, "why": why}
    return {"gt": 0.0, "ge": lo, "le": hi, "why": why}


_THETA = _bounds(
    1e-6,
    1e4,
    (
        "mass ratio ρAl/m_o: 1e-6 (a beam a millionth of its frame) to 1e4; the solvers are "
        "tested at 1e-3 … 1e3, and paper coupling diverges beyond about 500 anyway"
    ),
)
_SIGMA = _bounds(
    1e-6,
    1e6,
    (
        "beam stiffness; beam mode i sits at β_i²√σ: 1e-6 … 1e6 puts the first mode between "
        "3.5e-3 and 3.5e3 times ω_b (tests use 1e-4 … 1e5); far below, the solvers' matrices "
        "are singular"
    ),
)
_GAMMA_S = _bounds(
    1e-3,
    1e3,
    (
        "frequency ratio ω_b/ω_m: 1e-3 … 1e3 (tests use 0.8 … 10); outside, the mass stiffness "
        "1/(θγ_s²) dwarfs or vanishes against the beam's and the solvers' matrices degenerate"
    ),
)
_GAMMA_R = _bounds(
    1e-6,
    1e3,
    (
        "excitation frequency Ω/ω_b: 1e-6 … 1e3 (studies use 0.1 … 6, tests 1e-4 … 50); "
        "beyond, a point is only its static or inertia-dominated limit (1e308 gave −6180 dB)"
    ),
)
_DAMPING = _bounds(
    0.0,
    10.0,
    ("damping ratio: 0 (undamped) to 10, ten times critical (tests use up to 0.5)"),
    zero=True,
)
_GAP = _bounds(
    0.0,
    1e12,
    (
        "clearance in units of B: 0 (pinned) to 1e12; 'no stops' is a large finite gap (1e6 in "
        "studies; the event solver is verified to 1e12)"
    ),
    zero=True,
)
_RESTITUTION = _bounds(
    0.0,
    1.0,
    (
        "Newton's coefficient of restitution at the stop: 0, the plastic impact of the paper "
        "(the tip meets the stop and stays with it), to 1, an elastic one"
    ),
    zero=True,
)
_MODES = {
    "integer": True,
    "ge": 1,
    "le": MAX_MODES,
    "why": ("beam modes: 1 … 30, the range the mode shapes are exact for"),
}


@dataclass(frozen=True)
class CellParams:
    """Non-dimensional parameters of one point (docs/model.md §3).

    Parameters
    ----------
    theta : float
        Mass ratio ρAl/m_o, in [1e-6, 1e4].
    sigma : float
        Beam stiffness parameter EI/(ρAl⁴ω_b²), in [1e-6, 1e6].
    gamma_s : float
        Inverse mass frequency ω_b/ω_m, in [1e-3, 1e3].
    gamma_r : float
        Excitation frequency Ω/ω_b, in [1e-6, 1e3].
    xi : float
        Damping ratio of the mass's dashpot, in [0, 10]; also the beam's Rayleigh ratio unless
        ``xi_b`` is given.
    g1, g2 : float
        Clearances to stop 1 and stop 2 in units of B, in [0, 1e12]; zero gaps pin the tip.
    modes : int
        Number of beam modes, 1…30.
    coupling : {"paper", "full"}
        Eq. 29 as published, or the consistent Lagrangian coupling.
    xi_b : float or None
        Beam Rayleigh damping ratio, in [0, 10]; ``None`` means ``xi``.
    e1, e2 : float
        Coefficients of restitution at stop 1 and stop 2 (Newton's impact law), in [0, 1];
        0 (default) is the paper's plastic impact (docs/model.md §5).

    Raises
    ------
    ValueError
        A field out of its range, naming the field, the value and what is allowed.
    """

    theta: float = field(metadata=_THETA)
    sigma: float = field(metadata=_SIGMA)
    gamma_s: float = field(metadata=_GAMMA_S)
    gamma_r: float = field(metadata=_GAMMA_R)
    xi: float = field(default=0.05, metadata=_DAMPING)
    g1: float = field(default=0.1, metadata=_GAP)
    g2: float = field(default=0.1, metadata=_GAP)
    modes: int = field(default=5, metadata=_MODES)
    coupling: str = field(default="paper", metadata={"choices": COUPLINGS})
    xi_b: float | None = field(default=None, metadata={**_DAMPING, "optional": True})
    e1: float = field(default=0.0, metadata=_RESTITUTION)
    e2: float = field(default=0.0, metadata=_RESTITUTION)

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def elastic(self) -> bool:
        """Whether an impact rebounds (e1 or e2 > 0): Newton's law at the velocity level."""
        return self.e1 > 0.0 or self.e2 > 0.0

    @property
    def beam_xi(self) -> float:
        """The beam's Rayleigh damping ratio."""
        return self.xi if self.xi_b is None else self.xi_b

    @property
    def base_scale(self) -> float:
        """θγ_s: the base amplitude in units of B (Γ = 20 log10(A_s/θγ_s))."""
        return self.theta * self.gamma_s
