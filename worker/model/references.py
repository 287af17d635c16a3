"""Closed-form references (docs/model.md §7): the impact-free steady state and the pinned tip."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from worker.model.params import CellParams
from worker.model.system import System, assemble

__all__ = [
    "SteadyState",
    "linear_transmittance_db",
    "pinned_max_re",
    "pinned_transmittance_db",
    "steady_state",
]


@dataclass(frozen=True)
class SteadyState:
    """The impact-free steady state in closed form: ``u(τ) = Re(U e^{iγ_r τ})`` (docs/model.md §7).

    It is the response of the cell without stops (gaps → ∞), and the steady state of any point
    whose tip provably never reaches a stop again.
    """

    params: CellParams
    U: np.ndarray  # complex amplitudes of u = [η_1 … η_n, s]
    kappa: float
    d: np.ndarray
    W: np.ndarray

    @property
    def amplitude(self) -> float:
        """A_s = |U_s|."""
        return float(abs(self.U[-1]))

    @property
    def transmittance_db(self) -> float:
        """Γ = 20 log10(A_s / θγ_s) (Eq. 32)."""
        return 20.0 * math.log10(self.amplitude / self.params.base_scale)

    @property
    def theta_eff(self) -> float:
        """θ_eff from the first harmonics (Eq. 35); for a harmonic motion the phase-portrait
        slope ⟨ṡ_b ṡ⟩/⟨ṡ²⟩ is Re(Ŝ_b/Ŝ) too, so the phase-portrait ratio equals it."""
        ratio = (self.d @ self.U[:-1]) / self.U[-1]
        theta = self.params.theta
        return float((self.kappa - theta * ratio.real) / (1.0 + theta))

    @property
    def tip_amplitude(self) -> float:
        """|Ŵ|: the largest |w_tip| over the orbit."""
        return float(abs(self.W @ self.U))

    def state_at_phase_zero(self) -> np.ndarray:
        """``[u; q]`` at forcing phase 0 (τ a whole number of periods)."""
        g = self.params.gamma_r
        return np.concatenate([self.U.real, (1j * g * self.U).real])


def unit_response(K: np.ndarray, M: np.ndarray, C: np.ndarray, gamma: float,
                  at: int) -> np.ndarray | None:  # fmt: skip
    """``H⁻¹ e_at`` with ``H = K − γ²M + iγC``: the complex response to a unit harmonic force
    on coordinate ``at``; None where H is singular (an undamped resonance)."""
    H = K - gamma * gamma * M + 1j * gamma * C
    e = np.zeros(M.shape[0])
    e[at] = 1.0
    try:
        h = np.linalg.solve(H, e)
    except np.linalg.LinAlgError:
        return None
    # |H⁻¹| >= |H⁻¹ e|: a response 1e13 times the size of what H maps it to is a singular H
    if not np.all(np.isfinite(h)) or np.max(np.abs(h)) * np.max(np.abs(H)) > 1e13:
        return None
    return h


def steady_state(sys_: System, forcing: bool = True) -> SteadyState | None:
    """The closed-form impact-free steady state, or ``None`` at an undamped resonance (the
    forcing frequency on a natural frequency of an undamped system: no steady state)."""
    p = sys_.params
    h = unit_response(sys_.K, sys_.M, sys_.C, p.gamma_r, sys_.ndof - 1)
    if h is None:
        return None
    # F(τ) = e_s (f_sin sin γτ + f_cos cos γτ) = Re(e_s (f_cos - i f_sin) e^{iγτ})
    f = complex(sys_.f_cos, -sys_.f_sin) if forcing else 0j
    return SteadyState(params=p, U=h * f, kappa=sys_.kappa, d=sys_.d, W=sys_.W)


def linear_transmittance_db(p: CellParams) -> float:
    """Γ of the impact-free system (gaps → ∞): the closed-form frequency response (model.md §7)."""
    ss = steady_state(assemble(p))
    if ss is None:
        raise ValueError(f"no steady state: undamped resonance at gamma_r = {p.gamma_r}")
    return ss.transmittance_db


def pinned_transmittance_db(p: CellParams) -> float:
    """Γ with the tip pinned (g̃1 = g̃2 = 0): linear response of the system constrained to Wᵀu = 0.

    The constraint is eliminated with a null-space basis Z of Wᵀ (u = Z v), which is the exact
    constrained linear system.
    """
    sys_ = assemble(p)
    g = p.gamma_r
    Z, Y = _pinned_bases(sys_)
    H = Y.T @ (sys_.K - g * g * sys_.M + 1j * g * sys_.C) @ Z
    e_s = np.zeros(sys_.ndof)
    e_s[-1] = 1.0
    v = np.linalg.solve(H, Y.T @ e_s)
    s_amp = abs((Z @ v)[-1]) * abs(1.0 / p.gamma_s + 2j * p.xi * g)
    return 20.0 * math.log10(s_amp / p.base_scale)


def _pinned_bases(sys_: System) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases ``Z`` of the null space of Wᵀ (``u = Z v`` keeps the tip pinned) and
    ``Y`` of that of Xᵀ (the test space that eliminates the contact force, needed where M and
    X are not symmetric)."""
    _, _, vt = np.linalg.svd(sys_.W[None, :])
    _, _, vtx = np.linalg.svd(sys_.X[None, :])
    return vt[1:].T, vtx[1:].T


def pinned_max_re(sys_: System) -> float:
    """Largest Re λ of the pinned cell's free motion, ``Yᵀ(M Z v̈ + C Z v̇ + K Z v) = 0``: below 0,
    every motion with the tip pinned decays to the pinned steady state (whose Γ is
    :func:`pinned_transmittance_db`)."""
    Z, Y = _pinned_bases(sys_)
    Mr = Y.T @ sys_.M @ Z
    n = Mr.shape[0]
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -np.linalg.solve(Mr, Y.T @ sys_.K @ Z)
    A[n:, n:] = -np.linalg.solve(Mr, Y.T @ sys_.C @ Z)
    return float(np.max(np.linalg.eigvals(A).real))
