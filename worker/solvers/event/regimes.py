"""The three linear regimes of the plastic-impact cell and their exact propagators.

* Regime 0, free flight: ``z = [u; q; c; s]`` with ``(c, s) = f·(cos γτ, sin γτ)``, so the
  harmonic forcing is part of the linear system ``ż = A₀ z`` (``System.augmented_matrix``).
* Regimes 1 and 2, the tip stuck on stop 1 (``w_tip = g̃1``) or stop 2 (``w_tip = -g̃2``): the
  constrained system of docs/model.md §5 in reduced coordinates ``u = u₁ w* + Z v`` (``Z`` spans the
  null space of ``Wᵀ``, ``u₁ = W/|W|²``), tested with ``Y`` (null space of ``Xᵀ``, which
  removes the contact force): ``y = [v; v̇; c; s; w*]``, ``ẏ = A₁ y``. The trailing state is the
  stop's position ``w*`` itself (constant), so the matrix does not depend on the clearance and
  stays well conditioned for clearances up to 1e12 and beyond; both stops share it. The
  contact force ``μ = -λ1 + λ2`` is a linear row on y.

Every regime matrix is diagonalised once per point, ``A = V Λ V⁻¹``; the state at any time in a
regime is ``Re V e^{Λt} V⁻¹ y₀``, kept in reduced form (one eigenvalue of each conjugate pair,
weight 2). Precomputed per regime for one sub-grid interval ``h``: the step map ``Φ = e^{Ah}``,
the rows of the observables, the exact harmonic integrals ``∫ [s; s_b] e^{-iγt} dt`` and the
rows giving ``(ṡ, ṡ_b)`` at four Gauss nodes (the phase-portrait integrals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from worker.memo import ArrayMemo
from worker.model import System
from worker.solvers.event.roots import phi1_each
from worker.solvers.measure import GL_NODES

__all__ = ["EventArrays", "prepare_event", "stuck_matrices"]

MAX_COND = 1e10  # eigenvector condition number beyond which a regime is refused

# rows of observables over a regime's state
R_S = 0
R_SD = 1
R_W = 2
R_WD = 3
R_SB = 4
R_SBD = 5
R_MU = 6
R_MUD = 7
R_W4 = 8
R_MU4 = 9
NROWS = 10


@dataclass(frozen=True)
class EventArrays:
    """Per-regime matrices of one point, stacked (0 free, 1/2 stuck on stop 1/2)."""

    nzr: np.ndarray  # state size per regime
    nk: np.ndarray  # kept eigenvalues per regime (reduced form)
    Phi: np.ndarray  # e^{A h}
    eh: np.ndarray  # e^{λ h} of the kept eigenvalues
    lam: np.ndarray
    V: np.ndarray  # kept eigenvectors, weight folded in (2 for a pair, 1 for a real λ)
    Vi: np.ndarray  # the matching rows of V⁻¹
    wt: np.ndarray  # the weights
    R: np.ndarray  # observable rows over the regime state
    RV: np.ndarray  # R V (reduced)
    Pin: np.ndarray  # free state → stuck state (projection onto the constraint)
    Qout: np.ndarray  # stuck state → free state
    psi: np.ndarray  # (3, 2, nz) complex: ∫₀^h [s; s_b] e^{-iγt} dt = psi·y
    gl: np.ndarray  # (3, 4, 2, nz): (ṡ, ṡ_b) at the Gauss nodes of [0, h] = gl·y
    cond: float


def _null_basis(v: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the null space of vᵀ (N × N-1)."""
    _, _, vt = np.linalg.svd(v[None, :])
    return np.ascontiguousarray(vt[1:].T)


_STUCK = ArrayMemo()  # the constrained system's γ_r-free parts, per cell


def _stuck_blocks(M, C, K, W, X) -> tuple[np.ndarray, ...]:
    """What :func:`stuck_matrices` needs that γ_r does not enter: the null bases, the reduced
    mass inverse and the K, C and forcing blocks of ``A``, and ``Pin``/``Qout``."""
    N = len(W)
    m = N - 1
    Z = _null_basis(W)
    Y = _null_basis(X)
    Mr_inv = np.linalg.inv(Y.T @ M @ Z)
    e_s = np.zeros(N)
    e_s[-1] = 1.0
    u1 = W / (W @ W)  # u = u1 w* + Z v holds the tip at w*
    ny = 2 * N + 1
    AK = -Mr_inv @ (Y.T @ K @ Z)
    AC = -Mr_inv @ (Y.T @ C @ Z)
    fy = Mr_inv @ (Y.T @ e_s)
    Au = -Mr_inv @ (Y.T @ K @ u1)
    Qout = np.zeros((2 * N + 2, ny))
    Qout[:N, :m] = Z
    Qout[:N, 2 * m + 2] = u1
    Qout[N : 2 * N, m : 2 * m] = Z
    Qout[2 * N, 2 * m] = 1.0
    Qout[2 * N + 1, 2 * m + 1] = 1.0
    Pin = np.zeros((ny, 2 * N + 2))
    Pin[:m, :N] = Z.T
    Pin[m : 2 * m, N : 2 * N] = Z.T
    Pin[2 * m, 2 * N] = 1.0
    Pin[2 * m + 1, 2 * N + 1] = 1.0
    return Z, e_s, AK, AC, fy, Au, Qout, Pin


def stuck_matrices(sys_: System) -> tuple[np.ndarray, ...]:
    """The constrained system with the tip held on a stop at ``w_tip = w*`` (docs/model.md §5, §7).

    Returns ``(A, Pin, Qout, mu)``: ``ẏ = A y`` with ``y = [v; v̇; c; s; w*]``; ``y = Pin z``
    maps a free state onto the constraint (the caller sets the last entry to ``w*``);
    ``z = Qout y`` maps back; ``mu`` is the row of the contact force ``μ = -λ1 + λ2`` over y.
    """
    N = sys_.ndof
    m = N - 1
    g = sys_.params.gamma_r
    M, C, K, W, X = sys_.M, sys_.C, sys_.K, sys_.W, sys_.X
    Z, e_s, AK, AC, fy, Au, Qout, Pin = _STUCK.get(
        (M, C, K, W, X), lambda: _stuck_blocks(M, C, K, W, X)
    )
    ny = 2 * N + 1
    A = np.zeros((ny, ny))
    A[:m, m : 2 * m] = np.eye(m)
    A[m : 2 * m, :m] = AK
    A[m : 2 * m, m : 2 * m] = AC
    A[m : 2 * m, 2 * m] = fy * sys_.f_cos
    A[m : 2 * m, 2 * m + 1] = fy * sys_.f_sin
    A[m : 2 * m, 2 * m + 2] = Au
    A[2 * m, 2 * m + 1] = -g
    A[2 * m + 1, 2 * m] = g
    # contact force: M q̇ - h = X μ with q̇ = Z v̈, h = -C q - K u + e_s f
    Qd = Z @ A[m : 2 * m, :]
    H = -C @ Qout[N : 2 * N] - K @ Qout[:N]
    H[:, 2 * m] += e_s * sys_.f_cos
    H[:, 2 * m + 1] += e_s * sys_.f_sin
    mu = X @ (M @ Qd - H) / (X @ X)
    return A, Pin.copy(), Qout.copy(), mu


def _full_rows(sys_: System) -> np.ndarray:
    """Rows s, ṡ, w, ẇ, s_b, ṡ_b over the free state z."""
    N = sys_.ndof
    n = N - 1
    rows = np.zeros((6, 2 * N + 2))
    rows[0, n] = 1.0
    rows[1, N + n] = 1.0
    rows[2, :N] = sys_.W
    rows[3, N : 2 * N] = sys_.W
    rows[4, :n] = sys_.d
    rows[5, N : N + n] = sys_.d
    return rows


def _eig(A: np.ndarray):
    lam, V = np.linalg.eig(A)
    V = V / np.linalg.norm(V, axis=0)  # unit columns keep cond(V) meaningful
    Vi = np.linalg.inv(V)
    cond = float(np.abs(V).sum(axis=0).max() * np.abs(Vi).sum(axis=0).max())  # 1-norm
    return lam.astype(complex), V.astype(complex), Vi.astype(complex), cond


def _reduce(lam, V, Vi):
    """One eigenvalue of each conjugate pair, weight 2 (exact pairs, as LAPACK returns them);
    the full set with weight 1 where the pairing does not reconstruct the identity."""
    keep = lam.imag >= 0.0
    wt = np.where(lam.imag > 0.0, 2.0, 1.0)[keep]
    Vr = V[:, keep] * wt
    Vir = Vi[keep, :]
    eye = np.eye(len(lam))
    if np.sum(lam.imag > 0) != np.sum(lam.imag < 0) or np.max(np.abs((Vr @ Vir).real - eye)) > 1e-9:
        return lam, V, Vi, np.ones(len(lam))
    return lam[keep], Vr, Vir, wt


def prepare_event(sys_: System, n_grid: int) -> EventArrays:
    """Diagonalise the regimes and build the step maps and observable rows."""
    N = sys_.ndof
    nzm = 2 * N + 2
    gamma = sys_.params.gamma_r
    h = 2.0 * math.pi / gamma / n_grid
    full = _full_rows(sys_)
    A1, Pr, Qr, mu = stuck_matrices(sys_)
    nzr = np.array([nzm, nzm - 1, nzm - 1], dtype=np.int64)
    nk = np.zeros(3, dtype=np.int64)
    Phi = np.zeros((3, nzm, nzm))
    lam = np.zeros((3, nzm), dtype=complex)
    V = np.zeros((3, nzm, nzm), dtype=complex)
    Vi = np.zeros((3, nzm, nzm), dtype=complex)
    wt = np.zeros((3, nzm))
    R = np.zeros((3, NROWS, nzm))
    RV = np.zeros((3, NROWS, nzm), dtype=complex)
    psi = np.zeros((3, 2, nzm), dtype=complex)
    gl = np.zeros((3, 4, 2, nzm))
    Pin = np.zeros((2, nzm - 1, nzm))
    Qout = np.zeros((2, nzm, nzm - 1))
    cond = 0.0
    # regime 0 (free) and regime 1 (stuck); regime 2 has regime 1's matrices (the stop's
    # position is a state, not a parameter)
    for r, A in ((0, sys_.augmented_matrix()), (1, A1)):
        nz = A.shape[0]
        lf, Vf, Vif, cr = _eig(A)
        cond = max(cond, cr)
        lr, Vr, Vir, wr = _reduce(lf, Vf, Vif)
        m = len(lr)
        nk[r] = m
        lam[r, :m] = lr
        V[r, :nz, :m] = Vr
        Vi[r, :m, :nz] = Vir
        wt[r, :m] = wr
        Phi[r, :nz, :nz] = ((Vf * np.exp(lf * h)) @ Vif).real
        A2 = A @ A
        A4 = A2 @ A2
        if r == 0:
            R[0, :6] = full
            R[0, R_W4] = full[R_W] @ A4
        else:
            R[r, :6, :nz] = full @ Qr
            R[r, R_MU, :nz] = mu
            R[r, R_MUD, :nz] = mu @ A
            R[r, R_MU4, :nz] = mu @ A4
        RV[r, :, :m] = R[r, :, :nz] @ Vr
        # exact ∫₀^h e^{(λ - iγ)t} dt per mode, then back to rows over y
        phi = phi1_each(np.ascontiguousarray(lf - 1j * gamma, dtype=np.complex128), h)
        psi[r, :, :nz] = R[r, [R_S, R_SB], :nz] @ ((Vf * phi) @ Vif)
        RVf = R[r, [R_SD, R_SBD], :nz] @ Vf
        for j, t in enumerate(GL_NODES * h):
            gl[r, j, :, :nz] = ((RVf * np.exp(lf * t)) @ Vif).real
    for arr in (nk, Phi, lam, V, Vi, wt, R, RV, psi, gl):
        arr[2] = arr[1]
    Pin[:] = Pr
    Qout[:] = Qr
    eh = np.exp(lam * h)
    return EventArrays(nzr, nk, Phi, eh, lam, V, Vi, wt, R, RV, Pin, Qout, psi, gl, cond)
