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
of the gap (the contact force when stuck). The measurement's tables (``primitives.py``) are
built from the same modes and rows.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from worker.memo import ArrayMemo
from worker.model import System
from worker.solvers.event.roots import SPLITS, cexp, split_table

__all__ = ["EventArrays", "cell_modes", "eigen", "prepare_event", "stuck_matrices"]

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
    sp: np.ndarray  # (3, SPLITS, nk): e^{λt} at the first two splits' points of [0, h]
    lam: np.ndarray
    V: np.ndarray  # kept eigenvectors, weight folded in (2 for a pair, 1 for a real λ)
    Vi: np.ndarray  # the matching rows of V⁻¹
    R: np.ndarray  # observable rows over the regime state
    RV: np.ndarray  # R V (reduced): the rows over the modal coefficients
    B4: np.ndarray  # |RV_k| |λ_k|⁴ of the gap (free) or contact force (stuck) row
    Pin: np.ndarray  # free state → stuck state (projection onto the constraint)
    Qout: np.ndarray  # stuck state → free state
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
    # contact force μ = -λ1 + λ2 over y: M q̇ - h = X μ with q̇ = Z v̈, h = -C q - K u + e_s f;
    # its forcing entries are kc·(f_cos, f_sin), the rest does not depend on γ_r
    rows = np.zeros((m, ny))  # v̈ over y without the forcing
    rows[:, :m] = AK
    rows[:, m : 2 * m] = AC
    rows[:, 2 * m + 2] = Au
    H = -C @ Qout[N : 2 * N] - K @ Qout[:N]
    mu0 = X @ (M @ (Z @ rows) - H) / (X @ X)
    kc = float(X @ (M @ (Z @ fy) - e_s) / (X @ X))
    return Z, e_s, AK, AC, fy, Au, Qout, Pin, Ar, mu0, kc


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
    Z, e_s, AK, AC, fy, Au, Qout, Pin, Ar, mu0, kc = _STUCK.get(
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
    mu = mu0.copy()
    mu[2 * m] = kc * sys_.f_cos
    mu[2 * m + 1] = kc * sys_.f_sin
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


_PAIRS = ArrayMemo()  # the reduced form of the cells' own modes


def cell_modes(A0: np.ndarray) -> tuple:
    """The cached decomposition of a cell's own dynamics ``A₀`` and its reduced form (the one
    reduced form of the free modes: the event kernel's and the linear tail proof's): the kept
    modes (one of each conjugate pair, weight 2; real ones weight 1), whether that form
    reconstructs the identity (exact pairs, as LAPACK returns them for a real matrix; if not,
    every mode is kept with weight 1), and the 1-norms of V's columns and of V⁻¹'s columns."""
    lam0, V0, Vi0 = eigen(A0)

    def compute() -> tuple:
        keep = np.flatnonzero(lam0.imag >= 0.0)
        w = np.where(lam0.imag[keep] > 0.0, 2.0, 1.0)
        paired = bool(np.sum(lam0.imag > 0) == np.sum(lam0.imag < 0)) and bool(
            np.max(np.abs(((V0[:, keep] * w) @ Vi0[keep, :]).real - np.eye(len(lam0)))) <= 1e-9
        )
        if not paired:
            keep = np.arange(len(lam0))
            w = np.ones(len(lam0))
        cv = float(np.abs(V0).sum(axis=0).max())
        cvi = np.ascontiguousarray(np.abs(Vi0).sum(axis=0))
        return keep.astype(np.int64), w, paired, cv, cvi

    keep, w, paired, cv, cvi = _PAIRS.get((A0,), compute)
    return lam0, V0, Vi0, keep, w, paired, cv, cvi


@njit(cache=True, nogil=True)
def _col_l1(top, bottom, c):
    """Σ|top[:, c]| + Σ|bottom[:, c]|: the 1-norm of column c of [top; bottom]."""
    acc = 0.0
    for i in range(top.shape[0]):
        acc += abs(top[i, c])
    for i in range(bottom.shape[0]):
        acc += abs(bottom[i, c])
    return acc


@njit(cache=True, nogil=True)
def _resolvent(V0, Vi0, lam0, b, mu, u, T, c):
    """T[:, c] = (μ - A₀)⁻¹ b through A₀'s modes, ``V₀ (V₀⁻¹ b / (μ - λ₀))`` (u is scratch):
    the cell's part of the oscillator's eigenvector for eigenvalue μ with forcing column b."""
    n0 = lam0.shape[0]
    for i in range(n0):
        acc = 0j
        for j in range(n0):
            acc += Vi0[i, j] * b[j]
        u[i] = acc / (mu - lam0[i])
    for i in range(n0):
        acc = 0j
        for k in range(n0):
            acc += V0[i, k] * u[k]
        T[i, c] = acc


@njit(cache=True, nogil=True)
def _regime(r, lam0, V0, Vi0, keep0, w0, paired, cv0, cvi0, B, gamma, h, stuck, R, gaprow, imp,
            lam, V, Vi, RV, B4, D, eh, fidx, fcs, nk):  # fmt: skip
    """Fill regime r's tables for ``[[A₀, B], [0, Ω]]`` (A₀ the cell's own dynamics, with its
    cached modes; Ω the forcing oscillator at γ_r and, when ``stuck``, the stop's position as a
    constant state): its reduced modes, rows, bound weights and
    step factors over one sub-grid interval h (see :class:`EventArrays`). Returns the 1-norm
    condition number of its eigenvector matrix.

    Ω's eigenvectors e (e^{±iγτ} in (cos, sin), and the constant w*) extend to
    ``[(μ - A₀)⁻¹ B e; e]`` through A₀'s modes; with V = [[V₀, T], [0, E]] the inverse is
    [[V₀⁻¹, -V₀⁻¹ T E⁻¹], [0, E⁻¹]]."""
    n0 = lam0.shape[0]
    p = 3 if stuck else 2
    nz = n0 + p
    E = np.zeros((p, p), dtype=np.complex128)
    E[0, 0] = 1.0
    E[1, 0] = -1j
    E[0, 1] = 1.0
    E[1, 1] = 1j
    if stuck:
        E[2, 2] = 1.0
    T = np.zeros((n0, p), dtype=np.complex128)
    u = np.zeros(n0, dtype=np.complex128)
    b = np.empty(n0, dtype=np.complex128)
    for j in range(n0):
        b[j] = B[j, 0] - 1j * B[j, 1]
    _resolvent(V0, Vi0, lam0, b, 1j * gamma, u, T, 0)
    for i in range(n0):
        T[i, 1] = T[i, 0].conjugate()
    if stuck:
        for j in range(n0):
            b[j] = B[j, 2]
        _resolvent(V0, Vi0, lam0, b, 0j, u, T, 2)
    for c in range(p):  # unit columns
        sq = 0.0
        for i in range(n0):
            sq += T[i, c].real ** 2 + T[i, c].imag ** 2
        for i in range(p):
            sq += E[i, c].real ** 2 + E[i, c].imag ** 2
        sc = math.sqrt(sq)
        for i in range(n0):
            T[i, c] /= sc
        for i in range(p):
            E[i, c] /= sc
    Ei = np.zeros((p, p), dtype=np.complex128)
    det = E[0, 0] * E[1, 1] - E[0, 1] * E[1, 0]
    Ei[0, 0] = E[1, 1] / det
    Ei[0, 1] = -E[0, 1] / det
    Ei[1, 0] = -E[1, 0] / det
    Ei[1, 1] = E[0, 0] / det
    if stuck:
        Ei[2, 2] = 1.0 / E[2, 2]
    G = np.zeros((n0, p), dtype=np.complex128)  # -V₀⁻¹ T E⁻¹
    TE = np.zeros((n0, p), dtype=np.complex128)
    for i in range(n0):
        for c in range(p):
            acc = 0j
            for k in range(p):
                acc += T[i, k] * Ei[k, c]
            TE[i, c] = acc
    for i in range(n0):
        for c in range(p):
            acc = 0j
            for k in range(n0):
                acc += Vi0[i, k] * TE[k, c]
            G[i, c] = -acc
    # condition number: the largest column sums of V and V⁻¹ (A₀'s columns cached)
    nv = cv0
    nvi = 0.0
    for j in range(n0):
        nvi = max(nvi, cvi0[j])
    for c in range(p):
        nv = max(nv, _col_l1(T, E, c))
        nvi = max(nvi, _col_l1(G, Ei, c))
    cond = nv * nvi
    # the kept modes: A₀'s reduced ones, then +iγ (and -iγ when unpaired), then w*'s
    m = 0
    for q in range(keep0.shape[0]):
        k = keep0[q]
        lam[r, m] = lam0[k]
        for i in range(n0):
            V[r, i, m] = V0[i, k] * w0[q]
        for i in range(n0, nz):
            V[r, i, m] = 0.0
        for j in range(n0):
            Vi[r, m, j] = Vi0[k, j]
        for c in range(p):
            Vi[r, m, n0 + c] = G[k, c]
        m += 1
    fpos = m  # the forcing mode +iγ comes next; set from the exact phase where paired
    fidx[r] = fpos if paired else -1
    for c in range(p):
        if c == 1 and paired:
            continue  # the conjugate of +iγ
        wt = 2.0 if (c == 0 and paired) else 1.0
        lam[r, m] = 1j * gamma if c == 0 else (-1j * gamma if c == 1 else 0.0)
        for i in range(n0):
            V[r, i, m] = T[i, c] * wt
        for i in range(p):
            V[r, n0 + i, m] = E[i, c] * wt
        for j in range(n0):
            Vi[r, m, j] = 0.0
        for i in range(p):
            Vi[r, m, n0 + i] = Ei[c, i]
        m += 1
    nk[r] = m
    fcs[r, 0] = Vi[r, fpos, n0]
    fcs[r, 1] = Vi[r, fpos, n0 + 1]
    nrows = R.shape[0]
    for k in range(m):
        lk = lam[r, k]
        for row in range(nrows):
            acc = 0j
            for i in range(nz):
                acc += R[row, i] * V[r, i, k]
            RV[r, row, k] = acc
        m2 = lk.real * lk.real + lk.imag * lk.imag
        B4[r, k] = abs(RV[r, gaprow, k]) * m2 * m2
        eh[r, k] = cexp(lk * h)
        if imp.shape[0] > 0:
            acc = 0j
            for i in range(nz):
                acc += Vi[r, k, i] * imp[i]
            D[k] = acc
    return cond


def prepare_event(sys_: System, n_grid: int) -> EventArrays:
    """Diagonalise the regimes and build the step factors and observable rows."""
    N = sys_.ndof
    nzm = 2 * N + 2
    gamma = sys_.params.gamma_r
    h = 2.0 * math.pi / gamma / n_grid
    A1, Pr, Qr, mu, _ = _stuck(sys_)
    nzr = np.array([nzm, nzm - 1, nzm - 1], dtype=np.int64)
    nk = np.zeros(3, dtype=np.int64)
    lam = np.zeros((3, nzm), dtype=complex)
    V = np.zeros((3, nzm, nzm), dtype=complex)
    Vi = np.zeros((3, nzm, nzm), dtype=complex)
    R = np.zeros((3, NROWS, nzm))
    RV = np.zeros((3, NROWS, nzm), dtype=complex)
    B4 = np.zeros((3, nzm))
    eh = np.zeros((3, nzm), dtype=complex)
    fidx = np.zeros(3, dtype=np.int64)
    fcs = np.zeros((3, 2), dtype=complex)
    D = np.zeros(nzm, dtype=complex)
    full = _full_rows(sys_)
    R[0, :6] = full
    R[1, :6, : nzm - 1] = full @ Qr
    R[1, R_MU, : nzm - 1] = mu
    R[1, R_MUD, : nzm - 1] = mu @ A1
    imp = np.zeros(nzm)
    imp[N : 2 * N] = sys_.Minv @ sys_.X
    cond = 0.0
    # regime 0 (free) and regime 1 (stuck); regime 2 has regime 1's matrices (the stop's
    # position is a state, not a parameter)
    for r, A in ((0, sys_.augmented_matrix()), (1, A1)):
        nz = A.shape[0]
        n0 = nz - (2 if r == 0 else 3)
        lam0, V0, Vi0, keep, w, paired, cv, cvi = cell_modes(np.ascontiguousarray(A[:n0, :n0]))
        cr = _regime(r, lam0, V0, Vi0, keep, w, paired, cv, cvi,
                     np.ascontiguousarray(A[:n0, n0:]), gamma, h, r > 0,
                     np.ascontiguousarray(R[r, :, :nz]), R_W if r == 0 else R_MU,
                     imp if r == 0 else imp[:0], lam, V, Vi, RV, B4, D, eh, fidx, fcs,
                     nk)  # fmt: skip
        cond = max(cond, cr if math.isfinite(cr) else math.inf)
    for arr in (nk, lam, V, Vi, R, RV, B4, eh, fidx, fcs):
        arr[2] = arr[1]
    Pin = np.zeros((2, nzm - 1, nzm))
    Qout = np.zeros((2, nzm, nzm - 1))
    Pin[:] = Pr
    Qout[:] = Qr
    sp = np.zeros((3, SPLITS, nzm), dtype=complex)
    split_table(lam, nk, h, sp)  # the kernel's h: T / n_grid, T = 2π/γ_r
    cosg, sing = _phases(n_grid)
    return EventArrays(nzr, nk, eh, sp, lam, V, Vi, R, RV, B4, Pin, Qout, D, fidx, fcs, cosg,
                       sing, cond)  # fmt: skip


@functools.lru_cache(maxsize=8)
def _phases(n_grid: int) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of the forcing phase at the sub-grid points (the same for every point)."""
    ang = 2.0 * math.pi * np.arange(n_grid + 1) / n_grid
    cosg = np.cos(ang)
    sing = np.sin(ang)
    cosg[n_grid], sing[n_grid] = 1.0, 0.0
    cosg.flags.writeable = False
    sing.flags.writeable = False
    return cosg, sing
