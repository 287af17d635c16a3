"""numba kernels: the time loop of one point.

Everything here works on preallocated arrays and scalars; nothing in the time loop allocates,
so memory does not grow with the number of steps (histories go to a fixed-size ring buffer).
The drivers in ``simulate.py`` prepare the matrices and read the ``out`` record.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.lcp import LEMKE_OK, lemke_nb

METHOD_EULER = 0
METHOD_EXPONENTIAL = 1

# ``out`` record layout.
O_S_MAX = 0
O_S_MIN = 1
O_S_RE = 2
O_S_IM = 3
O_SB_RE = 4
O_SB_IM = 5
O_THETA_MEAN_SUM = 6
O_THETA_MEAN_T = 7
O_IMPACTS1 = 8
O_IMPACTS2 = 9
O_PEAK_IMPULSE = 10
O_MEASURED_PERIODS = 11
O_PERIODS = 12
O_STEPS = 13
O_CONTACT_STEPS = 14
O_RESPONSE_PERIOD = 15
O_CONVERGED = 16
O_FAILED = 17  # 0 ok, 1 non-finite state, 2 no contact solution
O_FAIL_PERIOD = 18
O_COARSE_SKIPPED = 19  # coarse steps taken whole (fine sub-steps saved)
O_HIST_COUNT = 20
O_SDOT_MAX = 21
O_STEADY_PERIOD = 22  # period index at which periodicity was detected (-1 none)
OUT_SIZE = 24

# history columns
H_TAU = 0
H_S = 1
H_WTIP = 2
H_SB = 3
H_SDOT = 4
H_SBDOT = 5
H_L1 = 6
H_L2 = 7
H_COLS = 8

MAX_PERIOD = 8
RING = 2 * MAX_PERIOD + 1


@njit(cache=True)
def _dot(a, x, n):
    acc = 0.0
    for i in range(n):
        acc += a[i] * x[i]
    return acc


@njit(cache=True)
def _hermite_extrema(s0, v0, s1, v1, dt):
    """Interior (min, max) of the cubic Hermite interpolant on a step; (inf, -inf) if none."""
    # p(t) = a t³ + b t² + c t + s0 on t ∈ [0, 1] with p'(0) = v0 dt, p'(1) = v1 dt.
    lo = np.inf
    hi = -np.inf
    c = v0 * dt
    a = 2.0 * s0 + c - 2.0 * s1 + v1 * dt
    b = 3.0 * (s1 - s0) - 2.0 * c - v1 * dt
    qa = 3.0 * a  # p'(t) = qa t² + qb t + c
    qb = 2.0 * b
    if abs(qa) < 1e-300:
        if abs(qb) > 1e-300:
            t = -c / qb
            if 0.0 < t < 1.0:
                p = ((a * t + b) * t + c) * t + s0
                lo = min(lo, p)
                hi = max(hi, p)
        return lo, hi
    disc = qb * qb - 4.0 * qa * c
    if disc < 0.0:
        return lo, hi
    qq = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))  # stable pair of roots
    for k in range(2):
        if k == 0:
            t = qq / qa
        elif qq != 0.0:
            t = c / qq
        else:
            continue
        if 0.0 < t < 1.0:
            p = ((a * t + b) * t + c) * t + s0
            lo = min(lo, p)
            hi = max(hi, p)
    return lo, hi


@njit(cache=True)
def _measure_sample(out, s0, v0, s1, v1, vb1, dt, kappa, theta, thr, l1, l2, contact_prev):
    """Accumulate amplitude, θ_eff time average and contact counts for one step [s0 → s1]."""
    lo = s1
    hi = s1
    if v0 * v1 <= 0.0:
        lo, hi = _hermite_extrema(s0, v0, s1, v1, dt)
        lo = min(lo, s1)
        hi = max(hi, s1)
    out[O_S_MAX] = max(out[O_S_MAX], hi)
    out[O_S_MIN] = min(out[O_S_MIN], lo)
    if abs(v1) >= thr and abs(v1) > 0.0:
        out[O_THETA_MEAN_SUM] += dt * (kappa - theta * vb1 / v1) / (1.0 + theta)
        out[O_THETA_MEAN_T] += dt
    if l1 > 0.0 and contact_prev != 1:
        out[O_IMPACTS1] += 1.0
    if l2 > 0.0 and contact_prev != 2:
        out[O_IMPACTS2] += 1.0
    out[O_PEAK_IMPULSE] = max(out[O_PEAK_IMPULSE], l1, l2)


@njit(cache=True)
def _reset_measure(out):
    out[O_S_MAX] = -np.inf
    out[O_S_MIN] = np.inf
    for k in range(O_S_RE, O_MEASURED_PERIODS + 1):
        out[k] = 0.0


@njit(cache=True)
def _record(hist, out, hist_cap, tau, s, w, sb, v, vb, l1, l2, x, xh):
    if hist_cap == 0:
        return
    k = int(out[O_HIST_COUNT]) % hist_cap
    hist[k, H_TAU] = tau
    hist[k, H_S] = s
    hist[k, H_WTIP] = w
    hist[k, H_SB] = sb
    hist[k, H_SDOT] = v
    hist[k, H_SBDOT] = vb
    hist[k, H_L1] = l1
    hist[k, H_L2] = l2
    for i in range(x.shape[0]):
        xh[k, i] = x[i]
    out[O_HIST_COUNT] += 1.0


@njit(cache=True)
def _periodicity(ring, nring, period_idx, x, tol, nx):
    """Smallest p in 1…8 with x_k ≈ x_{k-p}, allowing for the remaining geometric transient."""
    scale = 0.0
    for i in range(nx):
        scale = max(scale, abs(x[i]))
    scale = max(scale, 1e-300)
    for p in range(1, MAX_PERIOD + 1):
        if nring < 2 * p + 1:
            break
        a = (period_idx - p) % RING
        b = (period_idx - 2 * p) % RING
        d1 = 0.0
        d2 = 0.0
        for i in range(nx):
            d1 = max(d1, abs(x[i] - ring[a, i]))
            d2 = max(d2, abs(ring[a, i] - ring[b, i]))
        if d1 > tol * scale:
            continue
        # Remaining transient of a geometric decay with ratio rho = d1/d2 is d1·rho/(1-rho).
        if d1 <= 1e-13 * scale:
            return p
        if d2 > 0.0:
            rho = d1 / d2
            if rho < 0.95 and d1 / (1.0 - rho) <= tol * scale:
                return p
    return 0


@njit(cache=True)
def _propagate(Phi, E, x, cf, sf, xn, nx):
    """xn = Φ x + E [cos; sin]: the exact free-flight step."""
    for i in range(nx):
        acc = E[i, 0] * cf + E[i, 1] * sf
        for j in range(nx):
            acc += Phi[i, j] * x[j]
        xn[i] = acc


@njit(cache=True)
def _accumulate_harmonics(out, psi, psib, P, x, cf, sf, rot_c, rot_s, nx):
    """Add e^{-iγτ}·∫ [s; s_b] e^{-iγt} dt over one exact step (impulse P at its start)."""
    for r in range(2):
        zr = psib[r].real * P
        zi = psib[r].imag * P
        for j in range(nx):
            zr += psi[r, j].real * x[j]
            zi += psi[r, j].imag * x[j]
        zr += psi[r, nx].real * cf + psi[r, nx + 1].real * sf
        zi += psi[r, nx].imag * cf + psi[r, nx + 1].imag * sf
        out[O_S_RE + 2 * r] += zr * rot_c - zi * rot_s
        out[O_S_IM + 2 * r] += zr * rot_s + zi * rot_c


@njit(cache=True)
def _all_finite(x, nx):
    """Whether the first nx entries of x are finite."""
    for i in range(nx):  # noqa: SIM110 - a plain loop compiles to the tightest numba code
        if not math.isfinite(x[i]):
            return False
    return True


@njit(cache=True)
def _period_sample(ring, nring, period_idx, x, tol, nx, early_stop):
    """Store the stroboscopic sample of this period; the response period found (0: none yet).

    ``nring`` counts the samples stored, this one included. Shared by every method so that all
    classify responses by the same rule.
    """
    slot = period_idx % RING
    for i in range(nx):
        ring[slot, i] = x[i]
    if not early_stop:
        return 0
    p = _periodicity(ring, nring, period_idx, x, tol, nx)
    if p > 1:
        p = _smallest_divisor_period(ring, period_idx, x, tol, nx, p)
    return p


@njit(cache=True)
def _smallest_divisor_period(ring, period_idx, x, tol, nx, p):
    """A p-periodic state found while a slow transient lingers may really be q-periodic, q | p."""
    scale = 0.0
    for i in range(nx):
        scale = max(scale, abs(x[i]))
    for q in range(1, p):
        if p % q:
            continue
        a = (period_idx - q) % RING
        dq = 0.0
        for i in range(nx):
            dq = max(dq, abs(x[i] - ring[a, i]))
        if dq <= 10.0 * tol * scale:
            return q
    return p


@njit(cache=True)
def simulate_kernel(
    method,
    x,
    n_coarse,
    n_sub,
    gamma_r,
    f_scale,
    Phi_c,
    E_c,
    Phi_f,
    E_f,
    b_f,
    psi_c,
    psi_f,
    psib_f,
    MinvC,
    MinvK,
    Minv_es,
    MinvX,
    f_sin,
    f_cos,
    W,
    d,
    G,
    g1,
    g2,
    kappa,
    theta,
    max_periods,
    tol,
    window,
    margin,
    adaptive,
    early_stop,
    open_frac,
    hist,
    xh,
    out,
    xn,
    ring,
    use_lemke=False,
):
    """Run one point from state ``x`` until steady state or the period budget.

    ``method`` 0 is the paper's semi-implicit Euler with the two-stop closed-form LCP at every
    step; 1 is the exact propagator with Moreau impulses, taking whole coarse steps in free
    flight and ``n_sub`` fine sub-steps only where a stop may be reached.
    ``psi_c``/``psi_f`` (2 × (2N+2), complex) integrate [s; s_b]·e^{-iγt} exactly over a step.
    ``use_lemke`` (euler only) solves each step's two-stop LCP with the compiled Lemke of
    ``worker/lcp.py``, as the paper does, instead of the closed form (same solution).
    """
    nx = x.shape[0]
    N = nx // 2
    n = N - 1  # modes; s is u[n]
    T = 2.0 * math.pi / gamma_r
    if method == METHOD_EULER:
        n_sub = 1
    dtc = T / n_coarse
    dtf = dtc / n_sub
    rot_cd = math.cos(gamma_r * dtf)
    rot_sd = math.sin(gamma_r * dtf)
    hist_cap = hist.shape[0]
    Gf = G  # inverse effective tip mass seen by an impulse over one fine step
    if method == METHOD_EXPONENTIAL:
        Gf = _dot(W, b_f, N)
    # Lemke's LCP data and workspace (allocated once per point, only if used)
    nl = 2 if use_lemke else 1
    lcp_M = np.empty((nl, nl))
    lcp_q = np.zeros(nl)
    lcp_T = np.zeros((nl, 2 * nl + 2))
    lcp_basis = np.zeros(nl, dtype=np.int64)
    lcp_cand = np.zeros(nl, dtype=np.int64)
    lcp_B = np.zeros((nl, nl))
    lcp_xb = np.zeros(nl)
    lcp_z = np.zeros(nl)
    if use_lemke:
        gdt = G * dtc  # euler: n_sub = 1, so Δτ = dtc
        lcp_M[0, 0] = gdt
        lcp_M[0, 1] = -gdt
        lcp_M[1, 0] = -gdt
        lcp_M[1, 1] = gdt

    for k in range(OUT_SIZE):
        out[k] = 0.0
    out[O_STEADY_PERIOD] = -1.0
    _reset_measure(out)
    nring = 0
    contact_prev = 0
    measuring = False
    measure_end = -1
    thr = 0.0
    sdot_max_period = 0.0
    # margin: fraction of each gap inside which a stop counts as near.
    always_fine = (g1 + g2) <= 0.0 or margin < 0.0 or not adaptive
    steps = 0
    contact_steps = 0
    coarse_whole = 0
    period = 0

    while True:
        # ---- decide what this period is for
        if not measuring and period >= max_periods - window:
            measuring = True
            measure_end = max_periods
            _reset_measure(out)
            thr = 1e-3 * sdot_max_period
        if measuring and period >= measure_end:
            break
        sdot_max_this = 0.0
        for jc in range(n_coarse):
            tau_c = (period * n_coarse + jc) * dtc
            phase = jc * dtc
            s0 = x[n]
            v0 = x[N + n]
            cos0 = math.cos(gamma_r * phase)
            sin0 = math.sin(gamma_r * phase)
            fine = True
            if method == METHOD_EXPONENTIAL and not always_fine:
                # Whole coarse step in free flight; keep it unless the tip may come near a stop.
                cf = cos0 * f_scale
                sf = sin0 * f_scale
                _propagate(Phi_c, E_c, x, cf, sf, xn, nx)
                w0 = _dot(W, x, N)
                wv0 = 0.0
                w1 = _dot(W, xn, N)
                wv1 = 0.0
                for i in range(N):
                    wv0 += W[i] * x[N + i]
                    wv1 += W[i] * xn[N + i]
                wmin, wmax = _hermite_extrema(w0, wv0, w1, wv1, dtc)
                wmin = min(wmin, w0, w1)
                wmax = max(wmax, w0, w1)
                if wmax < g1 * (1.0 - margin) and wmin > -g2 * (1.0 - margin):
                    fine = False
                    steps += 1
                    coarse_whole += 1
                    if measuring:
                        # e^{-iγτ}: τ and the phase differ by whole periods
                        _accumulate_harmonics(out, psi_c, psib_f, 0.0, x, cf, sf, cos0, -sin0, nx)
                    for i in range(nx):
                        x[i] = xn[i]
                    s1 = x[n]
                    v1 = x[N + n]
                    sdot_max_this = max(sdot_max_this, abs(v1))
                    if measuring:
                        vb1 = _dot(d, x[N:], n)
                        _measure_sample(
                            out, s0, v0, s1, v1, vb1, dtc, kappa, theta, thr, 0.0, 0.0, 0
                        )
                    if hist_cap > 0:
                        _record(
                            hist,
                            out,
                            hist_cap,
                            tau_c + dtc,
                            s1,
                            w1,
                            _dot(d, x, n),
                            v1,
                            _dot(d, x[N:], n),
                            0.0,
                            0.0,
                            x,
                            xh,
                        )
                    contact_prev = 0
            if not fine:
                continue
            # cos/sin of the forcing phase by rotation within the coarse step (exact restart at
            # each coarse step keeps the recurrence's round-off to n_sub rotations).
            cph = cos0
            sph = sin0
            for js in range(n_sub):
                if js > 0:
                    tmp = cph * rot_cd - sph * rot_sd
                    sph = sph * rot_cd + cph * rot_sd
                    cph = tmp
                tau = tau_c + js * dtf
                s0 = x[n]
                v0 = x[N + n]
                if method == METHOD_EULER:
                    fval = f_scale * (f_sin * sph + f_cos * cph)
                    # q_f = q + Δτ M⁻¹(-C q - K u + e_s f)
                    for i in range(N):
                        acc = Minv_es[i] * fval
                        for j in range(N):
                            acc -= MinvC[i, j] * x[N + j] + MinvK[i, j] * x[j]
                        xn[N + i] = x[N + i] + dtf * acc
                    wpred = 0.0
                    for i in range(N):
                        wpred += W[i] * (x[i] + dtf * xn[N + i])
                    c1 = g1 - wpred
                    c2 = g2 + wpred
                    if use_lemke:
                        lcp_q[0] = c1
                        lcp_q[1] = c2
                        status = lemke_nb(lcp_M, lcp_q, lcp_T, lcp_basis, lcp_cand, lcp_B,
                                          lcp_xb, lcp_z, 50)  # fmt: skip
                        if status == LEMKE_OK:
                            l1 = lcp_z[0]
                            l2 = lcp_z[1]
                        else:  # no solution: the point ends as failed (non-finite state)
                            l1 = np.nan
                            l2 = 0.0
                    else:
                        l1 = max(0.0, -c1) / (G * dtf)
                        l2 = max(0.0, -c2) / (G * dtf)
                    P = l2 - l1
                    for i in range(N):
                        xn[N + i] += MinvX[i] * P
                        xn[i] = x[i] + dtf * xn[N + i]
                    if measuring:
                        # Rectangle rule on a uniform grid over whole periods: the discrete
                        # Fourier coefficient of the scheme's own samples.
                        rc = cph
                        rs = -sph
                        sbv = _dot(d, x, n)
                        out[O_S_RE] += dtf * x[n] * rc
                        out[O_S_IM] += dtf * x[n] * rs
                        out[O_SB_RE] += dtf * sbv * rc
                        out[O_SB_IM] += dtf * sbv * rs
                else:
                    cf = cph * f_scale
                    sf = sph * f_scale
                    _propagate(Phi_f, E_f, x, cf, sf, xn, nx)
                    wend = _dot(W, xn, N)
                    c1 = g1 - wend
                    c2 = g2 + wend
                    l1 = max(0.0, -c1) / Gf
                    l2 = max(0.0, -c2) / Gf
                    P = l2 - l1
                    if P != 0.0:
                        for i in range(nx):
                            xn[i] += b_f[i] * P
                    if measuring:
                        _accumulate_harmonics(out, psi_f, psib_f, P, x, cf, sf, cph, -sph, nx)
                    if P != 0.0:
                        # The step's trajectory starts after the impulse (Moreau: impulse first).
                        v0 += MinvX[n] * P
                steps += 1
                if l1 > 0.0 or l2 > 0.0:
                    contact_steps += 1
                for i in range(nx):
                    x[i] = xn[i]
                s1 = x[n]
                v1 = x[N + n]
                sdot_max_this = max(sdot_max_this, abs(v1))
                if measuring:
                    vb1 = _dot(d, x[N:], n)
                    _measure_sample(
                        out,
                        s0,
                        v0,
                        s1,
                        v1,
                        vb1,
                        dtf,
                        kappa,
                        theta,
                        thr,
                        l1,
                        l2,
                        contact_prev,
                    )
                if hist_cap > 0:
                    _record(
                        hist,
                        out,
                        hist_cap,
                        tau + dtf,
                        s1,
                        _dot(W, x, N),
                        _dot(d, x, n),
                        v1,
                        _dot(d, x[N:], n),
                        l1,
                        l2,
                        x,
                        xh,
                    )
                # A contact episode ends only once the tip has opened the gap by open_eps, so the
                # scheme's chatter at a release is not counted as new impacts.
                if l1 > 0.0:
                    contact_prev = 1
                elif l2 > 0.0:
                    contact_prev = 2
                elif contact_prev != 0:
                    wc = _dot(W, x, N)
                    if (contact_prev == 1 and g1 - wc > open_frac * g1) or (
                        contact_prev == 2 and g2 + wc > open_frac * g2
                    ):
                        contact_prev = 0
        # ---- end of period: health, stroboscopic sample, periodicity
        period += 1
        sdot_max_period = sdot_max_this
        if not _all_finite(x, nx):
            out[O_FAILED] = 1.0
            out[O_FAIL_PERIOD] = period
            break
        if measuring:
            out[O_MEASURED_PERIODS] += 1.0
            continue
        nring += 1
        p = _period_sample(ring, nring, period, x, tol, nx, early_stop)
        if p > 0:
            out[O_RESPONSE_PERIOD] = p
            out[O_CONVERGED] = 1.0
            out[O_STEADY_PERIOD] = period
            measuring = True
            measure_end = period + p
            _reset_measure(out)
            thr = 1e-3 * sdot_max_period

    out[O_PERIODS] = period
    out[O_STEPS] = steps
    out[O_CONTACT_STEPS] = contact_steps
    out[O_COARSE_SKIPPED] = coarse_whole
    out[O_SDOT_MAX] = sdot_max_period
