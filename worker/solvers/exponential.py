"""``method: exponential``: the exact propagator with Moreau impulses (docs/model.md §5).

Free flight takes whole coarse steps with the exact map ``x ← Φ x + E [cos; sin]`` (the
harmonic forcing carried in the state). Before a coarse step is kept, the tip's path over it
(the cubic Hermite fit of position and velocity at both ends) is checked against each stop with
a margin of ``near_margin`` of that stop's gap; if it may come near, the step is redone as
``n_sub`` fine steps, each with a Moreau impulse at its start sized so that the predicted end
gap is zero (the two-stop complementarity in closed form, with the fine step's contact gain
``G_f = Wᵀ(Φ_f [0; M⁻¹X])_u``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.model import System
from worker.solvers import measure as ms
from worker.solvers.lcp import two_stop_impulses
from worker.solvers.settings import MAX_STEPS_PER_PERIOD, SolverSettings
from worker.solvers.stepping import (
    SteppingRun,
    contact_step,
    extrema,
    gauss_rows,
    harmonics,
    portrait,
    record_step,
    tally_impulses,
)

DEFAULT_STEPS = 2048
# The fine step's contact gain must be at least this fraction of its short-step value G·Δτ;
# below it the step does not resolve the tip's modes and the impulse would be mis-sized.
MIN_GAIN_RATIO = 0.5


@njit(cache=True, nogil=True)
def _propagate(Phi, E, x, cf, sf, xn, nx):
    """xn = Φ x + E [cos; sin]: the exact free-flight step."""
    for i in range(nx):
        acc = E[i, 0] * cf + E[i, 1] * sf
        for j in range(nx):
            acc += Phi[i, j] * x[j]
        xn[i] = acc


@njit(cache=True, nogil=True, inline="always")
def _resting(lam, dt, held, pend, ct):
    """The time on a stop of a resting tip under Newton's law (e > 0): an impulse at a step's
    start leaves the tip off the stop by what the step's acceleration moves it, so a resting
    tip takes one every other step. A single impulse-free step between two impulse steps at
    the same stop is counted on it (``held``: 1 after an impulse step, 2 after one free step
    that followed one, whose time is ``pend``). Returns (held, pend, ct)."""
    if lam > 0.0:
        if held == 2:
            ct += pend
        return 1, 0.0, ct
    if held == 1:
        return 2, dt, ct
    return 0, 0.0, ct


@njit(**ms.KERNEL_JIT)
def exponential_kernel(x, kst, ring, n_periods, measure, checks, rows, samples, hist, xh,
                       n_coarse, n_sub, gamma_r, f_scale, Phi_c, E_c, Phi_f, E_f, b_f, psi_c,
                       psi_f, psib_f, gl_c, gl_f, glb_f, glb0, W, d, Gf, G, Gv, MinvX_s, g1, g2,
                       e1, e2, margin, adaptive, lin_L, lin_xp, lin_amp, lin_gate, div_limit, tol,
                       xn):  # fmt: skip
    """Advance up to ``n_periods`` periods; returns (periods done, END code, period found).

    With ``e1 = e2 = 0`` a fine step's impulse closes the predicted end gap (plastic); otherwise
    a stop whose end gap would close takes at the step's start Newton's impulse, which turns
    the tip's approach velocity v into −e v, or the impulse that stops it approaching at the
    step's end if that is larger (Newton's law,
    Moreau–Jean; ``G``: the tip velocity a unit impulse gives at once, ``Gv``: at the step's
    end)."""
    nx = x.shape[0]
    N = nx // 2
    n = N - 1
    T = 2.0 * math.pi / gamma_r
    elastic = e1 > 0.0 or e2 > 0.0
    dtc = T / n_coarse
    dtf = dtc / n_sub
    rot_cd = math.cos(gamma_r * dtf)
    rot_sd = math.sin(gamma_r * dtf)
    always_fine = (g1 + g2) <= 0.0 or not adaptive
    for k in range(n_periods):
        ms.begin_row(rows, k)
        period = kst[ms.K_PERIOD]
        contact = int(kst[ms.K_CONTACT])
        smin = np.inf
        smax = -np.inf
        h0 = h1 = h2 = h3 = vv = vb = 0.0
        imp1 = imp2 = peak = nsteps = ncontact = ncoarse = 0.0
        ct1 = ct2 = vimp1 = vimp2 = en1 = en2 = 0.0
        held1 = held2 = 0
        pend1 = pend2 = 0.0
        last = -1.0
        for jc in range(n_coarse):
            phase = jc * dtc
            tau_c = period * T + phase
            cos0 = math.cos(gamma_r * phase)
            sin0 = math.sin(gamma_r * phase)
            if not always_fine:
                # whole coarse step in free flight, kept unless the tip may come near a stop
                cf = cos0 * f_scale
                sf = sin0 * f_scale
                _propagate(Phi_c, E_c, x, cf, sf, xn, nx)
                w0 = ms.dot(W, x, N)
                w1 = ms.dot(W, xn, N)
                wv0 = 0.0
                wv1 = 0.0
                for i in range(N):
                    wv0 += W[i] * x[N + i]
                    wv1 += W[i] * xn[N + i]
                wmin, _, wmax, _ = ms.cubic_minmax(w0, wv0, w1, wv1, dtc)
                if wmax < g1 * (1.0 - margin) and wmin > -g2 * (1.0 - margin):
                    if measure:
                        a0, a1, a2, a3 = harmonics(psi_c, psib_f, 0.0, x, cf, sf, cos0, -sin0,
                                                   nx)  # fmt: skip
                        h0 += a0
                        h1 += a1
                        h2 += a2
                        h3 += a3
                        b0, b1 = portrait(gl_c, glb0, 0.0, x, cf, sf, dtc, nx)
                        vv += b0
                        vb += b1
                    s0 = x[n]
                    v0 = x[N + n]
                    for i in range(nx):
                        x[i] = xn[i]
                    ncoarse += 1.0
                    nsteps += 1.0
                    held1 = held2 = 0
                    smin, smax = extrema(s0, v0, x[n], x[N + n], dtc, smin, smax)
                    if contact != 0:
                        contact, imp1, imp2, peak, last = contact_step(
                            0.0, 0.0, phase / T, contact, imp1, imp2, peak, last, W, x, N, g1, g2
                        )
                    if hist.shape[0] > 0:
                        record_step(hist, xh, kst, tau_c + dtc, x, nx, W, d, N, n, 0.0, 0.0)
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
                s0 = x[n]
                v0 = x[N + n]
                _propagate(Phi_f, E_f, x, cf, sf, xn, nx)
                wend = ms.dot(W, xn, N)
                if elastic:
                    wv0 = 0.0
                    wvend = 0.0
                    for i in range(N):
                        wv0 += W[i] * x[N + i]
                        wvend += W[i] * xn[N + i]
                    # Newton's impulse at the step's start, or more where the tip would still
                    # approach the stop at the step's end (a resting contact)
                    l1 = l2 = 0.0
                    if g1 - wend <= 0.0:
                        l1 = max((1.0 + e1) * max(wv0, 0.0) / G, wvend / Gv, 0.0)
                    if g2 + wend <= 0.0:
                        l2 = max((1.0 + e2) * max(-wv0, 0.0) / G, -wvend / Gv, 0.0)
                    held1, pend1, ct1 = _resting(l1, dtf, held1, pend1, ct1)
                    held2, pend2, ct2 = _resting(l2, dtf, held2, pend2, ct2)
                else:
                    l1, l2 = two_stop_impulses(Gf, g1 - wend, g2 + wend)
                P = l2 - l1
                if P != 0.0:
                    # the impulse acts at once at the step's start: Wᵀq → Wᵀq + G P
                    vm = ms.dot(W, x[N:], N)
                    ct1, ct2, vimp1, vimp2, en1, en2 = tally_impulses(
                        l1, l2, contact, vm, vm, vm + G * P, G, dtf, ct1, ct2, vimp1, vimp2, en1,
                        en2,
                    )  # fmt: skip
                    for i in range(nx):
                        xn[i] += b_f[i] * P
                    v0 += MinvX_s * P  # Moreau: the step's trajectory starts after the impulse
                if measure:
                    a0, a1, a2, a3 = harmonics(psi_f, psib_f, P, x, cf, sf, cph, -sph, nx)
                    h0 += a0
                    h1 += a1
                    h2 += a2
                    h3 += a3
                    b0, b1 = portrait(gl_f, glb_f, P, x, cf, sf, dtf, nx)
                    vv += b0
                    vb += b1
                for i in range(nx):
                    x[i] = xn[i]
                nsteps += 1.0
                smin, smax = extrema(s0, v0, x[n], x[N + n], dtf, smin, smax)
                if P != 0.0:
                    ncontact += 1.0
                if P != 0.0 or contact != 0:
                    contact, imp1, imp2, peak, last = contact_step(
                        l1, l2, (phase + js * dtf) / T, contact, imp1, imp2, peak, last, W, x,
                        N, g1, g2,
                    )  # fmt: skip
                if hist.shape[0] > 0:
                    record_step(hist, xh, kst, tau_c + (js + 1) * dtf, x, nx, W, d, N, n, l1, l2)
        ms.close_row(rows, k, smin, smax, (h0, h1, h2, h3), vv, vb, imp1, imp2, peak, last,
                     nsteps, ncontact, ncoarse, contact)  # fmt: skip
        ms.close_impacts(rows, k, ct1, ct2, vimp1, vimp2, en1, en2)
        kst[ms.K_CONTACT] = contact  # read at the next period's start, this batch or the next
        kst[ms.K_PERIOD] += 1.0
        code, p = ms.period_end(x, nx, rows, samples, k, ring, kst, lin_L, lin_xp, lin_amp,
                                lin_gate, checks, div_limit, tol)  # fmt: skip
        if code != ms.END_NONE:
            return k + 1, code, p
    return n_periods, ms.END_NONE, 0


def _expm(A: np.ndarray) -> np.ndarray:
    """The matrix exponential (scipy's). scipy is imported here, at a point's set-up: it costs
    ~0.4 s of CPU to import, which processes that never run this method do not pay."""
    import scipy.linalg

    return scipy.linalg.expm(A)


def fourier_rows(sys_: System, A_aug: np.ndarray, dt: float) -> np.ndarray:
    """Rows ψ with ψ·z(0) = ∫₀^dt [s; s_b](t) e^{-iγt} dt exactly, for free flight from z(0)."""
    nz = A_aug.shape[0]
    # ∫₀^dt e^{(A - iγ)t} dt is the top-right block of exp([[A - iγ, I], [0, 0]] dt).
    B = np.zeros((2 * nz, 2 * nz), dtype=complex)
    B[:nz, :nz] = A_aug - 1j * sys_.params.gamma_r * np.eye(nz)
    B[:nz, nz:] = np.eye(nz)
    integral = _expm(B * dt)[:nz, nz:]
    n = sys_.ndof - 1
    R = np.zeros((2, nz))
    R[0, n] = 1.0  # s
    R[1, :n] = sys_.d  # s_b
    return np.ascontiguousarray(R @ integral)


class ExponentialRun(SteppingRun):
    """A point integrated by the exact propagator with Moreau impulses."""

    name = "exponential"
    kernel = staticmethod(exponential_kernel)

    def __init__(self, sys_: System, settings: SolverSettings, *args) -> None:
        super().__init__(sys_, settings, *args)
        p = sys_.params
        nx = self.nx
        T = 2.0 * math.pi / p.gamma_r
        spp = settings.steps_per_period or DEFAULT_STEPS
        A_aug = sys_.augmented_matrix()
        b = np.zeros(nx)
        b[sys_.ndof :] = sys_.Minv @ sys_.X
        G = sys_.G
        while True:
            n_coarse = min(settings.coarse_steps, spp)
            while spp % n_coarse:
                n_coarse -= 1
            n_sub = spp // n_coarse
            dtf = T / spp
            Pf = _expm(A_aug * dtf)
            b_f = Pf[:nx, :nx] @ b
            Gf = float(sys_.W @ b_f[: sys_.ndof])
            # the end tip velocity of a unit impulse (Newton's law for e > 0)
            Gv = float(sys_.W @ b_f[sys_.ndof :])
            if Gf >= MIN_GAIN_RATIO * G * dtf and (not p.elastic or Gv >= MIN_GAIN_RATIO * G):
                break
            # The fine step does not resolve the tip's lowest modes: the impulse that closes
            # the gap at the step's end would be mis-sized (or of the wrong sign). Refine.
            if 2 * spp > MAX_STEPS_PER_PERIOD:
                raise ValueError(
                    f"exponential: the fine step T/{spp} does not resolve the tip's modes "
                    f"(contact gain {Gf:.3g} < {MIN_GAIN_RATIO} G Δτ = "
                    f"{MIN_GAIN_RATIO * G * dtf:.3g}) even at the {MAX_STEPS_PER_PERIOD} steps "
                    f"per period limit; use method event"
                )
            spp *= 2
        self.spp = spp
        dtc = T / n_coarse
        Pc = _expm(A_aug * dtc)
        psi_c = fourier_rows(sys_, A_aug, dtc)
        psi_f = fourier_rows(sys_, A_aug, dtf)
        N = sys_.ndof
        gl_f = gauss_rows(lambda t: _expm(A_aug * t), dtf, N, sys_.d)
        gl_c = gauss_rows(lambda t: _expm(A_aug * t), dtc, N, sys_.d)
        c = np.ascontiguousarray
        self.arrays = (
            n_coarse, n_sub, p.gamma_r, self.f_scale, c(Pc[:nx, :nx]), c(Pc[:nx, nx:]),
            c(Pf[:nx, :nx]), c(Pf[:nx, nx:]), c(b_f), psi_c, psi_f, c(psi_f[:, :nx] @ b),
            gl_c, gl_f, c(gl_f[:, :, :nx] @ b), np.zeros((4, 2)), sys_.W, sys_.d, Gf, G, Gv,
            float((sys_.Minv @ sys_.X)[-1]), p.g1, p.g2, p.e1, p.e2, settings.near_margin,
            settings.adaptive,
        )  # fmt: skip
        self.xn = np.zeros(nx)
