"""The event-driven kernel: whole periods of exact regime propagation between located events.

Per sub-grid interval ``h = T/n_grid`` of the current regime (``regimes.py``):

* a cheap test first: the cubic Hermite interpolant of the tip (free flight) or of the contact
  force (stuck) from both ends, widened by ``h⁴/384·|f⁗|`` at the ends, must stay
  ``near_margin`` clear of the stop (of zero force, relative to the force); the interval is
  then taken whole with the precomputed step map;
* otherwise an exact search of the gap or contact force (``roots.first_root``) over the rest
  of the interval; the piece up to the first event is propagated exactly and the event is
  applied: at an impact the plastic impulse ``P = -Wᵀq/G`` along ``M⁻¹X`` zeroes the tip's
  velocity and the tip sticks if the stuck regime's contact force is compressive (or zero and
  increasing), else it leaves at once; a stuck tip is released where the force reaches zero.
  After leaving a stop the search for it starts once the gap has opened above round-off
  (``roots.skip_start``), so a release is never taken for a new impact;
* a per-period event budget ends a run that chatters.

Each period fills one row of the measurement layout (``measure.py``). The extrema of ``s`` are
located exactly (Newton on ``ṡ = 0``) when measuring, else taken from the Hermite
interpolant; the first harmonics are exact integrals; the phase-portrait integrals use four
Gauss nodes per piece.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.solvers import measure as ms
from worker.solvers.event import roots as rt
from worker.solvers.event.regimes import (
    R_MU,
    R_MU4,
    R_MUD,
    R_S,
    R_SB,
    R_SBD,
    R_SD,
    R_W,
    R_W4,
    R_WD,
)

# A state beyond this size ends the run (diverged): the search's error bounds (|c|·|λ|⁴·h⁴)
# overflow well before the state does, and a search on non-finite values never proves an
# interval clear (it would split ~4¹⁵ times per interval, i.e. hang).
MAX_STATE = 1e200

# Reassociation lets LLVM vectorise the small dot products and matrix-vector products (a
# different summation order, never NaN/inf assumptions).
FAST = {"reassoc", "contract"}

# kernel state entries (after the common ones of measure.py)
K_REGIME = ms.K_METHOD  # 0 free, 1/2 stuck on stop 1/2
K_SKIP_ON = ms.K_METHOD + 1  # the search of the current constraint starts late
K_SKIP_STOP = ms.K_METHOD + 2
K_SKIP_REM = ms.K_METHOD + 3
K_PENDING = ms.K_METHOD + 4  # >0: impact at once at this stop; <0: stick-or-leave after one
K_EVLOG = ms.K_METHOD + 5  # event log rows written

#: Columns of the event log (``history["events"]`` of method ``event``), described.
EVENT_FIELDS = {
    "tau": "non-dimensional time tau of the event",
    "kind": "event kind: 1 impact, 2 release",
    "stop": "stop index (1 or 2)",
    "residual": "residual of the event condition at the located time (gap over clearance at "
    "an impact, contact force over its scale at a release)",
    "impulse": "contact impulse of the event",
}
EV_COLS = len(EVENT_FIELDS)

# ----------------------------------------------------------------------------- state helpers


@njit(cache=True, nogil=True, fastmath=FAST)
def _modal(Vi, r, y, nk, nz, a):
    for i in range(nk):
        acc = 0.0 + 0.0j
        for j in range(nz):
            acc += Vi[r, i, j] * y[j]
        a[i] = acc


@njit(cache=True, nogil=True, fastmath=FAST)
def _state_E(V, r, a, E, nk, nz, out):
    for i in range(nz):
        acc = 0.0
        for k in range(nk):
            acc += (V[r, i, k] * (a[k] * E[k])).real
        out[i] = acc


@njit(cache=True, nogil=True)
def _coef(RV, r, row, a, nk, sgn, c):
    for k in range(nk):
        c[k] = sgn * RV[r, row, k] * a[k]


@njit(cache=True, nogil=True, fastmath=FAST)
def _row(R, r, row, y, nz):
    acc = 0.0
    for i in range(nz):
        acc += R[r, row, i] * y[i]
    return acc


@njit(cache=True, nogil=True, fastmath=FAST)
def _row_scale(R, r, row, y, nz):
    acc = 0.0
    for i in range(nz):
        acc += abs(R[r, row, i] * y[i])
    return acc


@njit(cache=True, nogil=True, fastmath=FAST)
def _matvec(A, r, y, nz, out):
    for i in range(nz):
        acc = 0.0
        for j in range(nz):
            acc += A[r, i, j] * y[j]
        out[i] = acc


@njit(cache=True, nogil=True)
def full_state(r, y, Qout, N, x):
    """The full state x = [u; q] of the regime state y."""
    nzm = 2 * N + 2
    if r == 0:
        for i in range(2 * N):
            x[i] = y[i]
        return
    for i in range(2 * N):
        acc = 0.0
        for j in range(nzm - 1):
            acc += Qout[r - 1, i, j] * y[j]
        x[i] = acc


@njit(cache=True, nogil=True)
def _record(hist, xh, kst, tau, R, r, y, nz, l1, l2, kind, Qout, N, x):
    if hist.shape[0] == 0:
        return
    full_state(r, y, Qout, N, x)
    ms.record(hist, xh, kst, tau, _row(R, r, R_S, y, nz), _row(R, r, R_W, y, nz),
              _row(R, r, R_SB, y, nz), _row(R, r, R_SD, y, nz), _row(R, r, R_SBD, y, nz), l1,
              l2, kind, x, 2 * N)  # fmt: skip


@njit(cache=True, nogil=True)
def _log_event(evlog, kst, tau, kind, stop, resid, impulse):
    cap = evlog.shape[0]
    if cap == 0:
        return
    k = int(kst[K_EVLOG]) % cap
    evlog[k, 0] = tau
    evlog[k, 1] = kind
    evlog[k, 2] = stop
    evlog[k, 3] = resid
    evlog[k, 4] = impulse
    kst[K_EVLOG] += 1.0


# ----------------------------------------------------------------------------- measurement


@njit(cache=True, nogil=True)
def _phase_rot(zr, zi, ph):
    """e^{-i ph}·(zr + i zi) as (re, im)."""
    rc = math.cos(ph)
    rs = -math.sin(ph)
    return zr * rc - zi * rs, zr * rs + zi * rc


@njit(cache=True, nogil=True)
def _measure_interval(r, y, ye, nz, R, psi, gl, h, ph0, Vi, RV, lam, nk, a, cw, tol_t):
    """Measure a whole sub-grid interval (y → ye = Φ y): exact extremum, exact harmonics,
    Gauss nodes for the phase portrait. Returns (lo, hi, s re, s im, s_b re, s_b im, ∫ṡ²,
    ∫ṡ_b ṡ)."""
    s0 = _row(R, r, R_S, y, nz)
    sd0 = _row(R, r, R_SD, y, nz)
    s1 = _row(R, r, R_S, ye, nz)
    sd1 = _row(R, r, R_SD, ye, nz)
    lo = min(s0, s1)
    hi = max(s0, s1)
    if sd0 * sd1 < 0.0:
        _modal(Vi, r, y, nk[r], nz, a)
        sc = _extremum(r, a, nk[r], lam, RV, h, sd0, sd1, tol_t, cw)
        lo = min(lo, sc)
        hi = max(hi, sc)
    # all twelve sums in one pass: each is still accumulated in index order (the same bits),
    # but twelve independent chains keep the adder busy where one or four wait on its latency
    z0r = z0i = z1r = z1i = 0.0
    v0 = v1 = v2 = v3 = 0.0
    q0 = q1 = q2 = q3 = 0.0
    for i in range(nz):
        yi = y[i]
        z0r += psi[r, 0, i].real * yi
        z0i += psi[r, 0, i].imag * yi
        z1r += psi[r, 1, i].real * yi
        z1i += psi[r, 1, i].imag * yi
        v0 += gl[r, 0, 0, i] * yi
        q0 += gl[r, 0, 1, i] * yi
        v1 += gl[r, 1, 0, i] * yi
        q1 += gl[r, 1, 1, i] * yi
        v2 += gl[r, 2, 0, i] * yi
        q2 += gl[r, 2, 1, i] * yi
        v3 += gl[r, 3, 0, i] * yi
        q3 += gl[r, 3, 1, i] * yi
    a0, a1 = _phase_rot(z0r, z0i, ph0)
    b0, b1 = _phase_rot(z1r, z1i, ph0)
    w = ms.GL_WEIGHTS
    vv = 0.0
    vv += w[0] * v0 * v0
    vv += w[1] * v1 * v1
    vv += w[2] * v2 * v2
    vv += w[3] * v3 * v3
    vb = 0.0
    vb += w[0] * q0 * v0
    vb += w[1] * q1 * v1
    vb += w[2] * q2 * v2
    vb += w[3] * q3 * v3
    return lo, hi, a0, a1, b0, b1, h * vv, h * vb


@njit(cache=True, nogil=True)
def _extremum(r, a, nk, lam, RV, ln, sd0, sd1, tol_t, cw):
    """s at the exact root of ṡ inside a piece where ṡ changes sign."""
    sgn = 1.0 if sd0 > 0.0 else -1.0
    _coef(RV, r, R_SD, a, nk, sgn, cw)
    tc = rt.refine(cw, lam[r], nk, 0.0, 0.0, ln, abs(sd0), -abs(sd1), 1e-3 * tol_t)
    _coef(RV, r, R_S, a, nk, 1.0, cw)
    sc, _ = rt.ev(cw, lam[r], nk, 0.0, tc)
    return sc


@njit(cache=True, nogil=True)
def _phi_shift(E, lam, shift, ln, es):
    """(e^{(λ+shift)·ln} - 1)/(λ + shift) from E = e^{λ·ln} and es = e^{shift·ln}."""
    x = lam + shift
    z = x * ln
    if z.real * z.real + z.imag * z.imag < 1e-6:  # |z| < 1e-3 without a hypot
        return ln * (1.0 + z / 2.0 * (1.0 + z / 3.0 * (1.0 + z / 4.0 * (1.0 + z / 5.0))))
    return (E * es - 1.0) / x


@njit(cache=True, nogil=True)
def _measure_piece(r, a, nk, lam, RV, wt, E, ln, s0, sd0, s1, sd1, ph, gamma_r, measure, tol_t,
                   cw):  # fmt: skip
    """Measure an exactly propagated piece of length ln (modal coefficients a at its start,
    E = e^{λ ln} of the kept modes). Returns what :func:`_measure_interval` returns; without
    ``measure`` only the range of s (from the Hermite interpolant) and zeros."""
    lo = min(s0, s1)
    hi = max(s0, s1)
    if ln <= 0.0:
        return lo, hi, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if sd0 * sd1 < 0.0:
        if measure:
            sc = _extremum(r, a, nk, lam, RV, ln, sd0, sd1, tol_t, cw)
            lo = min(lo, sc)
            hi = max(hi, sc)
        else:
            lo, _, hi, _ = ms.cubic_minmax(s0, sd0, s1, sd1, ln)
    if not measure:
        return lo, hi, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    shift = -1j * gamma_r
    es = rt.cexp(shift * ln)
    acc0 = 0.0 + 0.0j
    acc1 = 0.0 + 0.0j
    for m in range(nk):
        lm = lam[r, m]
        p = _phi_shift(E[m], lm, shift, ln, es)
        if wt[r, m] == 2.0:  # the pair (λ, λ̄) of a real sum: both terms of ∫ Re(·) e^{-iγt}
            pc = _phi_shift(E[m].conjugate(), lm.conjugate(), shift, ln, es)
            c = RV[r, R_S, m] * a[m]
            acc0 += 0.5 * (c * p + c.conjugate() * pc)
            c = RV[r, R_SB, m] * a[m]
            acc1 += 0.5 * (c * p + c.conjugate() * pc)
        else:
            acc0 += RV[r, R_S, m] * a[m] * p
            acc1 += RV[r, R_SB, m] * a[m] * p
    a0, a1 = _phase_rot(acc0.real, acc0.imag, ph)
    b0, b1 = _phase_rot(acc1.real, acc1.imag, ph)
    # ṡ and ṡ_b at the four Gauss nodes; the nodes are symmetric, so the step from the third
    # to the fourth is the one from the first to the second (three exponentials per mode)
    t0 = ms.GL_NODES[0] * ln
    t1 = ms.GL_NODES[1] * ln
    t2 = ms.GL_NODES[2] * ln
    v0 = v1 = v2 = v3 = 0.0
    q0 = q1 = q2 = q3 = 0.0
    for m in range(nk):
        lm = lam[r, m]
        rd = RV[r, R_SD, m]
        rb = RV[r, R_SBD, m]
        step = rt.cexp(lm * (t1 - t0))
        e = a[m] * rt.cexp(lm * t0)
        v0 += (rd * e).real
        q0 += (rb * e).real
        e *= step
        v1 += (rd * e).real
        q1 += (rb * e).real
        e = a[m] * rt.cexp(lm * t2)
        v2 += (rd * e).real
        q2 += (rb * e).real
        e *= step
        v3 += (rd * e).real
        q3 += (rb * e).real
    w = ms.GL_WEIGHTS
    vv = w[0] * v0 * v0 + w[1] * v1 * v1 + w[2] * v2 * v2 + w[3] * v3 * v3
    vb = w[0] * q0 * v0 + w[1] * q1 * v1 + w[2] * q2 * v2 + w[3] * q3 * v3
    return lo, hi, a0, a1, b0, b1, ln * vv, ln * vb


@njit(cache=True, nogil=True)
def _opened(contact, y, ye, ln, R, RV, Vi, lam, nk, nz, g1, g2, a, have_a, cw):
    """The contact episode state after a free piece: it ends once the gap of its stop has
    opened to ``OPEN_FRAC`` of the clearance (exact maximum of the gap over the piece).

    The exact maximum (Newton on the gap's slope, which near the round-off floor falls back to
    tens of bisections) is sought only where the ends and the gap's Hermite cubic leave it in
    doubt: not where the gap falls, then rises (its maximum is at an end), nor where the cubic
    plus its error bound stays below the threshold, nor where the gap at the cubic's maximum is
    above it."""
    sgn = -1.0 if contact == 1 else 1.0
    gk = g1 if contact == 1 else g2
    thr = ms.OPEN_FRAC * gk
    f0 = gk + sgn * _row(R, 0, R_W, y, nz)
    d0 = sgn * _row(R, 0, R_WD, y, nz)
    f1 = gk + sgn * _row(R, 0, R_W, ye, nz)
    d1 = sgn * _row(R, 0, R_WD, ye, nz)
    if f0 > thr or f1 > thr:
        return 0
    _, _, fmax, tmax = ms.cubic_minmax(f0, d0, f1, d1, ln)
    if fmax <= 0.5 * thr:
        return contact
    if d0 < 0.0 <= d1:
        # falling, then rising: the maximum is at an end, and neither is above the threshold
        # (the slope's root in between is a minimum, which the search below would locate)
        return contact
    if not have_a:
        _modal(Vi, 0, y, nk[0], nz, a)
    _coef(RV, 0, R_W, a, nk[0], sgn, cw)
    scale = gk
    bnd = 0.0
    for k in range(nk[0]):
        lk = lam[0, k]
        m2 = lk.real * lk.real + lk.imag * lk.imag
        ak = rt.cabs(cw[k])
        scale += ak
        bnd += ak * m2 * m2 * (1.0 if lk.real <= 0.0 else math.exp(lk.real * ln))
    if fmax + bnd * ln * ln * ln * ln / 384.0 + 1e-12 * scale < thr:
        return contact  # the gap stays below the threshold over the whole piece
    fm, _ = rt.ev(cw, lam[0], nk[0], gk, tmax)
    if fm > thr + 1e-12 * scale:
        return 0  # above it at one point: the maximum is too
    tc = rt.crit(cw, lam[0], nk[0], 0.0, ln, d0, d1, tmax)
    fc, _ = rt.ev(cw, lam[0], nk[0], gk, tc)
    return 0 if fc > thr else contact


# ----------------------------------------------------------------------------- events


@njit(cache=True, nogil=True)
def stick_or_leave(y, k, bilateral, Pin, Qout, R, RV, Vi, lam, nk, N, g1, g2, h, ye, x, x2, a,
                   cw):  # fmt: skip
    """After an impact at stop k: stick if the contact force is compressive (or zero and
    growing), else leave. A departure whose gap never opens above round-off within an interval
    (the force turns compressive again at once) is taken as stuck, and vice versa. Returns
    (ok, regime, skip_on, skip_stop, skip_rem); ok is False if neither works (the impact is
    then repeated, bounded by the event budget)."""
    nzm = 2 * N + 2
    nx = 2 * N
    kk = 1 if bilateral else k
    for i in range(nzm - 1):
        acc = 0.0
        for jj in range(nzm):
            acc += Pin[kk - 1, i, jj] * y[jj]
        ye[i] = acc
    ye[nzm - 2] = 0.0 if bilateral else (g1 if kk == 1 else -g2)  # the stop's position w*
    ye[nzm - 1] = 0.0
    sgn = -1.0 if kk == 1 else 1.0
    lk = sgn * _row(R, kk, R_MU, ye, nzm - 1)
    ld = sgn * _row(R, kk, R_MUD, ye, nzm - 1)
    eps = 1e-12 * _row_scale(R, kk, R_MU, ye, nzm - 1)
    stick = bilateral or lk > eps or (lk >= -eps and ld > 0.0)
    for _attempt in range(2):
        if stick:
            ok = False
            skip_on = False
            ts = 0.0
            if bilateral or lk > eps:
                ok = True
            else:
                _modal(Vi, kk, ye, nk[kk], nzm - 1, a)
                _coef(RV, kk, R_MU, a, nk[kk], sgn, cw)
                ts = rt.skip_start(cw, lam[kk], nk[kk], 0.0, h)
                if ts >= 0.0:
                    skip_on = True
                    ok = True
            if ok:
                for i in range(nzm):
                    y[i] = ye[i]
                return True, kk, skip_on, 0, ts
        else:
            full_state(kk, ye, Qout, N, x)
            for i in range(nx):
                x2[i] = x[i]
            x2[nx] = ye[nzm - 4]
            x2[nx + 1] = ye[nzm - 3]
            _modal(Vi, 0, x2, nk[0], nzm, a)
            _coef(RV, 0, R_W, a, nk[0], -1.0 if k == 1 else 1.0, cw)
            ts = rt.skip_start(cw, lam[0], nk[0], g1 if k == 1 else g2, h)
            if ts >= 0.0:
                for i in range(nzm):
                    y[i] = x2[i]
                return True, 0, True, k, ts
        stick = not stick
    return False, 0, False, 0, 0.0


@njit(cache=True, nogil=True)
def release(y, k, Qout, R, RV, Vi, lam, nk, N, g1, g2, h, x, a, cw):
    """Leave stuck regime k where the contact force reached zero: back to free flight, with the
    search for that stop starting once the gap has opened. Returns (pending, skip_on,
    skip_stop, skip_rem)."""
    nzm = 2 * N + 2
    nx = 2 * N
    full_state(k, y, Qout, N, x)
    osc_c = y[nzm - 4]
    osc_s = y[nzm - 3]
    for i in range(nx):
        y[i] = x[i]
    y[nx] = osc_c
    y[nx + 1] = osc_s
    _modal(Vi, 0, y, nk[0], nzm, a)
    _coef(RV, 0, R_W, a, nk[0], -1.0 if k == 1 else 1.0, cw)
    ts = rt.skip_start(cw, lam[0], nk[0], g1 if k == 1 else g2, h)
    if ts < 0.0:
        return k, False, 0, 0.0
    return 0, True, k, ts


# ----------------------------------------------------------------------------- the kernel


@njit(cache=True, nogil=True)
def _save_state(kst, r, skip_on, skip_stop, skip_rem, pending, contact):
    kst[K_REGIME] = r
    kst[K_SKIP_ON] = 1.0 if skip_on else 0.0
    kst[K_SKIP_STOP] = skip_stop
    kst[K_SKIP_REM] = skip_rem
    kst[K_PENDING] = pending
    kst[ms.K_CONTACT] = contact


@njit(**ms.KERNEL_JIT)
def event_kernel(y, x, kst, ring, n_periods, measure, checks, rows, samples, hist, xh, evlog,
                 nzr, nk, Phi, eh, lam, V, Vi, wt, R, RV, Pin, Qout, psi, gl, W, MinvX, G, g1,
                 g2, bilateral, N, n_grid, gamma_r, f_scale, margin, event_tol, max_events_pp,
                 lin_L, lin_xp, lin_amp, lin_gate, div_limit, tol, ye, a, c1, c2, cw, Ew,
                 x2, stack, w4):  # fmt: skip
    """Advance the regime state ``y`` (and its full state ``x``) by up to ``n_periods``
    periods; returns (periods done, END code, period found).

    The kernel's own state (regime, pending events, the late start of a search after a
    release, the contact episode) and the period's measurements live in local variables, stored
    to ``kst`` and ``rows`` only at period ends: stores inside the loop would make the compiler
    reload ``y`` and the matrices after each (measured: 2× slower free flight)."""
    nzm = 2 * N + 2
    nx = 2 * N
    T = 2.0 * math.pi / gamma_r
    h = T / n_grid
    tol_t = event_tol * T
    r = int(kst[K_REGIME])
    skip_on = kst[K_SKIP_ON] != 0.0
    skip_stop = int(kst[K_SKIP_STOP])
    skip_rem = kst[K_SKIP_REM]
    pending = int(kst[K_PENDING])
    contact = int(kst[ms.K_CONTACT])
    record = hist.shape[0] > 0
    for k in range(n_periods):
        ms.begin_row(rows, k)
        period = kst[ms.K_PERIOD]
        ev_period = 0
        failed = ms.END_NONE
        smin = np.inf
        smax = -np.inf
        h0 = h1 = h2 = h3 = vv = vb = 0.0
        nsteps = ncoarse = nimpacts = imp1 = imp2 = peak = 0.0
        last = -1.0
        for j in range(n_grid):
            t = 0.0
            ph0 = 2.0 * math.pi * j / n_grid
            while True:
                nz = nzr[r]
                nkr = nk[r]
                big = 0.0
                for i in range(nz):
                    if not math.isfinite(y[i]):
                        big = math.inf
                        break
                    big = max(big, abs(y[i]))
                if big > MAX_STATE:
                    failed = ms.END_DIVERGED if math.isfinite(big) else ms.END_NONFINITE
                    break
                tau_now = period * T + j * h + t
                imp_l = 0.0
                if pending > 0:
                    # impact at the current time (the tip did not leave a stop it was released
                    # from, or the run starts on a stop)
                    ev_period += 1
                    if ev_period > max_events_pp:
                        failed = ms.END_CHATTER
                        break
                    kk = pending
                    wu = _row(R, 0, R_W, y, nzm)
                    wd = _row(R, 0, R_WD, y, nzm)
                    gap = g1 - wu if kk == 1 else g2 + wu
                    resid = gap / max(g1 if kk == 1 else g2, 1e-300)
                    P = -wd / G
                    for i in range(N):
                        y[N + i] += MinvX[i] * P
                    imp_l = abs(P)
                    nimpacts += 1.0
                    if contact != kk:
                        if kk == 1:
                            imp1 += 1.0
                        else:
                            imp2 += 1.0
                        last = (j * h + t) / T
                    peak = max(peak, imp_l)
                    contact = kk
                    if record:
                        _log_event(evlog, kst, tau_now, 1.0, kk, resid, imp_l)
                    pending = -kk
                if pending < 0:
                    kk = -pending
                    pending = 0
                    ok, rn, so, ss, sr = stick_or_leave(y, kk, bilateral, Pin, Qout, R, RV, Vi,
                                                        lam, nk, N, g1, g2, h, ye, x, x2, a,
                                                        cw)  # fmt: skip
                    if ok:
                        r = rn
                        skip_on = so
                        if so and rn == 0:
                            skip_stop = ss
                        skip_rem = sr
                        if record:
                            _record(hist, xh, kst, tau_now, R, r, y, nzr[r],
                                    imp_l if kk == 1 else 0.0, imp_l if kk == 2 else 0.0, kk,
                                    Qout, N, x)  # fmt: skip
                    else:
                        pending = kk  # neither sticks nor leaves: impact again
                    continue
                ln = h - t
                if ln <= 1e-13 * h:
                    break
                # ---- the cheap test on a whole interval
                have_ye = False
                if t == 0.0 and not skip_on:
                    _matvec(Phi, r, y, nz, ye)
                    have_ye = True
                    if r == 0:
                        w0 = _row(R, 0, R_W, y, nz)
                        d0 = _row(R, 0, R_WD, y, nz)
                        w1 = _row(R, 0, R_W, ye, nz)
                        d1 = _row(R, 0, R_WD, ye, nz)
                        bnd = (
                            2.0
                            * h**4
                            / 384.0
                            * (abs(_row(R, 0, R_W4, y, nz)) + abs(_row(R, 0, R_W4, ye, nz)))
                        )
                        quick = ms.cubic_inside(w0, d0, w1, d1, h, -g2 * (1.0 - margin),
                                                g1 * (1.0 - margin), bnd)  # fmt: skip
                    elif bilateral:
                        quick = True
                    else:
                        sgn = -1.0 if r == 1 else 1.0
                        l0 = sgn * _row(R, r, R_MU, y, nz)
                        e0 = sgn * _row(R, r, R_MUD, y, nz)
                        l1 = sgn * _row(R, r, R_MU, ye, nz)
                        e1 = sgn * _row(R, r, R_MUD, ye, nz)
                        bnd = (
                            2.0
                            * h**4
                            / 384.0
                            * (abs(_row(R, r, R_MU4, y, nz)) + abs(_row(R, r, R_MU4, ye, nz)))
                        )
                        quick = ms.cubic_above(l0, e0, l1, e1, h, bnd, margin * max(l0, l1))
                    if quick:
                        if measure:
                            lo, hi, d0_, d1_, d2_, d3_, dv, db = _measure_interval(
                                r, y, ye, nz, R, psi, gl, h, ph0, Vi, RV, lam, nk, a, cw, tol_t
                            )
                            h0 += d0_
                            h1 += d1_
                            h2 += d2_
                            h3 += d3_
                            vv += dv
                            vb += db
                        else:
                            s0 = _row(R, r, R_S, y, nz)
                            s1 = _row(R, r, R_S, ye, nz)
                            lo = min(s0, s1)
                            hi = max(s0, s1)
                            sd0 = _row(R, r, R_SD, y, nz)
                            sd1 = _row(R, r, R_SD, ye, nz)
                            if sd0 * sd1 < 0.0:
                                lo, _, hi, _ = ms.cubic_minmax(s0, sd0, s1, sd1, h)
                        smax = max(smax, hi)
                        smin = min(smin, lo)
                        il = 0.0
                        if record and r != 0:
                            _modal(Vi, r, y, nkr, nz, a)
                            _coef(RV, r, R_MU, a, nkr, -1.0 if r == 1 else 1.0, cw)
                            for kq in range(nkr):
                                il += (cw[kq] * rt.phi1(lam[r, kq], h)).real
                        if r == 0 and contact != 0:
                            contact = _opened(contact, y, ye, h, R, RV, Vi, lam, nk, nz, g1, g2,
                                              a, False, cw)  # fmt: skip
                        for i in range(nz):
                            y[i] = ye[i]
                        nsteps += 1.0
                        ncoarse += 1.0
                        if record:
                            _record(hist, xh, kst, period * T + (j + 1) * h, R, r, y, nz,
                                    il if r == 1 else 0.0, il if r == 2 else 0.0, 0.0, Qout, N,
                                    x)  # fmt: skip
                        break
                # ---- exact search over [t, h] (ye = Φ y already if have_ye)
                if t == 0.0 and not have_ye:
                    _matvec(Phi, r, y, nz, ye)
                    have_ye = True
                _modal(Vi, r, y, nkr, nz, a)
                if have_ye:
                    for q in range(nkr):
                        Ew[q] = eh[r, q]
                else:
                    for q in range(nkr):
                        Ew[q] = rt.cexp(lam[r, q] * ln)
                t_ev = -1.0
                kind = 0
                if r == 0:
                    # the gaps are g1 - w and g2 + w: one set of sums of w proves both clear
                    _coef(RV, 0, R_W, a, nkr, 1.0, c2)
                    sums = rt.clear_sums(c2, lam[0], Ew, nkr, ln)
                    _coef(RV, 0, R_W, a, nkr, -1.0, c1)
                    for kk in range(1, 3):
                        gk = g1 if kk == 1 else g2
                        sg = -1.0 if kk == 1 else 1.0
                        cc = c1 if kk == 1 else c2
                        ts = 0.0
                        if skip_on and skip_stop == kk:
                            if skip_rem >= ln:
                                continue
                            ts = skip_rem
                        lim = ln if t_ev < 0.0 else t_ev
                        if ts >= lim:
                            continue
                        if ts == 0.0 and lim == ln:
                            if rt.clear_test(sums, gk, sg, ln):
                                continue
                            te = rt.first_root_whole(cc, lam[0], Ew, nkr, gk, ln, tol_t, stack,
                                                     w4)  # fmt: skip
                        elif lim == ln and not have_ye:  # Ew = cexp(λ ln): reuse it
                            te = rt.first_root_end(cc, lam[0], Ew, nkr, gk, ts, ln, tol_t, stack,
                                                   w4)  # fmt: skip
                        else:
                            te = rt.first_root(cc, lam[0], nkr, gk, ts, lim, tol_t, stack, w4)
                        if te >= 0.0 and (t_ev < 0.0 or te < t_ev):
                            t_ev = te
                            kind = kk
                elif not bilateral:
                    sgn = -1.0 if r == 1 else 1.0
                    _coef(RV, r, R_MU, a, nkr, sgn, c1)
                    ts = skip_rem if skip_on else 0.0
                    te = -1.0
                    if ts == 0.0:
                        if not rt.clear_whole(c1, lam[r], Ew, nkr, 0.0, ln):
                            te = rt.first_root_whole(c1, lam[r], Ew, nkr, 0.0, ln, tol_t, stack,
                                                     w4)  # fmt: skip
                    elif ts < ln and not have_ye:
                        te = rt.first_root_end(c1, lam[r], Ew, nkr, 0.0, ts, ln, tol_t, stack, w4)
                    elif ts < ln:
                        te = rt.first_root(c1, lam[r], nkr, 0.0, ts, ln, tol_t, stack, w4)
                    if te >= 0.0:
                        t_ev = te
                        kind = 2 + r  # release from stop r
                lp = t_ev if t_ev >= 0.0 else ln
                if t_ev >= 0.0:
                    for q in range(nkr):
                        Ew[q] = rt.cexp(lam[r, q] * lp)
                    _state_E(V, r, a, Ew, nkr, nz, ye)
                elif not have_ye:
                    _state_E(V, r, a, Ew, nkr, nz, ye)
                if measure and t == 0.0 and t_ev < 0.0:
                    # a whole interval after all: its precomputed rows measure it
                    lo, hi, d0_, d1_, d2_, d3_, dv, db = _measure_interval(
                        r, y, ye, nz, R, psi, gl, h, ph0, Vi, RV, lam, nk, a, cw, tol_t
                    )
                else:
                    lo, hi, d0_, d1_, d2_, d3_, dv, db = _measure_piece(
                        r, a, nkr, lam, RV, wt, Ew, lp, _row(R, r, R_S, y, nz),
                        _row(R, r, R_SD, y, nz), _row(R, r, R_S, ye, nz),
                        _row(R, r, R_SD, ye, nz), ph0 + gamma_r * t, gamma_r, measure, tol_t, cw,
                    )  # fmt: skip
                smax = max(smax, hi)
                smin = min(smin, lo)
                h0 += d0_
                h1 += d1_
                h2 += d2_
                h3 += d3_
                vv += dv
                vb += db
                il = 0.0
                if record and r != 0:
                    _coef(RV, r, R_MU, a, nkr, -1.0 if r == 1 else 1.0, cw)
                    for kq in range(nkr):
                        il += (cw[kq] * rt.phi1(lam[r, kq], lp)).real
                if r == 0 and contact != 0:
                    contact = _opened(contact, y, ye, lp, R, RV, Vi, lam, nk, nz, g1, g2, a,
                                      True, cw)  # fmt: skip
                if skip_on:
                    skip_rem -= lp
                    if skip_rem <= 0.0:
                        skip_on = False
                for i in range(nz):
                    y[i] = ye[i]
                nsteps += 1.0
                t = h if t_ev < 0.0 else t + lp
                tau_now = period * T + j * h + t
                if t_ev < 0.0:
                    if record:
                        _record(hist, xh, kst, tau_now, R, r, y, nz, il if r == 1 else 0.0,
                                il if r == 2 else 0.0, 0.0, Qout, N, x)  # fmt: skip
                    break
                if kind <= 2:
                    # impact on stop `kind` (applied at the top of the loop)
                    if record and lp > 0.0:
                        _record(hist, xh, kst, tau_now, R, r, y, nz, 0.0, 0.0, 0.0, Qout, N, x)
                    pending = kind
                    continue
                # release from stop r: the contact force reached zero
                ev_period += 1
                if ev_period > max_events_pp:
                    failed = ms.END_CHATTER
                    break
                if record:
                    sgn = -1.0 if r == 1 else 1.0
                    resid = sgn * _row(R, r, R_MU, y, nz) / max(_row_scale(R, r, R_MU, y, nz),
                                                                 1e-300)  # fmt: skip
                    _log_event(evlog, kst, tau_now, 2.0, r, resid, 0.0)
                rk = r
                pending, skip_on, ss, skip_rem = release(y, rk, Qout, R, RV, Vi, lam, nk, N, g1,
                                                         g2, h, x, a, cw)  # fmt: skip
                if skip_on:
                    skip_stop = ss
                r = 0
                if record:
                    _record(hist, xh, kst, tau_now, R, 0, y, nzm, il if rk == 1 else 0.0,
                            il if rk == 2 else 0.0, 2.0 + rk, Qout, N, x)  # fmt: skip
            if failed != ms.END_NONE:
                break
            # exact forcing phase at the grid point (no drift of the oscillator)
            ang = 2.0 * math.pi * (j + 1) / n_grid
            ic = 2 * N if r == 0 else 2 * N - 2
            y[ic] = f_scale * math.cos(ang)
            y[ic + 1] = f_scale * math.sin(ang)
        rows[k, ms.M_SMIN] = smin
        rows[k, ms.M_SMAX] = smax
        rows[k, ms.M_S_RE] = h0
        rows[k, ms.M_S_IM] = h1
        rows[k, ms.M_SB_RE] = h2
        rows[k, ms.M_SB_IM] = h3
        rows[k, ms.M_VV] = vv
        rows[k, ms.M_VB] = vb
        rows[k, ms.M_IMP1] = imp1
        rows[k, ms.M_IMP2] = imp2
        rows[k, ms.M_PEAK] = peak
        rows[k, ms.M_LAST_IMPACT] = last
        rows[k, ms.M_STEPS] = nsteps
        rows[k, ms.M_COARSE] = ncoarse
        rows[k, ms.M_CONTACT] = nimpacts
        rows[k, ms.M_REGIME] = r
        _save_state(kst, r, skip_on, skip_stop, skip_rem, pending, contact)
        kst[ms.K_PERIOD] += 1.0
        if failed != ms.END_NONE:
            return k + 1, failed, 0
        full_state(r, y, Qout, N, x)
        code, p = ms.period_end(x, nx, rows, samples, k, ring, kst, lin_L, lin_xp, lin_amp,
                                lin_gate, checks, div_limit, tol)  # fmt: skip
        if code != ms.END_NONE:
            return k + 1, code, p
    return n_periods, ms.END_NONE, 0


@njit(cache=True, nogil=True)
def start_state(y, kst, R, RV, Vi, lam, nk, bilateral, N, g1, g2, h, a, cw):
    """Regime and pending events for a free state y at τ = 0 (a reset): a gap closed at the
    start is an impact there (or a departure, if the tip moves away)."""
    nzm = 2 * N + 2
    kst[K_REGIME] = 0.0
    kst[K_SKIP_ON] = 0.0
    kst[K_PENDING] = 0.0
    if bilateral:
        kst[K_PENDING] = 1.0
        return
    wu = _row(R, 0, R_W, y, nzm)
    wd = _row(R, 0, R_WD, y, nzm)
    stop = 0
    if g1 - wu <= 1e-12 * max(g1, 1e-300):
        if wd >= 0.0:
            kst[K_PENDING] = 1.0
        else:
            stop = 1
    elif g2 + wu <= 1e-12 * max(g2, 1e-300):
        if wd <= 0.0:
            kst[K_PENDING] = 2.0
        else:
            stop = 2
    if stop:  # leaving a stop at τ = 0: search it once the gap has opened
        _modal(Vi, 0, y, nk[0], nzm, a)
        _coef(RV, 0, R_W, a, nk[0], -1.0 if stop == 1 else 1.0, cw)
        ts = rt.skip_start(cw, lam[0], nk[0], g1 if stop == 1 else g2, h)
        if ts < 0.0:
            kst[K_PENDING] = stop
        else:
            kst[K_SKIP_ON] = 1.0
            kst[K_SKIP_STOP] = stop
            kst[K_SKIP_REM] = ts
