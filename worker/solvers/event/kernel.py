"""The event-driven kernel: whole periods of exact regime propagation between located events.

Inside a regime (``regimes.py``) the state is carried as its modal coefficients ``α`` (reduced
form): a sub-grid interval ``h = T/n_grid`` is ``α ∘ e^{λh}`` and every observable is
``Re Σ RV_k α_k``. Per interval of the current regime:

* a cheap, rigorous test first: the cubic Hermite interpolant of the tip (free flight) or of
  the contact force (stuck) from both ends, widened by the bound ``h⁴/384 Σ|RV_k||λ_k|⁴|α_k|``
  of its interpolation error (and by round-off), must stay inside the stops (above zero force);
  the interval is then taken whole;
* otherwise an exact search of the gap or contact force (``roots.first_root``) over the rest
  of the interval; the piece up to the first event is propagated exactly and the event is
  applied: at an impact the plastic impulse ``P = -Wᵀq/G`` along ``M⁻¹X`` zeroes the tip's
  velocity (``α += V⁻¹[0; M⁻¹X; 0]·P``) and the tip sticks if the stuck regime's contact force
  is compressive (or zero and increasing), else it leaves at once; a stuck tip is released
  where the force reaches zero. After leaving a stop the search for it starts once the gap has
  opened above round-off (``roots.skip_start``), so a release is never taken for a new impact;
* a per-period event budget ends a run that chatters.

The forcing oscillator's coefficient is set from the exact phase at every sub-grid point (no
drift). The regime state ``y`` itself is formed only where it is needed: at events that change
regime, at period ends (the stroboscopic sample) and for histories.

Each period fills one row of the measurement layout (``measure.py``). The extrema of ``s`` are
located exactly (Newton on ``ṡ = 0``) when measuring, else taken from the Hermite
interpolant. The first harmonics and the phase-portrait integrals are exact integrals over
each measured segment (a stretch of one regime between events or period ends), the difference
of their primitives at its ends (``primitives.py``): nothing is computed per sub-grid interval.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.solvers import measure as ms
from worker.solvers.event import primitives as pm
from worker.solvers.event import roots as rt
from worker.solvers.event.regimes import R_MU, R_MUD, R_S, R_SB, R_SBD, R_SD, R_W, R_WD

# A state beyond this size ends the run (diverged): the search's error bounds (|c|·|λ|⁴·h⁴)
# overflow well before the state does, and a search on non-finite values never proves an
# interval clear (it would split ~4¹⁵ times per interval, i.e. hang).
MAX_STATE = 1e200

# A modal coefficient below this is zero (far below the round-off of any state it is part of).
TINY = 1e-200

# Round-off allowance of the cheap test, relative to the size of the sums it evaluates.
PAD = 1e-12

FAST = pm.FAST

# kernel state entries (after the common ones of measure.py)
K_REGIME = ms.K_METHOD  # 0 free, 1/2 stuck on stop 1/2
K_SKIP_ON = ms.K_METHOD + 1  # the search of the current constraint starts late
K_SKIP_STOP = ms.K_METHOD + 2
K_SKIP_REM = ms.K_METHOD + 3
K_PENDING = ms.K_METHOD + 4  # >0: impact at once at this stop; <0: stick-or-leave after one
K_EVLOG = ms.K_METHOD + 5  # event log rows written
K_SYNC = ms.K_METHOD + 6  # 1: the modal coefficients (al) are the state y's, carried over
# the rebound sequence in progress (restitution): its stop (0 none), the time of its last
# rebound from the current period's start, that impact's approach velocity, rebounds in it
K_REB_STOP = ms.K_METHOD + 7
K_REB_T = ms.K_METHOD + 8
K_REB_V = ms.K_METHOD + 9
K_REB_RUN = ms.K_METHOD + 10

# A rebound sequence is passed to its limit once the time left to its accumulation point is
# below this fraction of the period: from there on the limit state (the tip at rest on the
# stop, the stuck regime) is exact up to the change of the tip's acceleration over that time,
# far below the event tolerance's effect on the state (docs/solvers.md, "Restitution").
ACC_TIME = 1e-7
# Two consecutive rebounds belong to one geometric sequence (constant acceleration towards the
# stop) when the second approach velocity is e times the first to within this.
GEOMETRIC = 1e-2
# Rebounds of a converging geometric sequence are not charged to the event budget (it needs
# log(ACC_TIME)/log(e) of them, ~1,400 at e = 0.99) up to this many in one sequence.
MAX_SEQUENCE = 100_000

#: Columns of the event log (``history["events"]`` of method ``event``), described.
EVENT_FIELDS = {
    "tau": "non-dimensional time tau of the event",
    "kind": "event kind: 1 impact, 2 release, 3 the accumulation point of a rebound sequence",
    "stop": "stop index (1 or 2)",
    "residual": "residual of the event condition at the located time (gap over clearance at "
    "an impact, contact force over its scale at a release; at an accumulation point the time "
    "from the sequence's last impact to it, over the period)",
    "impulse": "contact impulse of the event (at an accumulation point the sequence's "
    "remaining impulses summed)",
}
EV_COLS = len(EVENT_FIELDS)

# ----------------------------------------------------------------------------- state helpers


@njit(cache=True, nogil=True, inline="always")
def _re_mul(v, a):
    """Re(v·a) without forming the product's imaginary part: the one term of every
    observable ``Re Σ v_k a_k`` of modal coefficients."""
    return v.real * a.real - v.imag * a.imag


@njit(cache=True, nogil=True, fastmath=FAST)
def _modal(Vi, r, y, nk, nz, a):
    """a = V⁻¹ y (the kept rows): a regime state's modal coefficients."""
    for i in range(nk):
        acc = 0.0 + 0.0j
        for j in range(nz):
            acc += Vi[r, i, j] * y[j]
        a[i] = acc


@njit(cache=True, nogil=True, fastmath=FAST)
def _state(V, r, a, nk, nz, out):
    """out = Re V a: the regime state of modal coefficients a."""
    for i in range(nz):
        acc = 0.0
        for k in range(nk):
            acc += _re_mul(V[r, i, k], a[k])
        out[i] = acc


@njit(cache=True, nogil=True, fastmath=FAST)
def _rowa(RV, r, row, a, nk):
    """Re Σ RV_k a_k: an observable of modal coefficients a."""
    acc = 0.0
    for k in range(nk):
        acc += _re_mul(RV[r, row, k], a[k])
    return acc


@njit(cache=True, nogil=True, fastmath=FAST)
def _step(a, E, nk, out):
    """out = a ∘ E, coefficients below ``TINY`` set to zero: a decaying mode's coefficient would
    otherwise shrink through the subnormal numbers, where every operation on it is some
    hundred times slower (measured: 5× slower free flight once the beam's middle modes
    had decayed)."""
    for k in range(nk):
        z = a[k] * E[k]
        if abs(z.real) + abs(z.imag) < TINY:
            z = 0.0 + 0.0j
        out[k] = z


@njit(cache=True, nogil=True, fastmath=FAST)
def _ends(RV, B4, lam, eh, r, row, al, ae, nk):
    """One pass over the modes for a whole sub-grid interval of regime r: ``ae = al ∘ e^{λh}``
    (as :func:`_step`), the observable ``row`` and its slope (``row + 1``), s and ṡ at the
    interval's end, the fourth derivative's bound and the size of the sum from ``al``
    (``Σ|RV_k||λ_k|⁴|a_k|``, ``Σ|RV_k||a_k|``, growing modes at the end) and
    :func:`_magnitude` of ``ae``, in one pass over the coefficients."""
    big = 0.0
    f1 = 0.0
    fd1 = 0.0
    s1 = 0.0
    sd1 = 0.0
    b = 0.0
    sc = 0.0
    for k in range(nk):
        a = al[k]
        e = eh[r, k]
        z = a * e
        mz = abs(z.real) + abs(z.imag)
        if mz < TINY:
            z = 0.0 + 0.0j
            mz = 0.0
        if mz > big:
            big = mz
        elif mz != mz:  # NaN: not finite (inf is caught by the comparison)
            big = math.inf
        ae[k] = z
        v = RV[r, row, k]
        f1 += _re_mul(v, z)
        fd1 += _re_mul(RV[r, row + 1, k], z)
        s1 += _re_mul(RV[r, R_S, k], z)
        sd1 += _re_mul(RV[r, R_SD, k], z)
        m = abs(a.real) + abs(a.imag)
        if lam[r, k].real > 0.0:
            m *= abs(e.real) + abs(e.imag)
        b += B4[r, k] * m
        sc += (abs(v.real) + abs(v.imag)) * m
    return f1, fd1, s1, sd1, b, sc, big


@njit(cache=True, nogil=True)
def _coef(RV, r, row, a, nk, sgn, c):
    for k in range(nk):
        c[k] = sgn * RV[r, row, k] * a[k]


@njit(cache=True, nogil=True)
def _impulse(RV, r, a, nk, lam, ln, cw):
    """The contact impulse ∫ μ dt over a piece of length ln of stuck regime r (modal
    coefficients a at its start), for histories."""
    _coef(RV, r, R_MU, a, nk, -1.0 if r == 1 else 1.0, cw)
    il = 0.0
    for k in range(nk):
        il += (cw[k] * rt.phi1(lam[r, k], ln)).real
    return il


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


@njit(cache=True, nogil=True)
def _magnitude(a, nk):
    """max |Re a_k| + |Im a_k|, or inf if some coefficient is not finite."""
    big = 0.0
    for k in range(nk):
        m = abs(a[k].real) + abs(a[k].imag)
        if not math.isfinite(m):
            return math.inf
        big = max(big, m)
    return big


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
def _extremum(r, a, nk, lam, RV, ln, sd0, sd1, tol_t, cw):
    """s at the exact root of ṡ inside a piece where ṡ changes sign."""
    sgn = 1.0 if sd0 > 0.0 else -1.0
    _coef(RV, r, R_SD, a, nk, sgn, cw)
    tc = rt.refine(cw, lam[r], nk, 0.0, 0.0, ln, abs(sd0), -abs(sd1), 1e-3 * tol_t)
    _coef(RV, r, R_S, a, nk, 1.0, cw)
    sc, _ = rt.ev(cw, lam[r], nk, 0.0, tc)
    return sc


@njit(cache=True, nogil=True)
def _s_range(r, a, nk, lam, RV, ln, s0, sd0, s1, sd1, measure, tol_t, cw):
    """The range of s over a piece: exact (Newton on ṡ = 0) when measuring, else that of the
    Hermite interpolant."""
    lo = min(s0, s1)
    hi = max(s0, s1)
    if ln > 0.0 and sd0 * sd1 < 0.0:
        if measure:
            sc = _extremum(r, a, nk, lam, RV, ln, sd0, sd1, tol_t, cw)
            lo = min(lo, sc)
            hi = max(hi, sc)
        else:
            lo, _, hi, _ = ms.cubic_minmax(s0, sd0, s1, sd1, ln)
    return lo, hi


@njit(cache=True, nogil=True)
def _rot(j, t, n_grid, gamma_r, cosg, sing):
    """e^{-iθ} = (rc, rs) at sub-grid point j plus t (θ = γ(τ - τ_k), the forcing phase in the
    period): the table's exact value at a sub-grid point."""
    if t == 0.0:
        return cosg[j], -sing[j]
    th = 2.0 * math.pi * j / n_grid + gamma_r * t
    return math.cos(th), -math.sin(th)


@njit(cache=True, nogil=True)
def _seg_open(r, al, a0, nk, H, C, rc, rs, h0, h1, h2, h3, vv, vb):
    """Open a measured segment of regime r at the current coefficients al (forcing phase
    rc + i rs): the primitive there is subtracted from the period's sums (``primitives.py``)
    and al kept as the segment's start. Returns the sums."""
    d0, d1, d2, d3, dv, db = pm.primitive(r, al, nk, H, C, rc, rs)
    for q in range(nk):
        a0[q] = al[q]
    return h0 - d0, h1 - d1, h2 - d2, h3 - d3, vv - dv, vb - db


@njit(cache=True, nogil=True)
def _seg_close(r, al, a0, nk, H, C, dint, dcm, nd, ln, rc0, rs0, rc, rs, h0, h1, h2, h3, vv,
               vb):  # fmt: skip
    """Close the measured segment of length ln (it started at a0, forcing phase rc0 + i rs0)
    at the current coefficients al (rc + i rs): the primitive there and the directly
    integrated terms are added to the period's sums. Returns the sums."""
    d0, d1, d2, d3, dv, db = pm.primitive(r, al, nk, H, C, rc, rs)
    e0, e1, e2, e3, ev, eb = pm.direct(r, a0, ln, rc0, rs0, dint, dcm, nd)
    return (h0 + d0 + e0, h1 + d1 + e1, h2 + d2 + e2, h3 + d3 + e3, vv + dv + ev,
            vb + db + eb)  # fmt: skip


@njit(cache=True, nogil=True)
def _opened(contact, a, ln, RV, lam, nk0, g1, g2, w0, d0, w1, d1, cw):
    """The contact episode state after a free piece (modal coefficients a at its start, the tip
    and its velocity at both ends): it ends once the gap of its stop has opened to
    ``OPEN_FRAC`` of the clearance (exact maximum of the gap over the piece).

    The exact maximum (Newton on the gap's slope, which near the round-off floor falls back to
    tens of bisections) is sought only where the ends and the gap's Hermite cubic leave it in
    doubt: not where the gap falls, then rises (its maximum is at an end), nor where the cubic
    plus its error bound stays below the threshold, nor where the gap at the cubic's maximum is
    above it."""
    sgn = -1.0 if contact == 1 else 1.0
    gk = g1 if contact == 1 else g2
    thr = ms.OPEN_FRAC * gk
    f0 = gk + sgn * w0
    e0 = sgn * d0
    f1 = gk + sgn * w1
    e1 = sgn * d1
    if f0 > thr or f1 > thr:
        return 0
    _, _, fmax, tmax = ms.cubic_minmax(f0, e0, f1, e1, ln)
    if fmax <= 0.5 * thr:
        return contact
    if e0 < 0.0 <= e1:
        # falling, then rising: the maximum is at an end, and neither is above the threshold
        # (the slope's root in between is a minimum, which the search below would locate)
        return contact
    _coef(RV, 0, R_W, a, nk0, sgn, cw)
    scale = gk
    bnd = 0.0
    for k in range(nk0):
        lk = lam[0, k]
        m2 = lk.real * lk.real + lk.imag * lk.imag
        ak = rt.cabs(cw[k])
        scale += ak
        bnd += ak * m2 * m2 * (1.0 if lk.real <= 0.0 else math.exp(lk.real * ln))
    if fmax + bnd * ln * ln * ln * ln / 384.0 + 1e-12 * scale < thr:
        return contact  # the gap stays below the threshold over the whole piece
    fm, _ = rt.ev(cw, lam[0], nk0, gk, tmax)
    if fm > thr + 1e-12 * scale:
        return 0  # above it at one point: the maximum is too
    tc = rt.crit(cw, lam[0], nk0, 0.0, ln, e0, e1, tmax)
    fc, _ = rt.ev(cw, lam[0], nk0, gk, tc)
    return 0 if fc > thr else contact


# ----------------------------------------------------------------------------- events


@njit(cache=True, nogil=True)
def time_to_accumulation(v_prev, v, flight, e):
    """The time from an impact to the accumulation point of its rebound sequence, or -1 if
    the impacts are not one converging geometric sequence.

    ``v_prev`` and ``v`` are the approach velocities (towards the stop) of two consecutive
    impacts at one stop, ``flight`` the time between them, ``e`` the stop's restitution. Under
    a constant acceleration ``a`` towards the stop a tip leaving at ``e v_prev`` returns at
    ``v = e v_prev`` after ``2 e v_prev / a``; so ``a = (v + e v_prev)/flight``, and the
    flights after the impact at ``v`` sum to ``2 e v / (a (1 - e))`` (``docs/solvers.md``)."""
    if not (0.0 < e < 1.0) or v_prev <= 0.0 or v <= 0.0 or flight <= 0.0:
        return -1.0
    if abs(v - e * v_prev) > GEOMETRIC * e * v_prev:
        return -1.0
    a = (v + e * v_prev) / flight
    return 2.0 * e * v / (a * (1.0 - e))


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
                ts = rt.skip_start(cw, lam[kk], nk[kk], 0.0, h, False)
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
            ts = rt.skip_start(cw, lam[0], nk[0], g1 if k == 1 else g2, h, True)
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
    ts = rt.skip_start(cw, lam[0], nk[0], g1 if k == 1 else g2, h, True)
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
                 nzr, nk, eh, SP, lam, V, Vi, R, RV, B4, Pin, Qout, H, C, dint, dcm, nd, D, fidx,
                 fcs, cosg, sing, MinvX, G, g1, g2, bilateral, N, n_grid, gamma_r, f_scale,
                 event_tol, max_events_pp, e1, e2, lin_L, lin_xp, lin_amp, lin_gate, div_limit,
                 tol, ye, al, ae, c1, c2, cw, Ew, x2, stack, w4, a0):  # fmt: skip
    """Advance the regime state ``y`` (and its full state ``x``) by up to ``n_periods``
    periods; returns (periods done, END code, period found).

    The kernel's own state (regime, pending events, the late start of a search after a
    release, the contact episode) and the period's measurements live in local variables, stored
    to ``kst`` and ``rows`` only at period ends: stores inside the loop would make the compiler
    reload the state and the matrices after each (measured: 2× slower free flight). Inside,
    the regime state is its modal coefficients ``al``; ``y`` is formed where it is needed."""
    nzm = 2 * N + 2
    nx = 2 * N
    T = 2.0 * math.pi / gamma_r
    h = T / n_grid
    h4 = h * h * h * h / 384.0
    tol_t = event_tol * T
    r = int(kst[K_REGIME])
    skip_on = kst[K_SKIP_ON] != 0.0
    skip_stop = int(kst[K_SKIP_STOP])
    skip_rem = kst[K_SKIP_REM]
    pending = int(kst[K_PENDING])
    contact = int(kst[ms.K_CONTACT])
    reb_stop = int(kst[K_REB_STOP])
    reb_t = kst[K_REB_T]
    reb_v = kst[K_REB_V]
    reb_run = kst[K_REB_RUN]
    record = hist.shape[0] > 0
    # events are logged wherever a log is given: with a history, or alone for the exact
    # monodromy matrix (monodromy.py)
    logev = evlog.shape[0] > 0
    if kst[K_SYNC] == 0.0:  # a new state: y → al (else al is carried over, to the bit)
        _modal(Vi, r, y, nk[r], nzr[r], al)
        kst[K_SYNC] = 1.0
    # the rows at the current coefficients, kept from the end of the last interval taken
    # whole: the gap's (free) or the contact force's (stuck) value and slope, s and ṡ
    have = False
    f0 = fd0 = s0 = sd0 = 0.0
    for k in range(n_periods):
        ms.begin_row(rows, k)
        period = kst[ms.K_PERIOD]
        ev_period = 0
        failed = ms.END_NONE
        smin = np.inf
        smax = -np.inf
        h0 = h1 = h2 = h3 = vv = vb = 0.0
        # the measured segment: open (seg) since position pos0 with forcing phase (rc0, rs0)
        seg = False
        pos0 = rc0 = rs0 = 0.0
        nsteps = ncoarse = nimpacts = imp1 = imp2 = peak = 0.0
        ct1 = ct2 = vimp1 = vimp2 = 0.0  # time stuck on each stop, approach velocities
        en1 = en2 = 0.0  # energy the impacts took at each stop
        last = -1.0
        known = -1.0  # _magnitude(al) where already known (the forcing phase is reset below)
        for j in range(n_grid):
            t = 0.0
            while True:
                nz = nzr[r]
                nkr = nk[r]
                if known >= 0.0:  # al's magnitude, from the interval that produced it
                    big = known
                    known = -1.0
                else:
                    big = _magnitude(al, nkr)
                if big > MAX_STATE:
                    failed = ms.END_DIVERGED if math.isfinite(big) else ms.END_NONFINITE
                    break
                tau_now = period * T + j * h + t
                imp_l = 0.0
                if pending > 0:
                    # impact at the current time (the tip did not leave a stop it was released
                    # from, or the run starts on a stop); the free regime
                    if seg:
                        rc, rs = _rot(j, t, n_grid, gamma_r, cosg, sing)
                        h0, h1, h2, h3, vv, vb = _seg_close(r, al, a0, nkr, H, C, dint, dcm, nd,
                                                            j * h + t - pos0, rc0, rs0, rc, rs,
                                                            h0, h1, h2, h3, vv, vb)  # fmt: skip
                        seg = False
                    kk = pending
                    wu = _rowa(RV, 0, R_W, al, nkr)
                    wd = _rowa(RV, 0, R_WD, al, nkr)
                    # Newton's law: a tip approaching a stop of restitution e > 0 rebounds,
                    # unless its rebounds accumulate (then the limit: at rest on the stop)
                    ek = e1 if kk == 1 else e2
                    vin = wd if kk == 1 else -wd
                    rebound = ek > 0.0 and vin > 0.0 and not bilateral
                    left = -1.0  # time left to the accumulation point
                    ts = 0.0
                    if rebound and reb_stop == kk:
                        left = time_to_accumulation(reb_v, vin, j * h + t - reb_t, ek)
                        reb_run = reb_run + 1.0 if left >= 0.0 else 0.0
                        if left >= 0.0 and left <= ACC_TIME * T:
                            rebound = False
                    if left < 0.0 or reb_run > MAX_SEQUENCE:
                        ev_period += 1
                        if ev_period > max_events_pp:
                            failed = ms.END_CHATTER
                            break
                    gap = g1 - wu if kk == 1 else g2 + wu
                    resid = gap / max(g1 if kk == 1 else g2, 1e-300)
                    P = -wd / G
                    if rebound:
                        P *= 1.0 + ek
                    for q in range(nkr):
                        al[q] += D[q] * P
                    have = False
                    if rebound:
                        # it leaves once the gap has opened above round-off; a rebound too
                        # small for that has accumulated (the plastic impulse instead)
                        _coef(RV, 0, R_W, al, nkr, -1.0 if kk == 1 else 1.0, cw)
                        ts = rt.skip_start(cw, lam[0], nkr, g1 if kk == 1 else g2, h, True)
                        if ts < 0.0:
                            rebound = False
                            for q in range(nkr):
                                al[q] -= D[q] * (P * ek / (1.0 + ek))
                            P = -wd / G
                    imp_l = abs(P)
                    nimpacts += 1.0
                    # the energy the impulse takes: ½(v⁻² − v⁺²)/G, v⁺ = −e v⁻ at a rebound
                    taken = 0.5 * wd * wd / G
                    if rebound:
                        taken *= 1.0 - ek * ek
                    if kk == 1:
                        en1 += taken
                    else:
                        en2 += taken
                    if contact != kk:
                        if kk == 1:
                            imp1 += 1.0
                            vimp1 += wd
                        else:
                            imp2 += 1.0
                            vimp2 -= wd
                        last = (j * h + t) / T
                    peak = max(peak, imp_l)
                    contact = kk
                    if logev:
                        _log_event(evlog, kst, tau_now, 1.0, kk, resid, imp_l)
                    if rebound:
                        pending = 0
                        skip_on = True
                        skip_stop = kk
                        skip_rem = ts
                        if reb_stop != kk:
                            reb_run = 0.0
                        reb_stop = kk
                        reb_t = j * h + t
                        reb_v = vin
                        if record:
                            _state(V, 0, al, nkr, nz, y)
                            _record(hist, xh, kst, tau_now, R, 0, y, nz,
                                    imp_l if kk == 1 else 0.0, imp_l if kk == 2 else 0.0, kk,
                                    Qout, N, x)  # fmt: skip
                        continue
                    if left >= 0.0 and logev:
                        # the sequence's limit: the remaining impulses (1 + e)/(1 - e)·e v/G
                        # summed, at the accumulation point
                        _log_event(evlog, kst, tau_now + left, 3.0, kk, left / T,
                                   2.0 * ek * vin / ((1.0 - ek) * G))  # fmt: skip
                    reb_stop = 0
                    reb_run = 0.0
                    pending = -kk
                if pending < 0:
                    kk = -pending
                    pending = 0
                    _state(V, 0, al, nkr, nz, y)
                    ok, rn, so, ss, sr = stick_or_leave(y, kk, bilateral, Pin, Qout, R, RV, Vi,
                                                        lam, nk, N, g1, g2, h, ye, x, x2, ae,
                                                        cw)  # fmt: skip
                    if ok:
                        r = rn
                        skip_on = so
                        if so and rn == 0:
                            skip_stop = ss
                        skip_rem = sr
                        _modal(Vi, r, y, nk[r], nzr[r], al)
                        have = False
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
                if t == 0.0 and not skip_on:
                    row = R_W if r == 0 else R_MU
                    if not have:
                        f0 = _rowa(RV, r, row, al, nkr)
                        fd0 = _rowa(RV, r, row + 1, al, nkr)
                        s0 = _rowa(RV, r, R_S, al, nkr)
                        sd0 = _rowa(RV, r, R_SD, al, nkr)
                        have = True
                    f1, fd1, s1, sd1, b4, sc, big_e = _ends(RV, B4, lam, eh, r, row, al, ae, nkr)
                    if r == 0:
                        quick = ms.cubic_inside(f0, fd0, f1, fd1, h, -g2, g1, b4 * h4 + PAD * sc)
                    elif bilateral:
                        quick = True
                    else:
                        sgn = -1.0 if r == 1 else 1.0
                        quick = ms.cubic_above(sgn * f0, sgn * fd0, sgn * f1, sgn * fd1, h,
                                               b4 * h4, PAD * sc)  # fmt: skip
                    if quick:
                        lo, hi = _s_range(r, al, nkr, lam, RV, h, s0, sd0, s1, sd1, measure,
                                          tol_t, cw)  # fmt: skip
                        smax = max(smax, hi)
                        smin = min(smin, lo)
                        if measure and not seg:
                            seg = True
                            pos0 = j * h
                            rc0 = cosg[j]
                            rs0 = -sing[j]
                            h0, h1, h2, h3, vv, vb = _seg_open(r, al, a0, nkr, H, C, rc0, rs0, h0,
                                                               h1, h2, h3, vv, vb)  # fmt: skip
                        il = _impulse(RV, r, al, nkr, lam, h, cw) if record and r != 0 else 0.0
                        if r == 1:
                            ct1 += h
                        elif r == 2:
                            ct2 += h
                        if r == 0 and contact != 0:
                            contact = _opened(contact, al, h, RV, lam, nkr, g1, g2, f0, fd0, f1,
                                              fd1, cw)  # fmt: skip
                        for q in range(nkr):
                            al[q] = ae[q]
                        known = big_e
                        f0 = f1
                        fd0 = fd1
                        s0 = s1
                        sd0 = sd1
                        have = not bilateral or r == 0
                        nsteps += 1.0
                        ncoarse += 1.0
                        if record:
                            _state(V, r, al, nkr, nz, y)
                            _record(hist, xh, kst, period * T + (j + 1) * h, R, r, y, nz,
                                    il if r == 1 else 0.0, il if r == 2 else 0.0, 0.0, Qout, N,
                                    x)  # fmt: skip
                        break
                # ---- exact search over [t, h]
                if t == 0.0:
                    for q in range(nkr):
                        Ew[q] = eh[r, q]
                else:
                    for q in range(nkr):
                        Ew[q] = rt.cexp(lam[r, q] * ln)
                t_ev = -1.0
                kind = 0
                if r == 0:
                    # the gaps are g1 - w and g2 + w: one set of sums of w proves both clear
                    _coef(RV, 0, R_W, al, nkr, 1.0, c2)
                    sums = rt.clear_sums(c2, lam[0], Ew, nkr, ln)
                    _coef(RV, 0, R_W, al, nkr, -1.0, c1)
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
                            # A whole interval: its split points' exponentials are in the
                            # table. Two calls, not one with ``SP[0] if t == 0.0 else None``:
                            # that Optional made every period of the kernel ~25 % slower,
                            # free flight too (interleaved, fastest of 20).
                            if t == 0.0:
                                te = rt.first_root_whole(cc, lam[0], Ew, nkr, gk, ln, tol_t,
                                                         stack, w4, SP[0])  # fmt: skip
                            else:
                                te = rt.first_root_whole(cc, lam[0], Ew, nkr, gk, ln, tol_t,
                                                         stack, w4)  # fmt: skip
                        elif lim == ln:  # Ew = e^{λ ln}: the end costs no exponentials
                            te = rt.first_root_end(cc, lam[0], Ew, nkr, gk, ts, ln, tol_t, stack,
                                                   w4)  # fmt: skip
                        else:
                            te = rt.first_root(cc, lam[0], nkr, gk, ts, lim, tol_t, stack, w4)
                        if te >= 0.0 and (t_ev < 0.0 or te < t_ev):
                            t_ev = te
                            kind = kk
                elif not bilateral:
                    sgn = -1.0 if r == 1 else 1.0
                    _coef(RV, r, R_MU, al, nkr, sgn, c1)
                    ts = skip_rem if skip_on else 0.0
                    te = -1.0
                    if ts == 0.0:
                        if not rt.clear_whole(c1, lam[r], Ew, nkr, 0.0, ln):
                            if t == 0.0:
                                te = rt.first_root_whole(c1, lam[r], Ew, nkr, 0.0, ln, tol_t,
                                                         stack, w4, SP[r])  # fmt: skip
                            else:
                                te = rt.first_root_whole(c1, lam[r], Ew, nkr, 0.0, ln, tol_t,
                                                         stack, w4)  # fmt: skip
                    elif ts < ln:
                        te = rt.first_root_end(c1, lam[r], Ew, nkr, 0.0, ts, ln, tol_t, stack, w4)
                    if te >= 0.0:
                        t_ev = te
                        kind = 2 + r  # release from stop r
                lp = t_ev if t_ev >= 0.0 else ln
                if t_ev >= 0.0:
                    for q in range(nkr):
                        Ew[q] = rt.cexp(lam[r, q] * lp)
                if measure and not seg:
                    seg = True
                    pos0 = j * h + t
                    rc0, rs0 = _rot(j, t, n_grid, gamma_r, cosg, sing)
                    h0, h1, h2, h3, vv, vb = _seg_open(r, al, a0, nkr, H, C, rc0, rs0, h0, h1, h2,
                                                       h3, vv, vb)  # fmt: skip
                _step(al, Ew, nkr, ae)
                if not have:
                    s0 = _rowa(RV, r, R_S, al, nkr)
                    sd0 = _rowa(RV, r, R_SD, al, nkr)
                s1 = _rowa(RV, r, R_S, ae, nkr)
                sd1 = _rowa(RV, r, R_SD, ae, nkr)
                lo, hi = _s_range(r, al, nkr, lam, RV, lp, s0, sd0, s1, sd1, measure, tol_t, cw)
                smax = max(smax, hi)
                smin = min(smin, lo)
                il = _impulse(RV, r, al, nkr, lam, lp, cw) if record and r != 0 else 0.0
                if r == 1:
                    ct1 += lp
                elif r == 2:
                    ct2 += lp
                if r == 0 and contact != 0:
                    contact = _opened(contact, al, lp, RV, lam, nkr, g1, g2,
                                      _rowa(RV, 0, R_W, al, nkr), _rowa(RV, 0, R_WD, al, nkr),
                                      _rowa(RV, 0, R_W, ae, nkr), _rowa(RV, 0, R_WD, ae, nkr),
                                      cw)  # fmt: skip
                if skip_on:
                    skip_rem -= lp
                    if skip_rem <= 0.0:
                        skip_on = False
                for q in range(nkr):
                    al[q] = ae[q]
                have = False
                nsteps += 1.0
                t = h if t_ev < 0.0 else t + lp
                tau_now = period * T + j * h + t
                if t_ev < 0.0:
                    if record:
                        _state(V, r, al, nkr, nz, y)
                        _record(hist, xh, kst, tau_now, R, r, y, nz, il if r == 1 else 0.0,
                                il if r == 2 else 0.0, 0.0, Qout, N, x)  # fmt: skip
                    break
                if kind <= 2:
                    # impact on stop `kind` (applied at the top of the loop)
                    if record and lp > 0.0:
                        _state(V, r, al, nkr, nz, y)
                        _record(hist, xh, kst, tau_now, R, r, y, nz, 0.0, 0.0, 0.0, Qout, N, x)
                    pending = kind
                    continue
                # release from stop r: the contact force reached zero
                ev_period += 1
                if ev_period > max_events_pp:
                    failed = ms.END_CHATTER
                    break
                if seg:
                    rc, rs = _rot(j, t, n_grid, gamma_r, cosg, sing)
                    h0, h1, h2, h3, vv, vb = _seg_close(r, al, a0, nkr, H, C, dint, dcm, nd,
                                                        j * h + t - pos0, rc0, rs0, rc, rs, h0,
                                                        h1, h2, h3, vv, vb)  # fmt: skip
                    seg = False
                _state(V, r, al, nkr, nz, y)
                if logev:
                    sgn = -1.0 if r == 1 else 1.0
                    resid = sgn * _row(R, r, R_MU, y, nz) / max(_row_scale(R, r, R_MU, y, nz),
                                                                1e-300)  # fmt: skip
                    _log_event(evlog, kst, tau_now, 2.0, r, resid, 0.0)
                rk = r
                pending, skip_on, ss, skip_rem = release(y, rk, Qout, R, RV, Vi, lam, nk, N, g1,
                                                         g2, h, x, ae, cw)  # fmt: skip
                if skip_on:
                    skip_stop = ss
                r = 0
                _modal(Vi, 0, y, nk[0], nzm, al)
                if record:
                    _record(hist, xh, kst, tau_now, R, 0, y, nzm, il if rk == 1 else 0.0,
                            il if rk == 2 else 0.0, 2.0 + rk, Qout, N, x)  # fmt: skip
            if failed != ms.END_NONE:
                break
        if seg and failed == ms.END_NONE:  # the period's end: forcing phase 2π
            h0, h1, h2, h3, vv, vb = _seg_close(r, al, a0, nk[r], H, C, dint, dcm, nd,
                                                n_grid * h - pos0, rc0, rs0, 1.0, 0.0, h0, h1, h2,
                                                h3, vv, vb)  # fmt: skip
        # the forcing oscillator's exact phase at the period's end (it cannot drift)
        f = fidx[r]
        if f >= 0 and failed == ms.END_NONE:
            al[f] = f_scale * fcs[r, 0]
            have = False
        ms.close_row(rows, k, smin, smax, (h0, h1, h2, h3), vv, vb, imp1, imp2, peak, last,
                     nsteps, nimpacts, ncoarse, r)  # fmt: skip
        ms.close_impacts(rows, k, ct1, ct2, vimp1, vimp2, en1, en2)
        _save_state(kst, r, skip_on, skip_stop, skip_rem, pending, contact)
        kst[K_REB_STOP] = reb_stop
        reb_t -= T
        kst[K_REB_T] = reb_t
        kst[K_REB_V] = reb_v
        kst[K_REB_RUN] = reb_run
        kst[ms.K_PERIOD] += 1.0
        _state(V, r, al, nk[r], nzr[r], y)
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
        ts = rt.skip_start(cw, lam[0], nk[0], g1 if stop == 1 else g2, h, True)
        if ts < 0.0:
            kst[K_PENDING] = stop
        else:
            kst[K_SKIP_ON] = 1.0
            kst[K_SKIP_STOP] = stop
            kst[K_SKIP_REM] = ts
