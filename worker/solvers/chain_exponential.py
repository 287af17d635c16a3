"""``method: exponential`` for a chain of N cells (docs/model.md §11, docs/chains.md): the exact
propagator of the whole chain with Moreau impulses at its 2N stops.

As for the unit cell (``exponential.py``): free flight takes whole coarse steps with the exact
map ``x ← Φ x + E [cos; sin]`` of the whole chain (the harmonic forcing, which drives cell 1,
carried in the state). A coarse step is kept unless some cell's tip may come near one of its
stops over it (the cubic Hermite fit of that cell's tip position and velocity at both ends,
against each stop less ``near_margin`` of its gap); otherwise it is redone as ``n_sub`` fine
steps, each with Moreau impulses at its start sized so that no cell's predicted end gap is
negative.

The fine step's contact problem couples the cells: an impulse ``P_i = Λ2_i − Λ1_i`` at cell i's
stops changes cell i's velocities only (M is block-diagonal), but over the fine step the springs
carry it on, and cell j's end tip moves by ``Gf[j, i] P_i`` with
``Gf[j, i] = W_j (Φ_f [0; M⁻¹X_i])_u``. ``Gf`` is diagonally dominant (its diagonal is each
cell's own gain, ~ G_j Δτ_f; a neighbour's entry is smaller by ~ Δτ_f², a cell k apart's by
~ Δτ_f^{2k}), but not diagonal. The 2N × 2N LCP (``Λ ≥ 0 ⊥ end gaps ≥ 0``) is solved by
:func:`chain_impulses`: each cell's closed form alone first (exact when no cell needs an
impulse, the common case, or when ``Gf`` is diagonal), otherwise block Gauss–Seidel sweeps with
each cell's two-stop closed form given its neighbours' impulses, to a relative change of
``GS_RTOL`` in the impulses (a contraction by the off-diagonal ratio a sweep), and Lemke's
algorithm on the whole LCP if the sweeps do not converge (or always, with ``lcp="lemke"``).

The period's row measures the last cell exactly (first harmonics of s_N and its beam's s_b by
exact Fourier rows of the propagator, the phase-portrait integrals by Gauss–Legendre rows, the
range of s_N by the cubic Hermite fit between steps); contact episodes are counted per cell as
``chain_euler`` counts them, and the regime digit is the same base-3 code of the cells' contact.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.model.chain import ChainSystem
from worker.solvers import measure as ms
from worker.solvers.chain_euler import ChainSteppingRun, ChainTail, cell_blocks, refuse_pinned
from worker.solvers.exponential import DEFAULT_STEPS, MIN_GAIN_RATIO, _expm, _propagate
from worker.solvers.lcp import LEMKE_OK, lemke_nb, lemke_workspace, two_stop_impulses
from worker.solvers.settings import MAX_STEPS_PER_PERIOD, SolverSettings
from worker.solvers.stepping import contact_step, extrema, tally_impulses

__all__ = ["GS_RTOL", "ChainExponentialRun", "chain_exponential_kernel", "chain_impulses"]

# The block Gauss–Seidel sweeps stop once no cell's net impulse changed by more than this
# fraction of the largest impulse; the end gaps then satisfy complementarity to about
# GS_RTOL·max|Gf_ij|·max|Λ| (the off-diagonal entries carry the last change).
GS_RTOL = 1e-14
# Sweeps before the LCP goes to Lemke's algorithm instead (a diagonally dominant Gf converges
# in a few: the change shrinks by the off-diagonal ratio, ~1e-5 at the default fine step).
GS_MAX_SWEEPS = 100


@njit(cache=True, nogil=True)
def chain_impulses(Gf, c1, c2, lam1, lam2, coupled, use_lemke, lcp_M, lcp_q, lcp_T,
                   lcp_basis, lcp_cand, lcp_B, lcp_xb, lcp_z):  # fmt: skip
    """The impulses (``lam1``, ``lam2``, written) at every cell's two stops that make the
    predicted end gaps ``c1_j − Σ_i Gf[j, i] P_i`` and ``c2_j + Σ_i Gf[j, i] P_i``
    (``P_i = lam2_i − lam1_i``) complementary to them. ``lcp_M`` holds the 2N × 2N matrix built
    from ``Gf``. Returns the Gauss–Seidel sweeps taken (0: the per-cell closed forms were
    already the solution), −1 when Lemke's algorithm solved it, −2 when it failed (the
    impulses are then NaN, so the point fails as not finite)."""
    ncell = Gf.shape[0]
    active = False
    for c in range(ncell):
        l1, l2 = two_stop_impulses(Gf[c, c], c1[c], c2[c])
        lam1[c] = l1
        lam2[c] = l2
        if l1 > 0.0 or l2 > 0.0:
            active = True
    # no cell needs an impulse on its own: Λ = 0 solves the whole LCP (the end gaps are c1, c2)
    if not active or not coupled:
        return 0
    if not use_lemke:
        for sweep in range(GS_MAX_SWEEPS):
            change = 0.0
            size = 0.0
            for c in range(ncell):
                s = 0.0  # cell c's end tip moved by the other cells' impulses
                for i in range(ncell):
                    if i != c and (lam1[i] != 0.0 or lam2[i] != 0.0):
                        s += Gf[c, i] * (lam2[i] - lam1[i])
                l1, l2 = two_stop_impulses(Gf[c, c], c1[c] - s, c2[c] + s)
                change = max(change, abs((l2 - l1) - (lam2[c] - lam1[c])))
                size = max(size, l1, l2)
                lam1[c] = l1
                lam2[c] = l2
            if change <= GS_RTOL * size:
                return sweep + 1
    for c in range(ncell):
        lcp_q[2 * c] = c1[c]
        lcp_q[2 * c + 1] = c2[c]
    # at most one pivot per complementary pair and the artificial variable, on a generic LCP;
    # the budget is the unit cell's 50 per cell
    status = lemke_nb(lcp_M, lcp_q, lcp_T, lcp_basis, lcp_cand, lcp_B, lcp_xb, lcp_z, 50 * ncell)
    if status != LEMKE_OK:
        for c in range(ncell):
            lam1[c] = np.nan
            lam2[c] = np.nan
        return -2
    for c in range(ncell):
        lam1[c] = lcp_z[2 * c]
        lam2[c] = lcp_z[2 * c + 1]
    return -1


def lcp_matrix(Gf: np.ndarray) -> np.ndarray:
    """The 2N × 2N LCP matrix of the fine step: rows/columns 2j, 2j + 1 are cell j's stops 1
    and 2; ``w = q + M z`` are the end gaps, ``q = [c1_0, c2_0, c1_1, …]``."""
    N = Gf.shape[0]
    M = np.zeros((2 * N, 2 * N))
    M[0::2, 0::2] = Gf
    M[0::2, 1::2] = -Gf
    M[1::2, 0::2] = -Gf
    M[1::2, 1::2] = Gf
    return M


@njit(cache=True, nogil=True, inline="always")
def _harmonics(psi, psib, P, x, cf, sf, rot_c, rot_s, nx, ncell):
    """``stepping.harmonics`` with one impulse column per cell (``psib`` (2, N), ``P`` (N))."""
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    out3 = 0.0
    for r in range(2):
        zr = 0.0
        zi = 0.0
        for c in range(ncell):
            zr += psib[r, c].real * P[c]
            zi += psib[r, c].imag * P[c]
        for j in range(nx):
            zr += psi[r, j].real * x[j]
            zi += psi[r, j].imag * x[j]
        zr += psi[r, nx].real * cf + psi[r, nx + 1].real * sf
        zi += psi[r, nx].imag * cf + psi[r, nx + 1].imag * sf
        if r == 0:
            out0 = zr * rot_c - zi * rot_s
            out1 = zr * rot_s + zi * rot_c
        else:
            out2 = zr * rot_c - zi * rot_s
            out3 = zr * rot_s + zi * rot_c
    return out0, out1, out2, out3


@njit(cache=True, nogil=True, inline="always")
def _portrait(gl, glb, P, x, cf, sf, dt, nx, ncell):
    """``stepping.portrait`` with one impulse column per cell (``glb`` (4, 2, N))."""
    vv = 0.0
    vb = 0.0
    for j in range(4):
        v = 0.0
        b = 0.0
        for c in range(ncell):
            v += glb[j, 0, c] * P[c]
            b += glb[j, 1, c] * P[c]
        v += gl[j, 0, nx] * cf + gl[j, 0, nx + 1] * sf
        b += gl[j, 1, nx] * cf + gl[j, 1, nx + 1] * sf
        for i in range(nx):
            v += gl[j, 0, i] * x[i]
            b += gl[j, 1, i] * x[i]
        wj = ms.GL_WEIGHTS[j]
        vv += wj * v * v
        vb += wj * b * v
    return dt * vv, dt * vb


@njit(cache=True, nogil=True, inline="always")
def _track(cell_ext, x, v0, xn, nd, b, ncell, dt):
    """Each cell's outer-mass extrema widened by one step from ``x`` (its velocity ``v0[c]`` at
    the step's start, after any impulse) to ``xn``."""
    for c in range(ncell):
        sj = (c + 1) * b - 1
        cell_ext[c, 0], cell_ext[c, 1] = extrema(
            x[sj], v0[c], xn[sj], xn[nd + sj], dt, cell_ext[c, 0], cell_ext[c, 1]
        )


@njit(**ms.KERNEL_JIT)
def chain_exponential_kernel(x, kst, ring, n_periods, measure, checks, rows, samples, hist, xh,
                             n_coarse, n_sub, gamma_r, f_scale, Phi_c, E_c, Phi_f, E_f, B_f,
                             Gf, G, coupled, psi_c, psi_f, psib_f, gl_c, gl_f, glb_f, W, d,
                             MinvX_s, g1, g2, margin, adaptive, contact, lam1, lam2, c1, c2,
                             P, P0, glb0, cell_ext, xv, use_lemke, lcp_M, lcp_q, lcp_T,
                             lcp_basis, lcp_cand, lcp_B, lcp_xb, lcp_z, lin_L, lin_xp, lin_amp,
                             lin_gate, div_limit, tol, xn):  # fmt: skip
    """Advance up to ``n_periods`` periods of the chain; returns (periods done, END code,
    period found). ``W`` (N, b): cell j's tip row on its own block of b = n + 1 coordinates;
    ``B_f`` (N, nx): the fine step's propagated unit impulse at cell j's stops; ``G`` (N): the
    cells' G, the tip velocity a unit impulse gives at once; ``contact`` (N)
    holds each cell's contact episode between batches; ``cell_ext`` (N × 2, or empty: off)
    accumulates each cell's outer-mass extrema, min and max, as the period rows do for the last
    cell (``ChainSteppingRun.cell_ranges``)."""
    nx = x.shape[0]
    nd = nx // 2
    ncell = W.shape[0]
    b = W.shape[1]
    n = b - 1
    sN = nd - 1  # the last cell's outer mass
    oN = nd - b  # the last cell's block
    track = cell_ext.shape[0] > 0
    T = 2.0 * math.pi / gamma_r
    dtc = T / n_coarse
    dtf = dtc / n_sub
    rot_cd = math.cos(gamma_r * dtf)
    rot_sd = math.sin(gamma_r * dtf)
    for k in range(n_periods):
        ms.begin_row(rows, k)
        period = kst[ms.K_PERIOD]
        smin = np.inf
        smax = -np.inf
        h0 = h1 = h2 = h3 = vv = vb = 0.0
        imp1 = imp2 = peak = nsteps = ncontact = ncoarse = 0.0
        # summed over the cells (the engine's last-cell view; a chain reports none of them)
        ct1 = ct2 = vimp1 = vimp2 = en1 = en2 = 0.0
        last = -1.0
        for jc in range(n_coarse):
            phase = jc * dtc
            tau_c = period * T + phase
            cos0 = math.cos(gamma_r * phase)
            sin0 = math.sin(gamma_r * phase)
            if adaptive:
                # whole coarse step in free flight, kept unless a cell's tip may come near
                # one of its stops
                cf = cos0 * f_scale
                sf = sin0 * f_scale
                _propagate(Phi_c, E_c, x, cf, sf, xn, nx)
                clear = True
                for c in range(ncell):
                    off = c * b
                    w0 = 0.0
                    w1 = 0.0
                    wv0 = 0.0
                    wv1 = 0.0
                    for i in range(b):
                        w0 += W[c, i] * x[off + i]
                        w1 += W[c, i] * xn[off + i]
                        wv0 += W[c, i] * x[nd + off + i]
                        wv1 += W[c, i] * xn[nd + off + i]
                    wmin, _, wmax, _ = ms.cubic_minmax(w0, wv0, w1, wv1, dtc)
                    if not (wmax < g1[c] * (1.0 - margin) and wmin > -g2[c] * (1.0 - margin)):
                        clear = False
                        break
                if clear:
                    if measure:
                        a0, a1, a2, a3 = _harmonics(psi_c, psib_f, P0, x, cf, sf, cos0, -sin0,
                                                    nx, ncell)  # fmt: skip
                        h0 += a0
                        h1 += a1
                        h2 += a2
                        h3 += a3
                        b0, b1 = _portrait(gl_c, glb0, P0, x, cf, sf, dtc, nx, ncell)
                        vv += b0
                        vb += b1
                    if track:
                        for c in range(ncell):
                            xv[c] = x[nd + (c + 1) * b - 1]
                        _track(cell_ext, x, xv, xn, nd, b, ncell, dtc)
                    s0 = x[sN]
                    v0 = x[nd + sN]
                    for i in range(nx):
                        x[i] = xn[i]
                    ncoarse += 1.0
                    nsteps += 1.0
                    smin, smax = extrema(s0, v0, x[sN], x[nd + sN], dtc, smin, smax)
                    for c in range(ncell):
                        if contact[c] != 0.0:
                            state, imp1, imp2, peak, last = contact_step(
                                0.0, 0.0, phase / T, int(contact[c]), imp1, imp2, peak, last,
                                W[c], x[c * b :], b, g1[c], g2[c],
                            )  # fmt: skip
                            contact[c] = state
                    if hist.shape[0] > 0:
                        ms.record(hist, xh, kst, tau_c + dtc, x[sN], ms.dot(W[ncell - 1],
                                  x[oN:], b), ms.dot(d, x[oN:], n), x[nd + sN],
                                  ms.dot(d, x[nd + oN :], n), 0.0, 0.0, 0.0, x, nx)  # fmt: skip
                    continue
            cph = cos0
            sph = sin0
            for js in range(n_sub):
                if js > 0:
                    tmp = cph * rot_cd - sph * rot_sd
                    sph = sph * rot_cd + cph * rot_sd
                    cph = tmp
                cf = cph * f_scale
                sf = sph * f_scale
                s0 = x[sN]
                v0 = x[nd + sN]
                _propagate(Phi_f, E_f, x, cf, sf, xn, nx)
                for c in range(ncell):
                    off = c * b
                    wend = 0.0
                    for i in range(b):
                        wend += W[c, i] * xn[off + i]
                    c1[c] = g1[c] - wend
                    c2[c] = g2[c] + wend
                chain_impulses(Gf, c1, c2, lam1, lam2, coupled, use_lemke, lcp_M, lcp_q, lcp_T,
                               lcp_basis, lcp_cand, lcp_B, lcp_xb, lcp_z)  # fmt: skip
                solved = False
                for c in range(ncell):
                    Pc = lam2[c] - lam1[c]
                    P[c] = Pc
                    if Pc != 0.0:
                        solved = True
                        # at once at the step's start, on cell c's block only
                        vm = ms.dot(W[c], x[nd + c * b :], b)
                        ct1, ct2, vimp1, vimp2, en1, en2 = tally_impulses(
                            lam1[c], lam2[c], contact[c], vm, vm, vm + G[c] * Pc, G[c], dtf, ct1,
                            ct2, vimp1, vimp2, en1, en2,
                        )  # fmt: skip
                        for i in range(nx):
                            xn[i] += B_f[c, i] * Pc
                # Moreau: the step's trajectory starts after the impulse (only the last cell's
                # own impulse moves s_N's velocity: M is block-diagonal)
                v0 += MinvX_s[ncell - 1] * P[ncell - 1]
                if measure:
                    a0, a1, a2, a3 = _harmonics(psi_f, psib_f, P, x, cf, sf, cph, -sph, nx,
                                                ncell)  # fmt: skip
                    h0 += a0
                    h1 += a1
                    h2 += a2
                    h3 += a3
                    b0, b1 = _portrait(gl_f, glb_f, P, x, cf, sf, dtf, nx, ncell)
                    vv += b0
                    vb += b1
                if track:
                    # each cell's velocity after its own impulse (Moreau), as v0 for s_N
                    for c in range(ncell):
                        xv[c] = x[nd + (c + 1) * b - 1] + MinvX_s[c] * P[c]
                    _track(cell_ext, x, xv, xn, nd, b, ncell, dtf)
                for i in range(nx):
                    x[i] = xn[i]
                nsteps += 1.0
                smin, smax = extrema(s0, v0, x[sN], x[nd + sN], dtf, smin, smax)
                if solved:
                    ncontact += 1.0
                for c in range(ncell):
                    if P[c] != 0.0 or contact[c] != 0.0:
                        state, imp1, imp2, peak, last = contact_step(
                            lam1[c], lam2[c], (phase + js * dtf) / T, int(contact[c]), imp1,
                            imp2, peak, last, W[c], x[c * b :], b, g1[c], g2[c],
                        )  # fmt: skip
                        contact[c] = state
                if hist.shape[0] > 0:
                    ms.record(hist, xh, kst, tau_c + (js + 1) * dtf, x[sN],
                              ms.dot(W[ncell - 1], x[oN:], b), ms.dot(d, x[oN:], n),
                              x[nd + sN], ms.dot(d, x[nd + oN :], n), lam1[ncell - 1],
                              lam2[ncell - 1], 0.0, x, nx)  # fmt: skip
        # the contact state at the period's end, one base-3 digit per cell (as chain_euler)
        regime = 0.0
        for c in range(ncell - 1, -1, -1):
            regime = 3.0 * regime + contact[c]
        ms.close_row(rows, k, smin, smax, (h0, h1, h2, h3), vv, vb, imp1, imp2, peak, last,
                     nsteps, ncontact, ncoarse, regime)  # fmt: skip
        ms.close_impacts(rows, k, ct1, ct2, vimp1, vimp2, en1, en2)
        kst[ms.K_CONTACT] = regime
        kst[ms.K_PERIOD] += 1.0
        code, p = ms.period_end(x, nx, rows, samples, k, ring, kst, lin_L, lin_xp, lin_amp,
                                lin_gate, checks, div_limit, tol)  # fmt: skip
        if code != ms.END_NONE:
            return k + 1, code, p
    return n_periods, ms.END_NONE, 0


# --------------------------------------------------------------------------- set-up


def augmented_matrix(cs: ChainSystem) -> np.ndarray:
    """``ż = A_aug z``, ``z = [u; q; cos γ_r τ; sin γ_r τ]``, of the chain (as
    ``System.augmented_matrix``; the base force enters at s_1)."""
    n = cs.ndof
    g = cs.params.cell.gamma_r
    A = np.zeros((2 * n + 2, 2 * n + 2))
    A[:n, n : 2 * n] = np.eye(n)
    A[n : 2 * n, :n] = -cs.Minv @ cs.K
    A[n : 2 * n, n : 2 * n] = -cs.Minv @ cs.C
    fs = cs.Minv[:, cs.s_index[0]]
    A[n : 2 * n, 2 * n] = fs * cs.f_cos
    A[n : 2 * n, 2 * n + 1] = fs * cs.f_sin
    A[2 * n, 2 * n + 1] = -g
    A[2 * n + 1, 2 * n] = g
    return A


def _fourier_rows(cs: ChainSystem, A_aug: np.ndarray, dt: float) -> np.ndarray:
    """Rows ψ with ψ·z(0) = ∫₀^dt [s_N; s_b,N](t) e^{-iγt} dt exactly, for free flight from
    z(0) (``exponential.fourier_rows`` on the last cell's coordinates)."""
    nz = A_aug.shape[0]
    B = np.zeros((2 * nz, 2 * nz), dtype=complex)
    B[:nz, :nz] = A_aug - 1j * cs.params.cell.gamma_r * np.eye(nz)
    B[:nz, nz:] = np.eye(nz)
    integral = _expm(B * dt)[:nz, nz:]
    return np.ascontiguousarray(_last_cell_rows(cs, nz, 0) @ integral)


def _last_cell_rows(cs: ChainSystem, nz: int, at: int) -> np.ndarray:
    """(2, nz) rows picking [s_N; s_b,N] (``at`` = 0) or their velocities (``at`` = ndof)."""
    nd = cs.ndof
    d = cs.cells[-1].d
    n = len(d)
    oN = nd - (n + 1)
    R = np.zeros((2, nz))
    R[0, at + nd - 1] = 1.0
    R[1, at + oN : at + oN + n] = d
    return R


def _gauss_rows(cs: ChainSystem, A_aug: np.ndarray, dt: float) -> np.ndarray:
    """(4, 2, nz) rows of (ṡ_N, ṡ_b,N) at the Gauss nodes of a step of ``dt``."""
    nz = A_aug.shape[0]
    R = _last_cell_rows(cs, nz, cs.ndof)
    return np.ascontiguousarray(np.array([R @ _expm(A_aug * t) for t in ms.GL_NODES * dt]))


class ChainExponentialRun(ChainSteppingRun):
    """A chain integrated by the exact propagator with Moreau impulses
    (``method: exponential``)."""

    name = "exponential"
    kernel = staticmethod(chain_exponential_kernel)

    @classmethod
    def check_point(cls, cs: ChainSystem, settings: SolverSettings) -> None:  # type: ignore[override]
        """Refuse a chain with a pinned cell."""
        refuse_pinned(cs)

    def __init__(self, cs: ChainSystem, settings: SolverSettings, tail: ChainTail,
                 forcing: bool, div_limit: float) -> None:  # fmt: skip
        super().__init__(cs, settings, tail, forcing, div_limit)
        self.check_point(cs, settings)
        p = cs.params
        N = p.n_cells
        nd = cs.ndof
        nx = self.nx
        gamma_r = p.cell.gamma_r
        T = 2.0 * math.pi / gamma_r
        spp = settings.steps_per_period or DEFAULT_STEPS
        A_aug = augmented_matrix(cs)
        # one column per cell: the state change [0; M⁻¹X_j] of a unit impulse at its stops
        bvec = np.zeros((nx, N))
        bvec[nd:, :] = cs.Minv @ cs.X.T
        G = np.array([s.G for s in cs.cells])
        while True:
            n_coarse = min(settings.coarse_steps, spp)
            while spp % n_coarse:
                n_coarse -= 1
            n_sub = spp // n_coarse
            dtf = T / spp
            Pf = _expm(A_aug * dtf)
            B_f = Pf[:nx, :nx] @ bvec  # (nx, N)
            Gf = cs.W @ B_f[:nd, :]  # Gf[j, i]: cell j's end tip per unit impulse at cell i
            gain = np.diag(Gf)
            low = gain < MIN_GAIN_RATIO * G * dtf
            if not np.any(low):
                break
            # the fine step does not resolve some cell's tip modes: the impulse that closes
            # its gap at the step's end would be mis-sized (or of the wrong sign). Refine.
            if 2 * spp > MAX_STEPS_PER_PERIOD:
                j = int(np.argmax(low))
                raise ValueError(
                    f"exponential: the fine step T/{spp} does not resolve cell {j + 1}'s tip "
                    f"modes (contact gain {gain[j]:.3g} < {MIN_GAIN_RATIO} G Δτ = "
                    f"{MIN_GAIN_RATIO * G[j] * dtf:.3g}) even at the {MAX_STEPS_PER_PERIOD} "
                    "steps per period limit"
                )
            spp *= 2
        self.spp = spp
        dtc = T / n_coarse
        Pc = _expm(A_aug * dtc)
        off = Gf - np.diag(gain)
        # numerically diagonal: the cells' closed forms are the LCP's solution
        coupled = bool(np.max(np.abs(off), initial=0.0) > 1e-15 * np.min(gain))
        psi_c = _fourier_rows(cs, A_aug, dtc)
        psi_f = _fourier_rows(cs, A_aug, dtf)
        gl_c = _gauss_rows(cs, A_aug, dtc)
        gl_f = _gauss_rows(cs, A_aug, dtf)
        W, MinvX, g1, g2 = cell_blocks(cs)
        c = np.ascontiguousarray
        self.contact = np.zeros(N)
        self.cell_ext = np.zeros((0, 2))  # off until ``cell_ranges`` turns it on
        self.Gf = Gf
        self.coupled = coupled
        self.arrays = (
            n_coarse, n_sub, gamma_r, self.f_scale, c(Pc[:nx, :nx]), c(Pc[:nx, nx:]),
            c(Pf[:nx, :nx]), c(Pf[:nx, nx:]), c(B_f.T), c(Gf), G, coupled, psi_c, psi_f,
            c(psi_f[:, :nx] @ bvec), gl_c, gl_f, c(gl_f[:, :, :nx] @ bvec), W, cs.cells[-1].d,
            c(MinvX[:, -1]), g1, g2, settings.near_margin, settings.adaptive, self.contact,
            np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N),
            np.zeros((4, 2, N)), self.cell_ext, np.zeros(N), settings.lcp == "lemke",
            lcp_matrix(Gf),
            np.zeros(2 * N), *lemke_workspace(2 * N),
        )  # fmt: skip
        self._W, self._g1, self._g2 = W, g1, g2
        self.xn = np.zeros(nx)
