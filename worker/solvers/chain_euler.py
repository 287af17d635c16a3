"""``method: euler`` for a chain of N cells (docs/model.md §11): the paper's scheme with 2N
contacts, and the chain's linear tail.

Per step, as for the unit cell (``euler.py``): the free velocity
``q_f = q + Δτ M⁻¹(-C q - K u + e_{s_1} f)``, each cell's two predicted gaps
``c1_j = g̃1_j - W_jᵀ(u + Δτ q_f)``, ``c2_j = g̃2_j + W_jᵀ(u + Δτ q_f)``, the 2N × 2N LCP for the
impulses, then ``q ← q_f + Σ_j M⁻¹X_j(-Λ1_j + Λ2_j)`` and ``u ← u + Δτ q``.

The LCP matrix is ``Δτ W M⁻¹ Xᵀ`` expanded to the two stops of every cell. M is block-diagonal,
so the Delassus matrix ``W M⁻¹ Xᵀ`` is diagonal (``ChainSystem.delassus``: the cells' G) and
the LCP is block-diagonal, one 2 × 2 block ``G_j Δτ [[1, -1], [-1, 1]]`` per cell: the cells'
LCPs are independent, and each has the unit cell's closed form. Lemke's algorithm on the whole
2N × 2N matrix (``lcp="lemke"``, the paper's formulation) finds the same net impulses
``Λ2_j - Λ1_j`` (a symmetric positive semidefinite LCP: its solutions share ``M z``).

A period's row measures the last cell as the unit cell measures its own (s_N, its beam's s_b,
so Γ is Γ_N); its impact columns count the contact episodes begun at every cell's stop 1 and
stop 2, its peak impulse is the largest of any cell. The stroboscopic sample is the whole chain
state ``[u; q]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from worker.model import CellParams, SteadyState, System
from worker.model.chain import ChainSystem, chain_steady_state
from worker.solvers import measure as ms
from worker.solvers.euler import check_stable, default_steps
from worker.solvers.lcp import LEMKE_OK, lemke_nb, lemke_workspace, two_stop_impulses
from worker.solvers.linear import GATE_RTOL, _free_modes, tail_proof
from worker.solvers.settings import MAX_STEPS_PER_PERIOD, SolverSettings
from worker.solvers.stepping import SteppingRun, contact_step, extrema, tally_impulses

__all__ = [
    "ChainEulerRun",
    "ChainSteppingRun",
    "ChainTail",
    "cell_blocks",
    "chain_euler_kernel",
    "chain_tail",
    "engine_view",
    "refuse_pinned",
]

# The tail proof keeps one (modes × state) complex row block per cell: N·2nd² entries for
# nd unknowns. Beyond this many (~64 MB) a chain gets no proof and its point runs on.
PROOF_MAX_ENTRIES = 4_000_000


@njit(**ms.KERNEL_JIT)
def chain_euler_kernel(x, kst, ring, n_periods, measure, checks, rows, samples, hist, xh, spp,
                       gamma_r, f_scale, Cv, Kv, col, ptr, Minv_es, MinvX, f_sin, f_cos, W, d, G,
                       g1, g2, contact, lam1, lam2, cell_ext, use_lemke, lcp_M, lcp_q, lcp_T,
                       lcp_basis, lcp_cand, lcp_B, lcp_xb, lcp_z, lin_L, lin_xp, lin_amp,
                       lin_gate, div_limit, tol, xn):  # fmt: skip
    """Advance up to ``n_periods`` periods of the chain; returns (periods done, END code,
    period found). ``W``, ``MinvX`` are (N, b): cell j's rows on its own block of b = n + 1
    coordinates; ``Cv``, ``Kv``, ``col``, ``ptr`` hold M⁻¹C and M⁻¹K by rows, their nonzero
    columns only (``sparse_rows``); ``contact`` (N) holds each cell's contact episode between
    batches;
    ``cell_ext`` (N × 2, or empty: off) accumulates each cell's outer-mass extrema, min and max,
    as the period rows do for the last cell."""
    nx = x.shape[0]
    nd = nx // 2
    ncell = W.shape[0]
    b = W.shape[1]
    n = b - 1
    sN = nd - 1  # the last cell's outer mass
    track = cell_ext.shape[0] > 0
    oN = nd - b  # the last cell's block
    T = 2.0 * math.pi / gamma_r
    dt = T / spp
    if use_lemke:
        # block-diagonal: cell j's two stops are rows 2j, 2j + 1
        for i in range(2 * ncell):
            for j in range(2 * ncell):
                lcp_M[i, j] = 0.0
        for c in range(ncell):
            gdt = G[c] * dt
            lcp_M[2 * c, 2 * c] = gdt
            lcp_M[2 * c, 2 * c + 1] = -gdt
            lcp_M[2 * c + 1, 2 * c] = -gdt
            lcp_M[2 * c + 1, 2 * c + 1] = gdt
    for k in range(n_periods):
        ms.begin_row(rows, k)
        period = kst[ms.K_PERIOD]
        smin = np.inf
        smax = -np.inf
        h0 = h1 = h2 = h3 = vv = vb = 0.0
        imp1 = imp2 = peak = nsteps = ncontact = 0.0
        # summed over the cells (the engine's last-cell view; a chain reports none of them)
        ct1 = ct2 = vimp1 = vimp2 = en1 = en2 = 0.0
        last = -1.0
        for js in range(spp):
            cph = math.cos(gamma_r * js * dt)
            sph = math.sin(gamma_r * js * dt)
            s0 = x[sN]
            v0 = x[nd + sN]
            fval = f_scale * (f_sin * sph + f_cos * cph)
            for i in range(nd):
                acc = Minv_es[i] * fval
                for t in range(ptr[i], ptr[i + 1]):  # the dense row's terms, zeros skipped
                    j = col[t]
                    acc -= Cv[t] * x[nd + j] + Kv[t] * x[j]
                xn[nd + i] = x[nd + i] + dt * acc
            for c in range(ncell):
                off = c * b
                wpred = 0.0
                for i in range(b):
                    wpred += W[c, i] * (x[off + i] + dt * xn[nd + off + i])
                c1 = g1[c] - wpred
                c2 = g2[c] + wpred
                if use_lemke:
                    lcp_q[2 * c] = c1
                    lcp_q[2 * c + 1] = c2
                else:
                    lam1[c], lam2[c] = two_stop_impulses(G[c] * dt, c1, c2)
            if use_lemke:
                # at most one pivot per complementary pair and the artificial variable, on a
                # generic LCP; the budget is the unit cell's 50 per cell
                status = lemke_nb(lcp_M, lcp_q, lcp_T, lcp_basis, lcp_cand, lcp_B, lcp_xb,
                                  lcp_z, 50 * ncell)  # fmt: skip
                if status != LEMKE_OK:  # no solution: the state becomes non-finite, the
                    lcp_z[0] = np.nan  # point fails with that reason
                for c in range(ncell):
                    lam1[c] = lcp_z[2 * c]
                    lam2[c] = lcp_z[2 * c + 1]
            for c in range(ncell):
                P = lam2[c] - lam1[c]
                if P != 0.0:  # M⁻¹X_j lives on cell j's block only
                    off = c * b
                    vm = ms.dot(W[c], xn[nd + off :], b)  # the free velocity, before it
                    ct1, ct2, vimp1, vimp2, en1, en2 = tally_impulses(
                        lam1[c], lam2[c], contact[c], ms.dot(W[c], x[nd + off :], b), vm,
                        vm + G[c] * P, G[c], dt, ct1, ct2, vimp1, vimp2, en1, en2,
                    )  # fmt: skip
                    for i in range(b):
                        xn[nd + off + i] += MinvX[c, i] * P
            for i in range(nd):
                xn[i] = x[i] + dt * xn[nd + i]
            if track:
                for c in range(ncell):
                    sj = (c + 1) * b - 1
                    cell_ext[c, 0], cell_ext[c, 1] = extrema(
                        x[sj], x[nd + sj], xn[sj], xn[nd + sj], dt, cell_ext[c, 0], cell_ext[c, 1]
                    )
            if measure:
                # the rectangle rule over whole periods, on the last cell (as euler_kernel)
                sbv = ms.dot(d, x[oN:], n)
                h0 += dt * x[sN] * cph
                h1 -= dt * x[sN] * sph
                h2 += dt * sbv * cph
                h3 -= dt * sbv * sph
            for i in range(nx):
                x[i] = xn[i]
            v1 = x[nd + sN]
            if measure:
                vv += dt * v1 * v1
                vb += dt * ms.dot(d, x[nd + oN :], n) * v1
            smin, smax = extrema(s0, v0, x[sN], v1, dt, smin, smax)
            nsteps += 1.0
            solved = False
            for c in range(ncell):
                l1 = lam1[c]
                l2 = lam2[c]
                if l1 > 0.0 or l2 > 0.0:
                    solved = True
                if l1 > 0.0 or l2 > 0.0 or contact[c] != 0.0:
                    state, imp1, imp2, peak, last = contact_step(
                        l1, l2, js / spp, int(contact[c]), imp1, imp2, peak, last, W[c],
                        x[c * b :], b, g1[c], g2[c],
                    )  # fmt: skip
                    contact[c] = state
            if solved:
                ncontact += 1.0
            if hist.shape[0] > 0:
                # the last cell's channels (its tip and its impulses), the whole chain's state
                tau = period * T + (js + 1) * dt
                ms.record(hist, xh, kst, tau, x[sN], ms.dot(W[ncell - 1], x[oN:], b),
                          ms.dot(d, x[oN:], n), x[nd + sN], ms.dot(d, x[nd + oN :], n),
                          lam1[ncell - 1], lam2[ncell - 1], 0.0, x, nx)  # fmt: skip
        # the contact state at the period's end, one base-3 digit per cell (cell 1 lowest):
        # 0 only with every cell free (the engine's quiet test), and the extrapolation's branch
        # test tells contact patterns apart (exactly up to 33 cells, a float's 53 bits)
        regime = 0.0
        for c in range(ncell - 1, -1, -1):
            regime = 3.0 * regime + contact[c]
        ms.close_row(rows, k, smin, smax, (h0, h1, h2, h3), vv, vb, imp1, imp2, peak, last,
                     nsteps, ncontact, 0.0, regime)  # fmt: skip
        ms.close_impacts(rows, k, ct1, ct2, vimp1, vimp2, en1, en2)
        kst[ms.K_CONTACT] = regime
        kst[ms.K_PERIOD] += 1.0
        code, p = ms.period_end(x, nx, rows, samples, k, ring, kst, lin_L, lin_xp, lin_amp,
                                lin_gate, checks, div_limit, tol)  # fmt: skip
        if code != ms.END_NONE:
            return k + 1, code, p
    return n_periods, ms.END_NONE, 0


def sparse_rows(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, ...]:
    """``A`` and ``B`` (square, the same shape) by rows, the columns where either is nonzero
    in ascending order: ``(A values, B values, columns, row starts)``. M is block-diagonal and
    the cells are tied at their outer masses only, so a row of M⁻¹C or M⁻¹K has its own
    cell's b columns and its neighbours' outer masses: a step costs O(N b²), not O(N² b²).
    Skipping exact zeros leaves every sum as the dense row's (in the same order)."""
    keep = (A != 0.0) | (B != 0.0)
    rows, cols = np.nonzero(keep)  # row-major: columns ascending within a row
    ptr = np.zeros(A.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=A.shape[0]), out=ptr[1:])
    return (np.ascontiguousarray(A[rows, cols]), np.ascontiguousarray(B[rows, cols]),
            cols.astype(np.int64), ptr)  # fmt: skip


# --------------------------------------------------------------------------- linear tail


@dataclass(frozen=True)
class ChainTail:
    """The chain's linear tail, with the fields the point engine reads from a ``LinearTail``.

    ``steady`` is the chain's closed-form steady state seen at its last cell (a unit-cell
    ``SteadyState`` on the last block of the chain's U: Γ_N, A_N, the last cell's θ_eff);
    ``xp0`` the whole chain's state at forcing phase 0. ``amp`` and ``gate`` are normalised:
    ``amp = max_j |Ŵ_j| / gate_j`` and ``gate = 1``, so ``amp < gate`` says that every cell's
    steady tip clears its stops, as the unit cell's test does.
    """

    steady: SteadyState | None
    lam: np.ndarray  # kept eigenvalues of the chain's free system
    L: np.ndarray  # (N, m, 2·ndof): cell j's tip coefficient of each kept mode from x - x_p(0)
    xp0: np.ndarray
    w_hat: np.ndarray  # (N,) complex: Ŵ_j
    cell_gates: np.ndarray  # (N,) min(g̃1_j, g̃2_j), less round-off
    g1: np.ndarray
    g2: np.ndarray
    amp: float
    gate: float
    gamma_r: float
    usable: bool
    damped: bool
    max_re: float
    scale: float

    def proves(self, x: np.ndarray, horizon: float) -> bool:
        """Whether the free motion from ``x`` (forcing phase 0) provably never reaches any
        cell's stop: the unit cell's proof (``linear.tail_proof``: a decreasing bound below the
        gate from some t* <= horizon on, an exact root search of both gaps before) for every
        cell's tip, each a sum of the chain's modes. No stop reached means the chain stays
        linear, so its motion tends to the closed form (when damped)."""
        if not self.usable:
            return False
        x = np.asarray(x, dtype=np.float64)
        for j in range(len(self.cell_gates)):
            if not tail_proof(self.L[j], self.xp0, self.lam, x, abs(self.w_hat[j]),
                              float(self.cell_gates[j]), complex(self.w_hat[j]), self.gamma_r,
                              float(self.g1[j]), float(self.g2[j]), float(horizon)):  # fmt: skip
                return False
        return True


def _state_matrix(cs: ChainSystem) -> np.ndarray:
    """First-order matrix A of the chain's free motion, ``x = [u; q]``."""
    n = cs.ndof
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -cs.Minv @ cs.K
    A[n:, n:] = -cs.Minv @ cs.C
    return A


def chain_tail(cs: ChainSystem) -> ChainTail:
    """The chain's closed-form steady state and the per-cell tail-proof data."""
    cp = cs.params
    N = cp.n_cells
    nd = cs.ndof
    b = nd // N
    A = _state_matrix(cs)
    # the unit cell's reduction of the free modes, one tip row per cell (the same modes)
    lam, L0, max_re, valid, damped = _free_modes(A, cs.W[0], nd)
    if N * L0.size > PROOF_MAX_ENTRIES:
        # the rows would not fit in memory: no proof (usable False below), the point runs on
        valid = False
        L = np.zeros((N, 0, 2 * nd), dtype=complex)
    else:
        L = np.ascontiguousarray(np.array([L0] + [_free_modes(A, w, nd)[1] for w in cs.W[1:]]))
    ss = chain_steady_state(cs)
    g = cp.cell.gamma_r
    last = cs.cells[-1]
    if ss is None:
        xp0 = np.zeros(2 * nd)
        w_hat = np.zeros(N, dtype=complex)
        e_s1 = np.zeros(nd)
        e_s1[cs.s_index[0]] = 1.0
        static = np.linalg.solve(cs.K, e_s1) * math.hypot(cs.f_sin, cs.f_cos)
        scale = float(np.max(np.abs(static)))
        steady = None
    else:
        xp0 = np.concatenate([ss.U.real, (1j * g * ss.U).real])
        w_hat = np.array([complex(w @ ss.U) for w in cs.W])
        scale = float(np.max(np.abs(np.concatenate([ss.U, 1j * g * ss.U]))))
        steady = SteadyState(params=last.params, U=ss.U[nd - b :].copy(), kappa=last.kappa,
                             d=last.d, W=last.W)  # fmt: skip
    g1 = np.array([p.g1 for p in cp.cells], dtype=float)
    g2 = np.array([p.g2 for p in cp.cells], dtype=float)
    gates = np.minimum(g1, g2) * (1.0 - GATE_RTOL)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(w_hat) / gates
    return ChainTail(
        steady=steady, lam=lam.copy(), L=L, xp0=np.ascontiguousarray(xp0), w_hat=w_hat,
        cell_gates=gates, g1=g1, g2=g2,
        amp=float(np.max(np.where(np.isfinite(ratio), ratio, np.inf))), gate=1.0,
        gamma_r=g, usable=bool(valid and ss is not None), damped=bool(damped),
        max_re=float(max_re), scale=max(scale, 1e-300),
    )  # fmt: skip


# --------------------------------------------------------------------------- the run


@dataclass(frozen=True)
class _SteppingView:
    """What ``euler``'s stability checks read of a system, for the chain: its γ_r (in
    ``params``), M⁻¹, K, C and largest natural frequency."""

    params: CellParams
    Minv: np.ndarray
    K: np.ndarray
    C: np.ndarray

    @property
    def ndof(self) -> int:
        return self.K.shape[0]

    def omega_max(self) -> float:
        return float(np.sqrt(np.max(np.abs(np.linalg.eigvals(self.Minv @ self.K)))))


def engine_view(cs: ChainSystem) -> System:
    """The system the point engine is given for a chain: its last cell. The engine reads γ_r,
    θ, the base scale (shared by every cell), the gaps (for a pinned tip, refused for chains)
    and κ (the last cell's θ_eff) from it; the dynamics are the run's and the tail's."""
    return cs.cells[-1]


def refuse_pinned(cs: ChainSystem) -> None:
    """Refuse a chain with a pinned cell (g1 = g2 = 0): the engine's pinned-tip analysis is
    the unit cell's."""
    pinned = [j + 1 for j, p in enumerate(cs.params.cells) if p.g1 == 0.0 and p.g2 == 0.0]
    if pinned:
        raise ValueError(
            f"cells {pinned} have g1 = g2 = 0 (a pinned tip): not supported for chains yet "
            "(the engine's pinned-tip analysis is the unit cell's); use gaps > 0"
        )


def cell_blocks(cs: ChainSystem) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each cell's rows on its own block of b = n + 1 coordinates: ``W`` (N, b) its tip,
    ``MinvX`` (N, b) the velocity change of a unit impulse at its stops; and the gaps g1, g2."""
    N = cs.params.n_cells
    b = cs.ndof // N
    c = np.ascontiguousarray
    blocks = [slice(j * b, (j + 1) * b) for j in range(N)]
    W = c(np.array([cs.W[j, blk] for j, blk in enumerate(blocks)]))
    MinvX = c(np.array([(cs.Minv @ cs.X[j])[blk] for j, blk in enumerate(blocks)]))
    g1 = np.array([q.g1 for q in cs.params.cells], dtype=float)
    g2 = np.array([q.g2 for q in cs.params.cells], dtype=float)
    return W, MinvX, g1, g2


class ChainSteppingRun(SteppingRun):
    """What a chain's time-stepping runs share: no per-period tail check in the kernel (the
    chain's proof is per cell and runs in the engine), and one contact episode per cell
    (``contact``, kept between batches, saved and restored with the state), and every cell's
    range over an orbit (``cell_ranges``). Subclasses set ``contact``, ``_W`` (N, b), ``_g1``,
    ``_g2`` in ``__init__``, and ``cell_ext`` (an empty (0, 2) array: off), which their kernel
    takes among its ``arrays`` and fills with each cell's outer-mass extrema when it is not
    empty."""

    contact: np.ndarray
    cell_ext: np.ndarray
    _W: np.ndarray
    _g1: np.ndarray
    _g2: np.ndarray

    def __init__(self, cs: ChainSystem, settings: SolverSettings, tail: ChainTail,
                 forcing: bool, div_limit: float) -> None:  # fmt: skip
        super().__init__(cs, settings, tail, forcing, div_limit)  # type: ignore[arg-type]
        # The kernels' per-period tail check bounds one tip; the chain's proof is per cell
        # and runs in the engine (``ChainTail.proves``, at quiet periods), so it is off here.
        self.lin_L = np.zeros((0, self.nx), dtype=complex)
        self.lin_xp = np.zeros(self.nx)
        self.lin_amp, self.lin_gate = 0.0, -1.0

    def cell_ranges(self, x0: np.ndarray, periods: int) -> np.ndarray:
        """Each cell's outer-mass half-range (max − min) / 2 over ``periods`` periods from the
        state ``x0`` at forcing phase 0, cell 1 first, by the same steps and the same in-step
        extrema as the period rows (the last cell's is the rows' amplitude). Resets the run."""
        N = self.contact.shape[0]
        ext = np.empty((N, 2))
        ext[:, 0], ext[:, 1] = np.inf, -np.inf
        at = next(i for i, a in enumerate(self.arrays) if a is self.cell_ext)
        off = self.arrays
        self.arrays = (*off[:at], ext, *off[at + 1 :])
        try:
            self.reset(x0)
            self.advance(periods, False, 0, np.zeros((periods, ms.ROW)),
                         np.zeros((periods, self.nx)))  # fmt: skip
        finally:
            self.arrays = off
        return 0.5 * (ext[:, 1] - ext[:, 0])

    def reset(self, x0: np.ndarray) -> None:
        """Start from the chain state ``x0`` at forcing phase 0; a cell already on a stop has
        its contact episode in progress (no new impact is counted), as for the unit cell."""
        self.x[:] = x0
        self.kst[:] = 0.0
        b = self._W.shape[1]
        for j in range(len(self.contact)):
            w = float(self._W[j] @ x0[j * b : (j + 1) * b])
            g1, g2 = self._g1[j], self._g2[j]
            self.contact[j] = (
                1.0 if g1 - w <= ms.OPEN_FRAC * g1 else 2.0 if g2 + w <= ms.OPEN_FRAC * g2 else 0.0
            )

    def _save(self) -> object:
        return self.contact.copy()

    def _restore(self, extra: object) -> None:
        self.contact[:] = extra  # type: ignore[index]


class ChainEulerRun(ChainSteppingRun):
    """A chain integrated by the paper's scheme (``method: euler``)."""

    name = "euler"
    kernel = staticmethod(chain_euler_kernel)

    @classmethod
    def check_point(cls, cs: ChainSystem, settings: SolverSettings) -> int:  # type: ignore[override]
        """The steps per period this chain runs at; refused beyond the stability limit of the
        whole chain or beyond ``MAX_STEPS_PER_PERIOD``, or with a pinned cell."""
        refuse_pinned(cs)
        view = _SteppingView(cs.params.cell, cs.Minv, cs.K, cs.C)
        spp = settings.steps_per_period or default_steps(view)  # type: ignore[arg-type]
        if spp > MAX_STEPS_PER_PERIOD:
            raise ValueError(
                f"the euler scheme needs steps_per_period >= {spp} for this chain "
                f"(Δτ·ω̃_max <= 1), more than the limit {MAX_STEPS_PER_PERIOD}"
            )
        check_stable(view, 2.0 * math.pi / cs.params.cell.gamma_r / spp)  # type: ignore[arg-type]
        return spp

    def __init__(self, cs: ChainSystem, settings: SolverSettings, tail: ChainTail,
                 forcing: bool, div_limit: float) -> None:  # fmt: skip
        super().__init__(cs, settings, tail, forcing, div_limit)
        p = cs.params
        N = p.n_cells
        self.spp = self.check_point(cs, settings)
        c = np.ascontiguousarray
        W, MinvX, g1, g2 = cell_blocks(cs)
        G = np.array([s.G for s in cs.cells])
        self.contact = np.zeros(N)
        self.cell_ext = np.zeros((0, 2))  # off until ``cell_ranges`` turns it on
        self.arrays = (
            self.spp, p.cell.gamma_r, self.f_scale, *sparse_rows(cs.Minv @ cs.C, cs.Minv @ cs.K),
            c(cs.Minv[:, cs.s_index[0]]), MinvX, cs.f_sin, cs.f_cos, W, cs.cells[-1].d, G, g1,
            g2, self.contact, np.zeros(N), np.zeros(N), self.cell_ext, settings.lcp == "lemke",
            np.zeros((2 * N, 2 * N)), np.zeros(2 * N), *lemke_workspace(2 * N),
        )  # fmt: skip
        self._W, self._g1, self._g2 = W, g1, g2
        self.xn = np.zeros(self.nx)
