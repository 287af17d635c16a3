"""The non-dimensional parameters of one point (docs/model.md §3)."""

from __future__ import annotations

from dataclasses import dataclass, field

from worker.checks import check_fields

__all__ = ["COUPLINGS", "MAX_MODES", "CellParams"]

MAX_MODES = 30
COUPLINGS = ("paper", "full")

# Field metadata (worker.checks): the allowed values, written once, read by the validation
# below and by the study schema.
_POS = {"gt": 0.0}
_NONNEG = {"ge": 0.0}


@dataclass(frozen=True)
class CellParams:
    """Non-dimensional parameters of one point (docs/model.md §3).

    Parameters
    ----------
    theta, sigma, gamma_s, gamma_r : float
        Mass ratio, beam stiffness parameter, inverse mass frequency, excitation frequency (> 0).
    xi : float
        Damping ratio of the mass's dashpot (>= 0); also the beam's Rayleigh ratio unless
        ``xi_b`` is given.
    g1, g2 : float
        Clearances to stop 1 and stop 2 (>= 0); zero gaps pin the tip.
    modes : int
        Number of beam modes, 1…30.
    coupling : {"paper", "full"}
        Eq. 29 as published, or the consistent Lagrangian coupling.
    xi_b : float or None
        Beam Rayleigh damping ratio; ``None`` means ``xi``.

    Raises
    ------
    ValueError
        A field out of its range, naming the field, the value and what is allowed.
    """

    theta: float = field(metadata=_POS)
    sigma: float = field(metadata=_POS)
    gamma_s: float = field(metadata=_POS)
    gamma_r: float = field(metadata=_POS)
    xi: float = field(default=0.05, metadata=_NONNEG)
    g1: float = field(default=0.1, metadata=_NONNEG)
    g2: float = field(default=0.1, metadata=_NONNEG)
    modes: int = field(default=5, metadata={"integer": True, "ge": 1, "le": MAX_MODES})
    coupling: str = field(default="paper", metadata={"choices": COUPLINGS})
    xi_b: float | None = field(default=None, metadata={**_NONNEG, "optional": True})

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def beam_xi(self) -> float:
        """The beam's Rayleigh damping ratio."""
        return self.xi if self.xi_b is None else self.xi_b

    @property
    def base_scale(self) -> float:
        """θγ_s: the base amplitude in units of B (Γ = 20 log10(A_s/θγ_s))."""
        return self.theta * self.gamma_s
