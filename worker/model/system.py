"""The assembled equations of motion: M, C, K, W, X and the forcing (docs/model.md §4)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from worker.model.modal import betas, mode_means, tip_values
from worker.model.params import CellParams

__all__ = ["System", "assemble", "rayleigh_constants"]


@dataclass(frozen=True)
class System:
    """Assembled matrices of ``M ü + C u̇ + K u = F(τ) + X(-λ1 + λ2)``.

    ``u = [η_1 … η_n, s]``. ``F(τ) = e_s (f_sin sin γ_r τ + f_cos cos γ_r τ)``.
    """

    params: CellParams
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    W: np.ndarray  # gap gradient: w_tip = Wᵀu
    X: np.ndarray  # contact force direction
    d: np.ndarray  # mode means: s_b = dᵀη
    f_sin: float
    f_cos: float
    Minv: np.ndarray = field(repr=False)

    @property
    def ndof(self) -> int:
        """Number of generalised coordinates (modes + 1)."""
        return self.M.shape[0]

    @property
    def G(self) -> float:
        """Wᵀ M⁻¹ X > 0: the tip's inverse effective mass for a contact impulse."""
        return float(self.W @ self.Minv @ self.X)

    @property
    def kappa(self) -> float:
        """Rigid-body momentum factor of the effective mass (1 paper, 1 + θ full)."""
        return 1.0 if self.params.coupling == "paper" else 1.0 + self.params.theta

    def omega_max(self) -> float:
        """Largest undamped natural frequency of the free system, sqrt(max eig M⁻¹K)."""
        ev = np.linalg.eigvals(self.Minv @ self.K)
        return float(np.sqrt(np.max(np.abs(ev))))

    def state_matrix(self) -> np.ndarray:
        """First-order matrix A of ``ẋ = A x`` with ``x = [u; q]``."""
        n = self.ndof
        A = np.zeros((2 * n, 2 * n))
        A[:n, n:] = np.eye(n)
        A[n:, :n] = -self.Minv @ self.K
        A[n:, n:] = -self.Minv @ self.C
        return A

    def augmented_matrix(self) -> np.ndarray:
        """``ż = A_aug z`` with ``z = [u; q; cos γ_r τ; sin γ_r τ]``: the harmonic forcing
        carried in the state, so free flight is one linear system (no particular solution
        needed, exact even at an undamped resonance)."""
        n = self.ndof
        g = self.params.gamma_r
        A = np.zeros((2 * n + 2, 2 * n + 2))
        A[: 2 * n, : 2 * n] = self.state_matrix()
        fs = self.Minv[:, -1]  # M⁻¹ e_s
        A[n : 2 * n, 2 * n] = fs * self.f_cos
        A[n : 2 * n, 2 * n + 1] = fs * self.f_sin
        A[2 * n, 2 * n + 1] = -g
        A[2 * n + 1, 2 * n] = g
        return A


def rayleigh_constants(omegas: np.ndarray, xi_b: float) -> tuple[float, float]:
    """Rayleigh α_R, β_R fixed at modes 1 and min(5, n) (docs/model.md §4)."""
    if len(omegas) == 1:
        return 2.0 * xi_b * omegas[0], 0.0
    wa, wb = omegas[0], omegas[min(5, len(omegas)) - 1]
    return 2.0 * xi_b * wa * wb / (wa + wb), 2.0 * xi_b / (wa + wb)


def assemble(p: CellParams) -> System:
    """Build M, C, K, W, X for ``p`` (docs/model.md §4).

    The matrices do not depend on γ_r, so the points of one spectrum share them (computed once
    per process and cell; callers never modify a ``System``'s arrays)."""
    # -0.0 == 0.0 as a key, yet a damping of -0.0 gives -0.0 entries: the signs are part of the
    # key, so a hit is the computation's own result, bit for bit
    key = (p.modes, p.coupling, p.theta, p.sigma, p.gamma_s, p.xi, p.beam_xi,
           math.copysign(1.0, p.xi), math.copysign(1.0, p.beam_xi))  # fmt: skip
    M, C, K, W, X, d, Minv = _matrices(key)
    return System(
        params=p,
        M=M,
        C=C,
        K=K,
        W=W,
        X=X,
        d=d,
        f_sin=1.0 / p.gamma_s,
        f_cos=2.0 * p.xi * p.gamma_r,
        Minv=Minv,
    )


@functools.lru_cache(maxsize=16)
def _matrices(key: tuple) -> tuple[np.ndarray, ...]:
    n, coupling, theta, sigma, gamma_s, xi, beam_xi = key[:7]
    b = betas(n)
    d = mode_means(n)
    tip = tip_values(n)
    N = n + 1

    M = np.zeros((N, N))
    M[:n, :n] = np.eye(n)
    M[:n, n] = -d
    if coupling == "paper":
        M[n, n] = 1.0 / theta
    else:
        M[n, :n] = -d
        M[n, n] = 1.0 / theta + 1.0

    k_beam = sigma * b**4
    K = np.diag(np.append(k_beam, 1.0 / (theta * gamma_s**2)))

    omegas = b**2 * math.sqrt(sigma)
    alpha_r, beta_r = rayleigh_constants(omegas, beam_xi)
    C = np.zeros((N, N))
    C[:n, :n] = np.diag(alpha_r + beta_r * k_beam)
    C[n, n] = 2.0 * xi / (theta * gamma_s)

    W = np.append(tip, 0.0)
    X = np.append(tip, 1.0) if coupling == "paper" else W.copy()

    # M is block-triangular (paper) or symmetric positive definite (full); a dense inverse of a
    # (n+1)-square matrix is exact enough and is computed once per cell.
    Minv = np.linalg.inv(M)
    return M, C, K, W, X, d, Minv


# --------------------------------------------------------------------------- linear references
