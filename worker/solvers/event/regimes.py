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

Each regime matrix is block triangular, ``[[A, B], [0, Ω]]``: the cell's own dynamics ``A``
(γ_r does not enter it) driven by the forcing oscillator ``Ω`` (eigenvalues ``±iγ_r``, and 0 for
``w*``). Its eigen-decomposition ``V Λ V⁻¹`` is built from that of ``A``, computed once per cell
and process (``worker.memo``): the oscillator's eigenvectors are ``[(μ - A)⁻¹ B e; e]`` and
``V⁻¹`` follows from the block form, so a point only adds what γ_r changes. The kernel
(``kernel.py``) carries a regime's state as its modal coefficients ``α = V⁻¹ y`` in reduced
form (one eigenvalue of each conjugate pair, weight 2): a step is ``α ∘ e^{λt}``, an
observable is ``Re Σ RV_k α_k``. Precomputed per regime for one sub-grid interval ``h``:
``e^{λh}``, the observable rows over α, the bound weights ``|RV_k| |λ_k|⁴`` of the Hermite error
of the gap (the contact force when stuck), the exact harmonic integrals and ``(ṡ, ṡ_b)`` at
four Gauss nodes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from worker.memo import ArrayMemo
from worker.model import System
from worker.solvers.event.roots import phi1_each
from worker.solvers.measure import GL_NODES

__all__ = ["EventArrays", "eigen", "prepare_event", "stuck_matrices"]

MAX_COND = 1e10  # eigenvector condition number beyond which a regime is refused

# rows of observables over a regime's state (and, times V, over its modal coefficients)
R_S = 0
R_SD = 1
R_W = 2
R_WD = 3
R_SB = 4
R_SBD = 5
R_MU = 6
R_MUD = 7
NROWS = 8


@dataclass(frozen=True)
class EventArrays:
    """Per-regime matrices of one point, stacked (0 free, 1/2 stuck on stop 1/2)."""

    nzr: np.ndarray  # state size per regime
    nk: np.ndarray  # kept eigenvalues per regime (reduced form)
    eh: np.ndarray  # e^{λ h} of the kept eigenvalues
    lam: np.ndarray
    V: np.ndarray  # kept eigenvectors, weight folded in (2 for a pair, 1 for a real λ)
    Vi: np.ndarray  # the matching rows of V⁻¹
    R: np.ndarray  # observable rows over the regime state
    RV: np.ndarray  # R V (reduced): the rows over the modal coefficients
    B4: np.ndarray  # |RV_k| |λ_k|⁴ of the gap (free) or contact force (stuck) row
    Pin: np.ndarray  # free state → stuck state (projection onto the constraint)
    Qout: np.ndarray  # stuck state → free state
    hp: np.ndarray  # (3, 2, nk) complex: ½ RV ∫₀^h e^{(λ - iγ)t} dt of the rows s and s_b
    hm: np.ndarray  # (3, 2, nk) complex: ½ conj(RV) ∫₀^h e^{(λ̄ - iγ)t} dt of the same rows
    gl: np.ndarray  # (3, 4, 2, nk) complex: (ṡ, ṡ_b) at the Gauss nodes of [0, h] = Re gl·α
    D: np.ndarray  # (nk,) complex: V⁻¹ [0; M⁻¹X; 0]: a contact impulse in free modal form
    fidx: np.ndarray  # (3,) the kept index of the forcing mode +iγ_r
    fcs: np.ndarray  # (3, 2) complex: its coefficient is fcs·(c, s)
    cosg: np.ndarray  # cos and sin of the forcing phase at the sub-grid points
    sing: np.ndarray
    cond: float


def _null_basis(v: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the null space of vᵀ (N × N-1)."""
    _, _, vt = np.linalg.svd(v[None, :])
    return np.ascontiguousarray(vt[1:].T)


_MODES = ArrayMemo()  # eigen-decompositions of the cells' γ_r-free matrices
_STUCK = ArrayMemo()  # the constrained system's γ_r-free parts, per cell


def _decompose(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lam, V = np.linalg.eig(A)
    V = V / np.linalg.norm(V, axis=0)  # unit columns keep cond(V) meaningful
    try:
        Vi = np.linalg.inv(V)
    except np.linalg.LinAlgError:
        Vi = np.full_like(V, np.nan)
    return lam.astype(complex), V.astype(complex), Vi.astype(complex)


def eigen(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(λ, V, V⁻¹)`` of a real matrix, V with unit columns (conjugate pairs exact, as LAPACK
    returns them; V⁻¹ NaN for a singular V), computed once per process for each matrix.
    Callers must not modify the arrays."""
    return _MODES.get((A,), lambda: _decompose(A))


def cond1(V: np.ndarray, Vi: np.ndarray) -> float:
    """1-norm condition number of V from its inverse in hand (inf if it is not finite)."""
    c = float(np.abs(V).sum(axis=0).max() * np.abs(Vi).sum(axis=0).max())
    return c if math.isfinite(c) else math.inf


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
    Ar = np.zeros((2 * m, 2 * m))  # the stuck cell's own dynamics: [[0, I], [AK, AC]]
    Ar[:m, m:] = np.eye(m)
    Ar[m:, :m] = AK
    Ar[m:, m:] = AC
    return Z, e_s, AK, AC, fy, Au, Qout, Pin, Ar


def stuck_matrices(sys_: System) -> tuple[np.ndarray, ...]:
    """The constrained system with the tip held on a stop at ``w_tip = w*`` (docs/model.md §5, §7).

    Returns ``(A, Pin, Qout, mu)``: ``ẏ = A y`` with ``y = [v; v̇; c; s; w*]``; ``y = Pin z``
    maps a free state onto the constraint (the caller sets the last entry to ``w*``);
    ``z = Qout y`` maps back; ``mu`` is the row of the contact force ``μ = -λ1 + λ2`` over y.
    """
    A, Pin, Qout, mu, _ = _stuck(sys_)
    return A, Pin.copy(), Qout.copy(), mu


def _stuck(sys_: System) -> tuple[np.ndarray, ...]:
    N = sys_.ndof
    m = N - 1
    g = sys_.params.gamma_r
    M, C, K, W, X = sys_.M, sys_.C, sys_.K, sys_.W, sys_.X
    Z, e_s, AK, AC, fy, Au, Qout, Pin, Ar = _STUCK.get(
        (M, C, K, W, X), lambda: _stuck_blocks(M, C, K, W, X)
    )
    ny = 2 * N + 1
    A = np.zeros((ny, ny))
    A[: 2 * m, : 2 * m] = Ar
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
    return A, Pin, Qout, mu, Ar


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


def _block_eig(A: np.ndarray, n: int, gamma: float, stuck: bool):
    """``(λ, V, V⁻¹, cond)`` of ``[[A₀, B], [0, Ω]]`` (``A₀`` its leading n × n block, the
    cell's own dynamics; ``Ω`` the forcing oscillator at γ_r, with the stop's position as a
    third, constant state when ``stuck``), from the cached decomposition of ``A₀``."""
    lam0, V0, Vi0 = eigen(np.ascontiguousarray(A[:n, :n]))
    B = A[:n, n:]
    # Ω's eigenvectors: e^{±iγτ} in (cos, sin), and the constant w*
    mus = [1j * gamma, -1j * gamma] + ([0j] if stuck else [])
    p = len(mus)
    E = np.zeros((p, p), dtype=complex)
    E[0, 0], E[1, 0] = 1.0, -1j
    E[0, 1], E[1, 1] = 1.0, 1j
    if stuck:
        E[2, 2] = 1.0
    # (μ - A₀)⁻¹ B e through A₀'s modes; the -iγ column is the conjugate of the +iγ one
    T = np.zeros((n, p), dtype=complex)
    ViB = Vi0 @ B
    T[:, 0] = V0 @ ((ViB @ E[:, 0]) / (mus[0] - lam0))
    T[:, 1] = T[:, 0].conj()
    if stuck:
        T[:, 2] = V0 @ ((ViB @ E[:, 2]) / (0.0 - lam0))
    scale = np.sqrt(np.sum(np.abs(T) ** 2, axis=0) + np.sum(np.abs(E) ** 2, axis=0))
    T /= scale
    E /= scale
    Ei = np.linalg.inv(E)
    nz = n + p
    V = np.zeros((nz, nz), dtype=complex)
    V[:n, :n] = V0
    V[:n, n:] = T
    V[n:, n:] = E
    Vi = np.zeros((nz, nz), dtype=complex)
    Vi[:n, :n] = Vi0
    Vi[:n, n:] = -Vi0 @ T @ Ei
    Vi[n:, n:] = Ei
    lam = np.concatenate([lam0, np.array(mus, dtype=complex)])
    return lam, V, Vi, cond1(V, Vi)


def _reduce(lam, V, Vi):
    """One eigenvalue of each conjugate pair, weight 2 (exact pairs, as LAPACK returns them);
    the full set with weight 1 where the pairing does not reconstruct the identity."""
    keep = lam.imag >= 0.0
    wt = np.where(lam.imag > 0.0, 2.0, 1.0)[keep]
    Vr = V[:, keep] * wt
    Vir = Vi[keep, :]
    eye = np.eye(len(lam))
    if np.sum(lam.imag > 0) != np.sum(lam.imag < 0) or np.max(np.abs((Vr @ Vir).real - eye)) > 1e-9:
        return lam, V, Vi, np.ones(len(lam)), np.arange(len(lam))
    return lam[keep], Vr, Vir, wt, np.flatnonzero(keep)


def prepare_event(sys_: System, n_grid: int) -> EventArrays:
    """Diagonalise the regimes and build the step factors and observable rows."""
    N = sys_.ndof
    nzm = 2 * N + 2
    gamma = sys_.params.gamma_r
    h = 2.0 * math.pi / gamma / n_grid
    full = _full_rows(sys_)
    A1, Pr, Qr, mu, _ = _stuck(sys_)
    nzr = np.array([nzm, nzm - 1, nzm - 1], dtype=np.int64)
    nk = np.zeros(3, dtype=np.int64)
    lam = np.zeros((3, nzm), dtype=complex)
    V = np.zeros((3, nzm, nzm), dtype=complex)
    Vi = np.zeros((3, nzm, nzm), dtype=complex)
    R = np.zeros((3, NROWS, nzm))
    RV = np.zeros((3, NROWS, nzm), dtype=complex)
    B4 = np.zeros((3, nzm))
    hp = np.zeros((3, 2, nzm), dtype=complex)
    hm = np.zeros((3, 2, nzm), dtype=complex)
    gl = np.zeros((3, 4, 2, nzm), dtype=complex)
    fidx = np.zeros(3, dtype=np.int64)
    fcs = np.zeros((3, 2), dtype=complex)
    D = np.zeros(nzm, dtype=complex)
    cond = 0.0
    # regime 0 (free) and regime 1 (stuck); regime 2 has regime 1's matrices (the stop's
    # position is a state, not a parameter)
    for r, A in ((0, sys_.augmented_matrix()), (1, A1)):
        nz = A.shape[0]
        n0 = nz - (2 if r == 0 else 3)
        lf, Vf, Vif, cr = _block_eig(A, n0, gamma, stuck=r > 0)
        cond = max(cond, cr)
        lr, Vr, Vir, _, kept = _reduce(lf, Vf, Vif)
        m = len(lr)
        nk[r] = m
        lam[r, :m] = lr
        V[r, :nz, :m] = Vr
        Vi[r, :m, :nz] = Vir
        if r == 0:
            R[0, :6] = full
        else:
            R[r, :6, :nz] = full @ Qr
            R[r, R_MU, :nz] = mu
            R[r, R_MUD, :nz] = mu @ A
        RV[r, :, :m] = R[r, :, :nz] @ Vr
        m2 = np.abs(lr) ** 2
        B4[r, :m] = np.abs(RV[r, R_W if r == 0 else R_MU, :m]) * m2 * m2
        # exact ∫₀^h Re(c e^{λt}) e^{-iγt} dt = ½ (c ∫e^{(λ - iγ)t} + c̄ ∫e^{(λ̄ - iγ)t})
        pp = 0.5 * phi1_each(np.ascontiguousarray(lr - 1j * gamma), h)
        pm = 0.5 * phi1_each(np.ascontiguousarray(lr.conj() - 1j * gamma), h)
        for i, row in enumerate((R_S, R_SB)):
            hp[r, i, :m] = RV[r, row, :m] * pp
            hm[r, i, :m] = RV[r, row, :m].conj() * pm
        for j, t in enumerate(GL_NODES * h):
            et = np.exp(lr * t)
            gl[r, j, 0, :m] = RV[r, R_SD, :m] * et
            gl[r, j, 1, :m] = RV[r, R_SBD, :m] * et
        f = int(np.flatnonzero(kept == n0)[0])  # the +iγ mode (first after A₀'s)
        # its coefficient is set from the exact phase at every grid point, where the reduced
        # form holds (unpaired, its conjugate would drift apart from it)
        fidx[r] = f if m < nz else -1
        ic = n0
        fcs[r, 0] = Vir[f, ic]
        fcs[r, 1] = Vir[f, ic + 1]
        if r == 0:
            imp = np.zeros(nz)
            imp[N : 2 * N] = sys_.Minv @ sys_.X
            D[:m] = Vir @ imp
    for arr in (nk, lam, V, Vi, R, RV, B4, hp, hm, gl, fidx, fcs):
        arr[2] = arr[1]
    Pin = np.zeros((2, nzm - 1, nzm))
    Qout = np.zeros((2, nzm, nzm - 1))
    Pin[:] = Pr
    Qout[:] = Qr
    eh = np.exp(lam * h)
    ang = 2.0 * math.pi * np.arange(n_grid + 1) / n_grid
    cosg = np.cos(ang)
    sing = np.sin(ang)
    cosg[n_grid], sing[n_grid] = 1.0, 0.0
    return EventArrays(nzr, nk, eh, lam, V, Vi, R, RV, B4, Pin, Qout, hp, hm, gl, D, fidx, fcs,
                       cosg, sing, cond)  # fmt: skip
