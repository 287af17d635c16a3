"""Event-driven reference solver (``method: "event"``).

An independent check of the time-stepping schemes in ``kernels.py``: no stepping code is shared
with them. The plastic-impact model of MODEL.md §4 is piecewise linear with three regimes:

* regime 0, free flight: ``z = [u; q; c; s]`` with ``(c, s) = f·(cos γτ, sin γτ)``, so the
  harmonic forcing is part of the linear system ``ż = A₀ z``;
* regimes 1 and 2, the tip stuck on stop 1 (``w_tip = g̃1``) or stop 2 (``w_tip = -g̃2``): the
  constrained system of MODEL.md §8 in reduced coordinates ``u = u*ₖ + Z v`` (``Z`` spans the
  null space of ``Wᵀ``), tested with ``Y`` (null space of ``Xᵀ``, which removes the contact
  force), ``y = [v; v̇; c; s; 1]``, ``ẏ = Aₖ y``. The trailing 1 carries the constant force that
  holds the tip off its rest position. The contact force ``μ = -λ1 + λ2`` is a linear row on y.

Every regime matrix is diagonalised once per point, ``A = V Λ V⁻¹``, so the state at any time
inside a regime is ``Re V e^{Λt} V⁻¹ y₀`` (exact up to round-off times cond(V); the point fails
with a reason if an eigenvector matrix is too ill-conditioned, e.g. an undamped resonance). The
step map of one sub-grid interval ``h = T/n`` (``Φ = V e^{Λh} V⁻¹``) is precomputed.

Event location, per sub-grid interval:

* A cheap test first: the cubic Hermite interpolant of the tip (free flight) or of the contact
  force (stuck) from both ends, widened by an estimate of its error (``h⁴/384·|f⁗|`` at the
  ends), must stay ``near_margin`` clear of the stop (of zero force, relative to the force).
* Otherwise an exact search of the sum of exponentials ``f(t) = f₀ + Σ cₖ e^{λₖ t}`` (gap or
  contact force): pieces are examined left to right; a piece is clear when the Hermite cubic's
  minimum minus the rigorous bound ``len⁴/384 · Σ|cₖ||λₖ|⁴ max e^{Re λₖ t}`` stays positive,
  otherwise it is split in four. A sign change in a short piece is refined by safeguarded Newton
  (bisection fallback) to ``event_tol·T`` plus one Newton polish; a tangential touch (grazing)
  is found as the exact minimum (Newton on ``ḟ = 0``) of a tiny piece. So grazing contacts are
  not missed by the sub-grid and the first root in an interval is the one taken.
* At an impact the plastic impulse ``P = -Wᵀq/G`` along ``M⁻¹X`` zeroes the tip's velocity; the
  tip sticks if the stuck regime's contact force is compressive (or zero and increasing), else it
  leaves at once. A stuck tip is released where the contact force reaches zero. After leaving a
  stop, the search for that stop starts once the gap has opened above round-off (the gap grows
  like t² or t³ there), so a release is never taken for a new impact.
* A per-period event budget (``max_events_per_period``) ends a run that chatters; the point is
  then ``failed`` with the reason.

Measurements match the other methods (MODEL.md §6): stroboscopic periodicity at period
boundaries, then ``p`` measured periods (or the last ``window`` of an irregular run).
First harmonics of ``s`` and ``s_b`` are integrated analytically within each regime piece
(``∫ e^{(λ-iγ)t} dt``, no quadrature); the amplitude's extrema are located exactly (Newton on
``ṡ = 0`` with the exact propagator); ``theta_eff_mean`` uses the rectangle rule (right ends,
like the other methods on their steps) on an exact sub-sampling of every piece at
``THETA_SAMPLES`` = 4096 per period (its integrand is singular near ``ṡ = 0``, so it converges
only to first order and differs from the other methods at their resolutions). Impacts per
period count contact episodes as the other methods do: an episode ends once the gap has opened
to 0.1% of its clearance (exact maximum of the gap over each free piece).

``SolverSettings.steps_per_period`` is the number of sub-grid intervals per period (default
64); it sets the cost, not the accuracy (the trajectory is exact between events). ``steps`` in
the result counts pieces (sub-grid intervals plus splits at events), ``contact_steps`` counts
impacts and ``coarse_steps`` the intervals cleared by the cheap test.
"""

from __future__ import annotations

import cmath
import dataclasses
import math
import time

import numpy as np
from numba import njit

# The periodicity test is measurement, not stepping: the same rule classifies every method.
from worker.kernels import _all_finite, _period_sample
from worker.model import CellParams, System, assemble

DEFAULT_EVENT_GRID = 64
DEFAULT_EVENT_TOL = 1e-12
DEFAULT_MAX_EVENTS_PER_PERIOD = 1000
MAX_COND = 1e10  # eigenvector condition number beyond which a regime is refused
# A state beyond this size ends the run as failed (diverged): the event search's error bounds
# (|c|·|λ|⁴·h⁴) overflow well before the state does, and a search on non-finite values never
# proves an interval clear (it would split ~4¹⁵ times per interval, i.e. hang).
MAX_STATE = 1e200

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

# own output record
E_S_MAX = 0
E_S_MIN = 1
E_S_RE = 2
E_S_IM = 3
E_SB_RE = 4
E_SB_IM = 5
E_THETA_SUM = 6
E_THETA_T = 7
E_IMP1 = 8
E_IMP2 = 9
E_PEAK = 10
E_MEASURED = 11
E_PERIODS = 12
E_PIECES = 13
E_IMPACTS = 14
E_RESPONSE_PERIOD = 15
E_CONVERGED = 16
E_FAILED = 17  # 0 ok, 1 non-finite state, 3 event budget exceeded, 5 diverged
E_FAIL_PERIOD = 18
E_QUICK = 19
E_HIST_COUNT = 20
E_SDOT_MAX = 21
E_STEADY = 22
E_EVENTS = 23
E_EVLOG_COUNT = 24
E_RELEASES = 25
E_EXACT_FREE = 26  # intervals searched exactly in free flight (diagnostic)
E_EXACT_STUCK = 27  # … while stuck
E_SIZE = 28

# history columns
EH_TAU = 0
EH_S = 1
EH_W = 2
EH_SB = 3
EH_SD = 4
EH_SBD = 5
EH_L1 = 6
EH_L2 = 7
EH_KIND = 8  # 0 interval end, 1/2 impact at stop 1/2, 3/4 release from stop 1/2
EH_COLS = 9

# event log columns: tau, kind (1 impact, 2 release), stop, residual (gap/g or force), impulse
EV_COLS = 5

MAX_PERIOD = 8
RING = 2 * MAX_PERIOD + 1
STACK = 160
THETA_SAMPLES = 4096  # sub-samples per period of the θ_eff time average


# --------------------------------------------------------------------------- scalar helpers


@njit(cache=True)
def _ev(c, lam, nz, off, t):
    """f(t) = off + Re Σ c_k e^{λ_k t} and its derivative."""
    f = off
    d = 0.0
    for k in range(nz):
        e = c[k] * cmath.exp(lam[k] * t)
        f += e.real
        d += (e * lam[k]).real
    return f, d


@njit(cache=True)
def _ev2(c, lam, nz, t):
    """First and second derivative of Re Σ c_k e^{λ_k t}."""
    d = 0.0
    dd = 0.0
    for k in range(nz):
        e = c[k] * lam[k] * cmath.exp(lam[k] * t)
        d += e.real
        dd += (e * lam[k]).real
    return d, dd


@njit(cache=True)
def _bound4(c, lam, nz, lo, hi):
    """Rigorous bound of the cubic Hermite interpolation error of Σ c e^{λt} on [lo, hi]."""
    acc = 0.0
    for k in range(nz):
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        r = lam[k].real
        acc += abs(c[k]) * m2 * m2 * math.exp(max(r * lo, r * hi))
    ln = hi - lo
    return acc * ln * ln * ln * ln / 384.0


@njit(cache=True)
def _cubic_minmax(f0, d0, f1, d1, ln):
    """(min, argmin, max, argmax) over [0, ln] of the cubic Hermite interpolant."""
    fmin = f0
    tmin = 0.0
    fmax = f0
    tmax = 0.0
    if f1 < fmin:
        fmin = f1
        tmin = ln
    if f1 > fmax:
        fmax = f1
        tmax = ln
    c = d0 * ln
    a = 2.0 * f0 + c - 2.0 * f1 + d1 * ln
    b = 3.0 * (f1 - f0) - 2.0 * c - d1 * ln
    qa = 3.0 * a
    qb = 2.0 * b
    roots = np.empty(2)
    nr = 0
    if abs(qa) < 1e-300:
        if abs(qb) > 1e-300:
            roots[0] = -c / qb
            nr = 1
    else:
        disc = qb * qb - 4.0 * qa * c
        if disc >= 0.0:
            qq = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))
            roots[0] = qq / qa
            nr = 1
            if qq != 0.0:
                roots[1] = c / qq
                nr = 2
    for i in range(nr):
        s = roots[i]
        if 0.0 < s < 1.0:
            p = ((a * s + b) * s + c) * s + f0
            if p < fmin:
                fmin = p
                tmin = s * ln
            if p > fmax:
                fmax = p
                tmax = s * ln
    return fmin, tmin, fmax, tmax


@njit(cache=True)
def _refine(c, lam, nz, off, lo, hi, flo, fhi, tol_t):
    """Root of f in [lo, hi] with f(lo) > 0 >= f(hi): safeguarded Newton, then one polish."""
    if fhi == 0.0:
        return hi
    a = lo
    b = hi
    t = lo + (hi - lo) * flo / (flo - fhi)  # regula falsi start
    if not (a < t < b):
        t = 0.5 * (a + b)
    for _ in range(200):
        f, d = _ev(c, lam, nz, off, t)
        if f > 0.0:
            a = t
        else:
            b = t
        if f == 0.0:
            return t
        tn = t - f / d if d != 0.0 else -1.0
        if not (a < tn < b):
            tn = 0.5 * (a + b)
        step = abs(tn - t)
        t = tn
        if step <= tol_t or b - a <= 4e-16 * max(abs(a), abs(b)):
            f, d = _ev(c, lam, nz, off, t)
            if d != 0.0:
                tn = t - f / d
                if a <= tn <= b:
                    t = tn
            return t
    return t


@njit(cache=True)
def _crit(c, lam, nz, lo, hi, dlo, dhi, guess):
    """A critical point (ḟ = 0) in [lo, hi]; Newton safeguarded by the bracket if there is one."""
    if dlo * dhi > 0.0:
        return guess
    a = lo
    b = hi
    up = dlo < 0.0  # ḟ increasing through zero: a minimum
    t = guess if lo < guess < hi else 0.5 * (lo + hi)
    for _ in range(100):
        d, dd = _ev2(c, lam, nz, t)
        if (d < 0.0) == up:
            a = t
        else:
            b = t
        tn = t - d / dd if dd != 0.0 else -1.0
        if not (a < tn < b):
            tn = 0.5 * (a + b)
        if abs(tn - t) <= 1e-15 * max(abs(hi), 1e-300):
            return tn
        t = tn
    return t


@njit(cache=True)
def _first_root(c, lam, nz, off, t0, t1, tol_t, stack):
    """First t in [t0, t1] where f(t) = off + Re Σ c e^{λt} reaches zero, or -1."""
    f0, d0 = _ev(c, lam, nz, off, t0)
    if f0 <= 0.0:
        return t0
    f1, d1 = _ev(c, lam, nz, off, t1)
    total = t1 - t0
    tiny = 1e-9 * total
    sp = 0
    stack[0, 0] = t0
    stack[0, 1] = t1
    stack[0, 2] = f0
    stack[0, 3] = d0
    stack[0, 4] = f1
    stack[0, 5] = d1
    sp = 1
    while sp > 0:
        sp -= 1
        lo = stack[sp, 0]
        hi = stack[sp, 1]
        flo = stack[sp, 2]
        dlo = stack[sp, 3]
        fhi = stack[sp, 4]
        dhi = stack[sp, 5]
        if flo <= 0.0:
            return lo
        ln = hi - lo
        if fhi <= 0.0:
            # sign change; a long piece may hide an earlier touch, so look closer first
            if ln <= 0.0625 * total or sp >= STACK - 5:
                return _refine(c, lam, nz, off, lo, hi, flo, fhi, tol_t)
        else:
            fmin, tmin, _, _ = _cubic_minmax(flo, dlo, fhi, dhi, ln)
            bnd = _bound4(c, lam, nz, lo, hi)
            if fmin - bnd > 0.0:
                continue
            if ln <= tiny or sp >= STACK - 5:
                tc = _crit(c, lam, nz, lo, hi, dlo, dhi, lo + tmin)
                fc, _ = _ev(c, lam, nz, off, tc)
                if fc <= 0.0:
                    return _refine(c, lam, nz, off, lo, tc, flo, fc, tol_t)
                continue
        # split in four, pushed right to left so the leftmost piece is examined first
        pf = fhi
        pd = dhi
        for i in range(3, -1, -1):
            a_ = lo + ln * i / 4.0
            b_ = lo + ln * (i + 1) / 4.0 if i < 3 else hi
            if i > 0:
                fa, da = _ev(c, lam, nz, off, a_)
            else:
                fa = flo
                da = dlo
            stack[sp, 0] = a_
            stack[sp, 1] = b_
            stack[sp, 2] = fa
            stack[sp, 3] = da
            stack[sp, 4] = pf
            stack[sp, 5] = pd
            sp += 1
            pf = fa
            pd = da
    return -1.0


@njit(cache=True)
def _clear_whole(c, lam, E, nz, off, ln):
    """True if off + Re Σ c e^{λt} > 0 on [0, ln] is proven by the Hermite cubic and the
    rigorous error bound, with ``E = e^{λ·ln}`` given (no exponentials evaluated)."""
    f0 = off
    d0 = 0.0
    f1 = off
    d1 = 0.0
    acc = 0.0
    for k in range(nz):
        cl = c[k] * lam[k]
        ce = c[k] * E[k]
        f0 += c[k].real
        d0 += cl.real
        f1 += ce.real
        d1 += (cl * E[k]).real
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        acc += abs(c[k]) * m2 * m2 * max(1.0, abs(E[k]))
    if f0 <= 0.0 or f1 <= 0.0:
        return False
    fmin, _, _, _ = _cubic_minmax(f0, d0, f1, d1, ln)
    return fmin - acc * ln * ln * ln * ln / 384.0 > 0.0


@njit(cache=True)
def _state_E(V, r, a, E, nz, out):
    for i in range(nz):
        acc = 0.0
        for k in range(nz):
            acc += (V[r, i, k] * (a[k] * E[k])).real
        out[i] = acc


@njit(cache=True)
def _skip_start(c, lam, nz, off, h):
    """Smallest tried t in (0, h] where f(t) is clearly positive (after leaving f = 0), or -1."""
    scale = abs(off)
    for k in range(nz):
        scale += abs(c[k])
    eps = 1e-12 * scale
    t = h * 8.0**-13
    while t <= h * (1.0 + 1e-12):
        f, _ = _ev(c, lam, nz, off, t)
        if f > eps:
            return t
        t *= 8.0
    return -1.0


@njit(cache=True)
def _phi1(x, ln):
    """(e^{x·ln} - 1)/x, stable for small x·ln."""
    z = x * ln
    if abs(z) < 1e-3:
        return ln * (1.0 + z / 2.0 * (1.0 + z / 3.0 * (1.0 + z / 4.0 * (1.0 + z / 5.0))))
    return (cmath.exp(z) - 1.0) / x


# --------------------------------------------------------------------------- state helpers


@njit(cache=True)
def _modal(Vi, r, y, nz, a):
    for i in range(nz):
        acc = 0.0 + 0.0j
        for j in range(nz):
            acc += Vi[r, i, j] * y[j]
        a[i] = acc


@njit(cache=True)
def _state_at(V, lam, r, a, nz, t, out, tmp):
    for k in range(nz):
        tmp[k] = a[k] * cmath.exp(lam[r, k] * t)
    for i in range(nz):
        acc = 0.0
        for k in range(nz):
            acc += (V[r, i, k] * tmp[k]).real
        out[i] = acc


@njit(cache=True)
def _coef(RV, r, row, a, nz, sgn, c):
    for k in range(nz):
        c[k] = sgn * RV[r, row, k] * a[k]


@njit(cache=True)
def _row(R, r, row, y, nz):
    acc = 0.0
    for i in range(nz):
        acc += R[r, row, i] * y[i]
    return acc


@njit(cache=True)
def _row_scale(R, r, row, y, nz):
    acc = 0.0
    for i in range(nz):
        acc += abs(R[r, row, i] * y[i])
    return acc


@njit(cache=True)
def _matvec(A, r, y, nz, out):
    for i in range(nz):
        acc = 0.0
        for j in range(nz):
            acc += A[r, i, j] * y[j]
        out[i] = acc


@njit(cache=True)
def _full(r, y, Qout, N, x):
    """Full state x = [u; q] of the regime state."""
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


# --------------------------------------------------------------------------- measurement


@njit(cache=True)
def _measure_piece(out, r, a, nz, lam, RV, ln, s0, sd0, s1, sd1, sbd1, ph, gamma_r, kappa,
                   theta, thr, tol_t, dt_theta, cw, cw2, ew, pw):  # fmt: skip
    """Exact harmonics, exact extrema of s and the θ_eff rectangle rule over one piece."""
    if ln <= 0.0:
        return
    rc = math.cos(ph)
    rs = -math.sin(ph)
    shift = -1j * gamma_r
    for q in range(2):
        row = R_S if q == 0 else R_SB
        acc = 0.0 + 0.0j
        for k in range(nz):
            acc += RV[r, row, k] * a[k] * _phi1(lam[r, k] + shift, ln)
        out[E_S_RE + 2 * q] += acc.real * rc - acc.imag * rs
        out[E_S_IM + 2 * q] += acc.real * rs + acc.imag * rc
    hi = max(s0, s1)
    lo = min(s0, s1)
    if sd0 * sd1 < 0.0:
        sgn = 1.0 if sd0 > 0.0 else -1.0
        _coef(RV, r, R_SD, a, nz, sgn, cw)
        tc = _refine(cw, lam[r], nz, 0.0, 0.0, ln, abs(sd0), -abs(sd1), 1e-3 * tol_t)
        _coef(RV, r, R_S, a, nz, 1.0, cw)
        sc, _ = _ev(cw, lam[r], nz, 0.0, tc)
        hi = max(hi, sc)
        lo = min(lo, sc)
    out[E_S_MAX] = max(out[E_S_MAX], hi)
    out[E_S_MIN] = min(out[E_S_MIN], lo)
    # θ_eff time average: rectangle rule on a fine uniform sub-sampling of the exact piece
    m = max(1, int(math.ceil(ln / dt_theta)))
    dt = ln / m
    for k in range(nz):
        cw[k] = RV[r, R_SD, k] * a[k]
        cw2[k] = RV[r, R_SBD, k] * a[k]
        ew[k] = cmath.exp(lam[r, k] * dt)
        pw[k] = 1.0
    for i in range(m):
        if i == m - 1:
            sd = sd1
            sbd = sbd1
        else:
            sd = 0.0
            sbd = 0.0
            for k in range(nz):
                pw[k] *= ew[k]
                sd += (cw[k] * pw[k]).real
                sbd += (cw2[k] * pw[k]).real
        if abs(sd) >= thr and abs(sd) > 0.0:
            out[E_THETA_SUM] += dt * (kappa - theta * sbd / sd) / (1.0 + theta)
            out[E_THETA_T] += dt


@njit(cache=True)
def _opened(contact_prev, y, ye, ln, r_, R, RV, Vi, lam, nz, g1, g2, open_frac, a, have_a, cw):
    """Contact state after a free piece: an episode ends once the gap of its stop has opened to
    ``open_frac`` of the clearance (exact maximum of the gap over the piece)."""
    k = contact_prev
    sgn = -1.0 if k == 1 else 1.0
    gk = g1 if k == 1 else g2
    thr = open_frac * gk
    f0 = gk + sgn * _row(R, r_, R_W, y, nz)
    d0 = sgn * _row(R, r_, R_WD, y, nz)
    f1 = gk + sgn * _row(R, r_, R_W, ye, nz)
    d1 = sgn * _row(R, r_, R_WD, ye, nz)
    if f0 > thr or f1 > thr:
        return 0
    _, _, fmax, tmax = _cubic_minmax(f0, d0, f1, d1, ln)
    if fmax <= 0.5 * thr:
        return k
    if not have_a:
        _modal(Vi, r_, y, nz, a)
    _coef(RV, r_, R_W, a, nz, sgn, cw)
    tc = _crit(cw, lam[r_], nz, 0.0, ln, d0, d1, tmax)
    fc, _ = _ev(cw, lam[r_], nz, gk, tc)
    return 0 if fc > thr else k


@njit(cache=True)
def _reset_measure(out):
    out[E_S_MAX] = -np.inf
    out[E_S_MIN] = np.inf
    for k in range(E_S_RE, E_MEASURED + 1):
        out[k] = 0.0


@njit(cache=True)
def _record(hist, out, tau, R, r, y, nz, l1, l2, kind, Qout, N, xh):
    cap = hist.shape[0]
    if cap == 0:
        return
    k = int(out[E_HIST_COUNT]) % cap
    hist[k, EH_TAU] = tau
    hist[k, EH_S] = _row(R, r, R_S, y, nz)
    hist[k, EH_W] = _row(R, r, R_W, y, nz)
    hist[k, EH_SB] = _row(R, r, R_SB, y, nz)
    hist[k, EH_SD] = _row(R, r, R_SD, y, nz)
    hist[k, EH_SBD] = _row(R, r, R_SBD, y, nz)
    hist[k, EH_L1] = l1
    hist[k, EH_L2] = l2
    hist[k, EH_KIND] = kind
    _full(r, y, Qout, N, xh[k])
    out[E_HIST_COUNT] += 1.0


@njit(cache=True)
def _log_event(evlog, out, tau, kind, stop, resid, impulse):
    cap = evlog.shape[0]
    if cap == 0:
        return
    k = int(out[E_EVLOG_COUNT]) % cap
    evlog[k, 0] = tau
    evlog[k, 1] = kind
    evlog[k, 2] = stop
    evlog[k, 3] = resid
    evlog[k, 4] = impulse
    out[E_EVLOG_COUNT] += 1.0


# --------------------------------------------------------------------------- the kernel


@njit(cache=True)
def event_kernel(
    y,
    nzr,
    Phi,
    eh,
    lam,
    V,
    Vi,
    R,
    RV,
    Pin,
    Qout,
    W,
    MinvX,
    G,
    g1,
    g2,
    bilateral,
    N,
    n_grid,
    gamma_r,
    f_scale,
    kappa,
    theta,
    max_periods,
    tol,
    window,
    margin,
    early_stop,
    open_frac,
    event_tol,
    max_events_pp,
    hist,
    xh,
    evlog,
    out,
    ring,
):
    """Run one point from the free-flight state ``y = [u; q; f; 0]`` at τ = 0.

    See the module docstring for the method. ``Phi``, ``lam``, ``V``, ``Vi``, ``R``, ``RV`` are
    stacked per regime (0 free, 1/2 stuck on stop 1/2), zero-padded to ``2N+2``.
    """
    nzm = 2 * N + 2
    nx = 2 * N
    T = 2.0 * math.pi / gamma_r
    h = T / n_grid
    tol_t = event_tol * T
    hist_cap = hist.shape[0]
    ye = np.zeros(nzm)
    tmp = np.zeros(nzm, dtype=np.complex128)
    a = np.zeros(nzm, dtype=np.complex128)
    c1 = np.zeros(nzm, dtype=np.complex128)
    c2 = np.zeros(nzm, dtype=np.complex128)
    cw = np.zeros(nzm, dtype=np.complex128)
    cw2 = np.zeros(nzm, dtype=np.complex128)
    ew = np.zeros(nzm, dtype=np.complex128)
    pw = np.zeros(nzm, dtype=np.complex128)
    Ew = np.zeros(nzm, dtype=np.complex128)
    dt_theta = T / THETA_SAMPLES
    x = np.zeros(nx)
    x2 = np.zeros(nzm)
    stack = np.zeros((STACK, 6))

    for k in range(E_SIZE):
        out[k] = 0.0
    out[E_EXACT_FREE] = 0.0
    out[E_STEADY] = -1.0
    _reset_measure(out)

    r = 0  # regime
    skip_on = False  # the search of the current regime's constraint starts late
    skip_stop = 0
    skip_rem = 0.0
    pending = 0  # impact to apply at once (stop index)
    contact_prev = 0
    nring = 0
    measuring = False
    measure_end = -1
    thr = 0.0
    sdot_max_period = 0.0
    events = 0
    impacts = 0
    releases = 0
    pieces = 0
    quick_steps = 0
    period = 0
    failed = 0

    # start on a stop: a gap closed at τ = 0 is an impact (or a departure) there
    if bilateral:
        pending = 1
    else:
        wu = _row(R, 0, R_W, y, nzm)
        wd = _row(R, 0, R_WD, y, nzm)
        if g1 - wu <= 1e-12 * max(g1, 1e-300):
            if wd >= 0.0:
                pending = 1
            else:
                skip_on = True
                skip_stop = 1
                skip_rem = 0.0
        elif g2 + wu <= 1e-12 * max(g2, 1e-300):
            if wd <= 0.0:
                pending = 2
            else:
                skip_on = True
                skip_stop = 2
                skip_rem = 0.0
        if skip_on:  # leaving a stop at τ = 0: search it once the gap has opened
            _modal(Vi, 0, y, nzm, a)
            _coef(RV, 0, R_W, a, nzm, -1.0 if skip_stop == 1 else 1.0, cw)
            ts = _skip_start(cw, lam[0], nzm, g1 if skip_stop == 1 else g2, h)
            if ts < 0.0:
                skip_on = False
                pending = skip_stop
            else:
                skip_rem = ts

    while True:
        if not measuring and period >= max_periods - window:
            measuring = True
            measure_end = max_periods
            _reset_measure(out)
            thr = 1e-3 * sdot_max_period
        if measuring and period >= measure_end:
            break
        sdot_max_this = 0.0
        ev_period = 0
        for j in range(n_grid):
            t = 0.0
            ph0 = 2.0 * math.pi * j / n_grid
            while failed == 0:
                nz = nzr[r]
                big = 0.0
                for i in range(nz):
                    big = max(big, abs(y[i]))  # NaN never wins a max: test finiteness too
                    if not math.isfinite(y[i]):
                        big = math.inf
                        break
                if big > MAX_STATE:
                    failed = 5
                    break
                if pending != 0:
                    # impact at the current time without propagation (start on a stop, or the
                    # tip did not leave a stop it was released from)
                    k = pending
                    pending = 0
                    tau_now = period * T + j * h + t
                    events += 1
                    ev_period += 1
                    if ev_period > max_events_pp:
                        failed = 3
                        break
                    # --- plastic impact on stop k (r is 0 here)
                    wu = _row(R, 0, R_W, y, nzm)
                    wd = _row(R, 0, R_WD, y, nzm)
                    resid = (g1 - wu) / max(g1, 1e-300) if k == 1 else (g2 + wu) / max(g2, 1e-300)
                    P = -wd / G
                    for i in range(N):
                        y[N + i] += MinvX[i] * P
                    impacts += 1
                    if measuring:
                        if contact_prev != k:
                            out[E_IMP1 if k == 1 else E_IMP2] += 1.0
                        out[E_PEAK] = max(out[E_PEAK], abs(P))
                    contact_prev = k
                    _log_event(evlog, out, tau_now, 1.0, k, resid, abs(P))
                    pending = -k  # decide stick or leave below
                    imp_l = abs(P)
                else:
                    imp_l = 0.0
                if pending < 0:
                    # after an impact at stop k: stick if the contact force is compressive
                    k = -pending
                    pending = 0
                    kk = 1 if bilateral else k
                    for i in range(nzm - 1):
                        acc = 0.0
                        for jj in range(nzm):
                            acc += Pin[kk - 1, i, jj] * y[jj]
                        ye[i] = acc
                    ye[nzm - 2] = 1.0  # the constant state
                    ye[nzm - 1] = 0.0
                    sgn = -1.0 if kk == 1 else 1.0
                    lk = sgn * _row(R, kk, R_MU, ye, nzm - 1)
                    ld = sgn * _row(R, kk, R_MUD, ye, nzm - 1)
                    eps = 1e-12 * _row_scale(R, kk, R_MU, ye, nzm - 1)
                    # Stick if the contact force is compressive (or zero and growing), else
                    # leave. A departure whose gap never opens above round-off within an
                    # interval (the force turns compressive again at once) is taken as stuck,
                    # and vice versa; if neither works the impact repeats (event budget).
                    stick = bilateral or lk > eps or (lk >= -eps and ld > 0.0)
                    ok = False
                    tau_now = period * T + j * h + t
                    for _attempt in range(2):
                        if stick:
                            if bilateral or lk > eps:
                                skip_on = False
                                ok = True
                            else:
                                _modal(Vi, kk, ye, nzm - 1, a)
                                _coef(RV, kk, R_MU, a, nzm - 1, sgn, cw)
                                ts = _skip_start(cw, lam[kk], nzm - 1, 0.0, h)
                                if ts >= 0.0:
                                    skip_on = True
                                    skip_rem = ts
                                    ok = True
                            if ok:
                                for i in range(nzm):
                                    y[i] = ye[i]
                                r = kk
                                break
                        else:
                            _full(kk, ye, Qout, N, x)
                            for i in range(nx):
                                x2[i] = x[i]
                            x2[nx] = ye[nzm - 4]
                            x2[nx + 1] = ye[nzm - 3]
                            _modal(Vi, 0, x2, nzm, a)
                            _coef(RV, 0, R_W, a, nzm, -1.0 if k == 1 else 1.0, cw)
                            ts = _skip_start(cw, lam[0], nzm, g1 if k == 1 else g2, h)
                            if ts >= 0.0:
                                for i in range(nzm):
                                    y[i] = x2[i]
                                r = 0
                                skip_on = True
                                skip_stop = k
                                skip_rem = ts
                                ok = True
                                break
                        stick = not stick
                    if not ok:
                        pending = k  # neither sticks nor leaves: impact again
                    elif hist_cap > 0:
                        _record(hist, out, tau_now, R, r, y, nzr[r],
                                imp_l if k == 1 else 0.0, imp_l if k == 2 else 0.0, k,
                                Qout, N, xh)  # fmt: skip
                    continue

                ln = h - t
                if ln <= 1e-13 * h:
                    break
                # ---- cheap test on a whole interval
                have_ye = False
                if t == 0.0 and not skip_on:
                    _matvec(Phi, r, y, nz, ye)
                    have_ye = True
                    quick = False
                    if r == 0:
                        w0 = _row(R, 0, R_W, y, nz)
                        d0 = _row(R, 0, R_WD, y, nz)
                        w1 = _row(R, 0, R_W, ye, nz)
                        d1 = _row(R, 0, R_WD, ye, nz)
                        wmin, _, wmax, _ = _cubic_minmax(w0, d0, w1, d1, h)
                        bnd = (
                            2.0
                            * h**4
                            / 384.0
                            * (abs(_row(R, 0, R_W4, y, nz)) + abs(_row(R, 0, R_W4, ye, nz)))
                        )
                        quick = wmax + bnd < g1 * (1.0 - margin) and wmin - bnd > -g2 * (
                            1.0 - margin
                        )
                    elif bilateral:
                        quick = True
                    else:
                        sgn = -1.0 if r == 1 else 1.0
                        l0 = sgn * _row(R, r, R_MU, y, nz)
                        e0 = sgn * _row(R, r, R_MUD, y, nz)
                        l1 = sgn * _row(R, r, R_MU, ye, nz)
                        e1 = sgn * _row(R, r, R_MUD, ye, nz)
                        lmin, _, _, _ = _cubic_minmax(l0, e0, l1, e1, h)
                        bnd = (
                            2.0
                            * h**4
                            / 384.0
                            * (abs(_row(R, r, R_MU4, y, nz)) + abs(_row(R, r, R_MU4, ye, nz)))
                        )
                        quick = lmin - bnd > margin * max(l0, l1)
                    if quick:
                        s0 = _row(R, r, R_S, y, nz)
                        sd0 = _row(R, r, R_SD, y, nz)
                        if measuring or (hist_cap > 0 and r != 0):
                            _modal(Vi, r, y, nz, a)
                        il = 0.0
                        if hist_cap > 0 and r != 0:
                            _coef(RV, r, R_MU, a, nz, -1.0 if r == 1 else 1.0, cw)
                            for kq in range(nz):
                                il += (cw[kq] * _phi1(lam[r, kq], h)).real
                        if measuring:
                            _measure_piece(out, r, a, nz, lam, RV, h, s0, sd0,
                                           _row(R, r, R_S, ye, nz), _row(R, r, R_SD, ye, nz),
                                           _row(R, r, R_SBD, ye, nz), ph0, gamma_r, kappa,
                                           theta, thr, tol_t, dt_theta, cw, cw2, ew,
                                           pw)  # fmt: skip
                        if r == 0 and contact_prev != 0:
                            contact_prev = _opened(contact_prev, y, ye, h, 0, R, RV, Vi, lam, nz,
                                                   g1, g2, open_frac, a, measuring, cw)  # fmt: skip
                        for i in range(nz):
                            y[i] = ye[i]
                        pieces += 1
                        quick_steps += 1
                        sdot_max_this = max(sdot_max_this, abs(_row(R, r, R_SD, y, nz)))
                        if hist_cap > 0:
                            _record(hist, out, period * T + (j + 1) * h, R, r, y, nz,
                                    il if r == 1 else 0.0, il if r == 2 else 0.0, 0, Qout, N,
                                    xh)  # fmt: skip
                        break
                # ---- exact search over [t, h] (ye = Φ y already if have_ye)
                if t == 0.0 and not have_ye:
                    _matvec(Phi, r, y, nz, ye)
                    have_ye = True
                out[E_EXACT_FREE if r == 0 else E_EXACT_STUCK] += 1.0
                _modal(Vi, r, y, nz, a)
                if have_ye:
                    for k in range(nz):
                        Ew[k] = eh[r, k]
                else:
                    for k in range(nz):
                        Ew[k] = cmath.exp(lam[r, k] * ln)
                t_ev = -1.0
                kind = 0
                if r == 0:
                    for k in range(1, 3):
                        gk = g1 if k == 1 else g2
                        cc = c1 if k == 1 else c2
                        _coef(RV, 0, R_W, a, nz, -1.0 if k == 1 else 1.0, cc)
                        ts = 0.0
                        if skip_on and skip_stop == k:
                            if skip_rem >= ln:
                                continue
                            ts = skip_rem
                        lim = ln if t_ev < 0.0 else t_ev
                        if ts >= lim:
                            continue
                        if ts == 0.0 and lim == ln and _clear_whole(cc, lam[0], Ew, nz, gk, ln):
                            continue
                        te = _first_root(cc, lam[0], nz, gk, ts, lim, tol_t, stack)
                        if te >= 0.0 and (t_ev < 0.0 or te < t_ev):
                            t_ev = te
                            kind = k
                elif not bilateral:
                    sgn = -1.0 if r == 1 else 1.0
                    _coef(RV, r, R_MU, a, nz, sgn, c1)
                    ts = skip_rem if skip_on else 0.0
                    if ts < ln and not (ts == 0.0 and _clear_whole(c1, lam[r], Ew, nz, 0.0, ln)):
                        te = _first_root(c1, lam[r], nz, 0.0, ts, ln, tol_t, stack)
                        if te >= 0.0:
                            t_ev = te
                            kind = 2 + r  # release from stop r
                lp = t_ev if t_ev >= 0.0 else ln
                if t_ev >= 0.0:
                    _state_at(V, lam, r, a, nz, lp, ye, tmp)
                elif not have_ye:
                    _state_E(V, r, a, Ew, nz, ye)
                s0 = _row(R, r, R_S, y, nz)
                sd0 = _row(R, r, R_SD, y, nz)
                if measuring:
                    _measure_piece(out, r, a, nz, lam, RV, lp, s0, sd0,
                                   _row(R, r, R_S, ye, nz), _row(R, r, R_SD, ye, nz),
                                   _row(R, r, R_SBD, ye, nz), ph0 + gamma_r * t, gamma_r,
                                   kappa, theta, thr, tol_t, dt_theta, cw, cw2, ew, pw)  # fmt: skip
                il = 0.0
                if hist_cap > 0 and r != 0:
                    _coef(RV, r, R_MU, a, nz, -1.0 if r == 1 else 1.0, cw)
                    for kq in range(nz):
                        il += (cw[kq] * _phi1(lam[r, kq], lp)).real
                if r == 0 and contact_prev != 0:
                    contact_prev = _opened(contact_prev, y, ye, lp, 0, R, RV, Vi, lam, nz, g1, g2,
                                           open_frac, a, True, cw)  # fmt: skip
                if skip_on:
                    skip_rem -= lp
                    if skip_rem <= 0.0:
                        skip_on = False
                for i in range(nz):
                    y[i] = ye[i]
                pieces += 1
                sdot_max_this = max(sdot_max_this, abs(_row(R, r, R_SD, y, nz)))
                t = h if t_ev < 0.0 else t + lp
                tau_now = period * T + j * h + t
                if t_ev < 0.0:
                    if hist_cap > 0:
                        _record(hist, out, tau_now, R, r, y, nz, il if r == 1 else 0.0,
                                il if r == 2 else 0.0, 0, Qout, N, xh)  # fmt: skip
                    break
                if kind <= 2:
                    # impact on stop `kind` (applied at the top of the loop)
                    if hist_cap > 0 and lp > 0.0:
                        _record(hist, out, tau_now, R, r, y, nz, 0.0, 0.0, 0, Qout, N, xh)
                    pending = kind
                    continue
                # release from stop r: the contact force reached zero
                events += 1
                releases += 1
                ev_period += 1
                if ev_period > max_events_pp:
                    failed = 3
                    break
                k = r
                sgn = -1.0 if k == 1 else 1.0
                resid = sgn * _row(R, k, R_MU, y, nz) / max(_row_scale(R, k, R_MU, y, nz), 1e-300)
                _log_event(evlog, out, tau_now, 2.0, k, resid, 0.0)
                _full(k, y, Qout, N, x)
                osc_c = y[nzm - 4]
                osc_s = y[nzm - 3]
                for i in range(nx):
                    y[i] = x[i]
                y[nx] = osc_c
                y[nx + 1] = osc_s
                r = 0
                if hist_cap > 0:
                    _record(hist, out, tau_now, R, 0, y, nzm, il if k == 1 else 0.0,
                            il if k == 2 else 0.0, 2 + k, Qout, N, xh)  # fmt: skip
                _modal(Vi, 0, y, nzm, a)
                _coef(RV, 0, R_W, a, nzm, -1.0 if k == 1 else 1.0, cw)
                ts = _skip_start(cw, lam[0], nzm, g1 if k == 1 else g2, h)
                if ts < 0.0:
                    pending = k
                else:
                    skip_on = True
                    skip_stop = k
                    skip_rem = ts
            if failed != 0:
                break
            # exact forcing phase at the grid point (no drift of the oscillator)
            ang = 2.0 * math.pi * (j + 1) / n_grid
            ic = 2 * N if r == 0 else 2 * N - 2
            y[ic] = f_scale * math.cos(ang)
            y[ic + 1] = f_scale * math.sin(ang)
        period += 1
        if failed != 0:
            out[E_FAILED] = failed
            out[E_FAIL_PERIOD] = period
            break
        sdot_max_period = sdot_max_this
        _full(r, y, Qout, N, x)
        if not _all_finite(x, nx):
            out[E_FAILED] = 1.0
            out[E_FAIL_PERIOD] = period
            break
        if measuring:
            out[E_MEASURED] += 1.0
            continue
        nring += 1
        p = _period_sample(ring, nring, period, x, tol, nx, early_stop)
        if p > 0:
            out[E_RESPONSE_PERIOD] = p
            out[E_CONVERGED] = 1.0
            out[E_STEADY] = period
            measuring = True
            measure_end = period + p
            _reset_measure(out)
            thr = 1e-3 * sdot_max_period

    out[E_PERIODS] = period
    out[E_PIECES] = pieces
    out[E_IMPACTS] = impacts
    out[E_RELEASES] = releases
    out[E_EVENTS] = events
    out[E_QUICK] = quick_steps
    out[E_SDOT_MAX] = sdot_max_period


# --------------------------------------------------------------------------- preparation


@dataclasses.dataclass(frozen=True)
class EventArrays:
    """Per-regime matrices of one point, stacked (0 free, 1/2 stuck on stop 1/2)."""

    nzr: np.ndarray
    Phi: np.ndarray
    eh: np.ndarray
    lam: np.ndarray
    V: np.ndarray
    Vi: np.ndarray
    R: np.ndarray
    RV: np.ndarray
    Pin: np.ndarray
    Qout: np.ndarray
    cond: float


def _null_basis(v: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the null space of vᵀ (N × N-1)."""
    _, _, vt = np.linalg.svd(v[None, :])
    return np.ascontiguousarray(vt[1:].T)


def free_matrix(sys_: System) -> np.ndarray:
    """A₀ of ``ż = A₀ z``, ``z = [u; q; c; s]`` with the forcing oscillator carried exactly."""
    N = sys_.ndof
    g = sys_.params.gamma_r
    A = np.zeros((2 * N + 2, 2 * N + 2))
    A[:N, N : 2 * N] = np.eye(N)
    A[N : 2 * N, :N] = -sys_.Minv @ sys_.K
    A[N : 2 * N, N : 2 * N] = -sys_.Minv @ sys_.C
    fs = sys_.Minv[:, -1]
    A[N : 2 * N, 2 * N] = fs * sys_.f_cos
    A[N : 2 * N, 2 * N + 1] = fs * sys_.f_sin
    A[2 * N, 2 * N + 1] = -g
    A[2 * N + 1, 2 * N] = g
    return A


def stuck_matrices(sys_: System, w_star: float) -> tuple[np.ndarray, ...]:
    """Reduced constrained system with the tip held at ``w_tip = w_star`` (MODEL.md §8).

    Returns ``(A, Pin, Qout, mu)``: ``ẏ = A y`` with ``y = [v; v̇; c; s; 1]``; ``y = Pin z``
    (plus the constant 1) maps a free state onto the constraint; ``z = Qout y`` maps back;
    ``mu`` is the row of the contact force ``μ = -λ1 + λ2`` over y.
    """
    N = sys_.ndof
    m = N - 1
    g = sys_.params.gamma_r
    W, X = sys_.W, sys_.X
    Z = _null_basis(W)
    Y = _null_basis(X)
    M, C, K = sys_.M, sys_.C, sys_.K
    Mr_inv = np.linalg.inv(Y.T @ M @ Z)
    e_s = np.zeros(N)
    e_s[-1] = 1.0
    u_star = W * (w_star / (W @ W))
    ny = 2 * N + 1
    A = np.zeros((ny, ny))
    A[:m, m : 2 * m] = np.eye(m)
    A[m : 2 * m, :m] = -Mr_inv @ (Y.T @ K @ Z)
    A[m : 2 * m, m : 2 * m] = -Mr_inv @ (Y.T @ C @ Z)
    fy = Mr_inv @ (Y.T @ e_s)
    A[m : 2 * m, 2 * m] = fy * sys_.f_cos
    A[m : 2 * m, 2 * m + 1] = fy * sys_.f_sin
    A[m : 2 * m, 2 * m + 2] = -Mr_inv @ (Y.T @ K @ u_star)
    A[2 * m, 2 * m + 1] = -g
    A[2 * m + 1, 2 * m] = g
    Qout = np.zeros((2 * N + 2, ny))
    Qout[:N, :m] = Z
    Qout[:N, 2 * m + 2] = u_star
    Qout[N : 2 * N, m : 2 * m] = Z
    Qout[2 * N, 2 * m] = 1.0
    Qout[2 * N + 1, 2 * m + 1] = 1.0
    Pin = np.zeros((ny, 2 * N + 2))
    Pin[:m, :N] = Z.T
    Pin[m : 2 * m, N : 2 * N] = Z.T
    Pin[2 * m, 2 * N] = 1.0
    Pin[2 * m + 1, 2 * N + 1] = 1.0
    # contact force: M q̇ - h = X μ with q̇ = Z v̈, h = -C q - K u + e_s f
    Qd = Z @ A[m : 2 * m, :]
    H = -C @ Qout[N : 2 * N] - K @ Qout[:N]
    H[:, 2 * m] += e_s * sys_.f_cos
    H[:, 2 * m + 1] += e_s * sys_.f_sin
    mu = X @ (M @ Qd - H) / (X @ X)
    return A, Pin, Qout, mu


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


def _eig(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    lam, V = np.linalg.eig(A)
    # unit columns keep cond(V) meaningful
    V = V / np.linalg.norm(V, axis=0)
    Vi = np.linalg.inv(V)
    return lam.astype(complex), V.astype(complex), Vi, float(np.linalg.cond(V))


def prepare_event(sys_: System, n_grid: int) -> EventArrays:
    """Diagonalise the three regimes and build the step maps and observable rows."""
    N = sys_.ndof
    nzm = 2 * N + 2
    T = 2.0 * math.pi / sys_.params.gamma_r
    h = T / n_grid
    p = sys_.params
    bilateral = p.g1 + p.g2 <= 0.0
    full = _full_rows(sys_)
    A0 = free_matrix(sys_)
    mats = [(A0, None, None, None)]
    for w_star in (p.g1, -p.g2):
        mats.append(stuck_matrices(sys_, 0.0 if bilateral else w_star))
    nzr = np.array([nzm, nzm - 1, nzm - 1], dtype=np.int64)
    Phi = np.zeros((3, nzm, nzm))
    lam = np.zeros((3, nzm), dtype=complex)
    V = np.zeros((3, nzm, nzm), dtype=complex)
    Vi = np.zeros((3, nzm, nzm), dtype=complex)
    R = np.zeros((3, NROWS, nzm))
    RV = np.zeros((3, NROWS, nzm), dtype=complex)
    Pin = np.zeros((2, nzm - 1, nzm))
    Qout = np.zeros((2, nzm, nzm - 1))
    cond = 0.0
    for r, (A, Pr, Qr, mu) in enumerate(mats):
        nz = A.shape[0]
        lr, Vr, Vir, cr = _eig(A)
        cond = max(cond, cr)
        lam[r, :nz] = lr
        V[r, :nz, :nz] = Vr
        Vi[r, :nz, :nz] = Vir
        Phi[r, :nz, :nz] = ((Vr * np.exp(lr * h)) @ Vir).real
        A4 = np.linalg.matrix_power(A, 4)
        if r == 0:
            R[0, :6] = full
            R[0, R_W4] = full[R_W] @ A4
        else:
            R[r, :6, :nz] = full @ Qr
            R[r, R_MU, :nz] = mu
            R[r, R_MUD, :nz] = mu @ A
            R[r, R_MU4, :nz] = mu @ A4
            Pin[r - 1] = Pr
            Qout[r - 1, :, :] = Qr
        RV[r, :, :nz] = R[r, :, :nz] @ Vr
    eh = np.exp(lam * h)
    return EventArrays(nzr, Phi, eh, lam, V, Vi, R, RV, Pin, Qout, cond)


# --------------------------------------------------------------------------- driver


def _check_tol(event_tol: float) -> float:
    if (
        isinstance(event_tol, bool)
        or not isinstance(event_tol, (int, float))
        or not 0.0 < event_tol < 1e-2
    ):
        raise ValueError(f"event_tol must be in (0, 0.01), got {event_tol!r}")
    return float(event_tol)


def simulate_event(
    params: CellParams,
    settings=None,
    *,
    history_periods: int = 0,
    initial_state: np.ndarray | None = None,
    forcing: bool = True,
    event_tol: float = DEFAULT_EVENT_TOL,
    max_events_per_period: int = DEFAULT_MAX_EVENTS_PER_PERIOD,
):
    """Simulate one point with the event-driven solver; same ``PointResult`` as other methods.

    Parameters
    ----------
    params : CellParams
        The cell and excitation.
    settings : SolverSettings, optional
        ``steps_per_period`` is the sub-grid (default 64 intervals per period);
        ``near_margin`` the margin of the cheap no-event test; ``max_periods``,
        ``periodicity_tol``, ``window``, ``early_stop`` as for the other methods;
        ``coarse_steps`` and ``adaptive`` are not used. ``method`` is reported as ``"event"``.
    history_periods : int
        Keep the history of the last this-many periods: samples at every sub-grid point and at
        every event (τ non-decreasing; an impact gives a pre- and a post-impact sample). Extra
        keys: ``kind`` (0 sample, 1/2 impact on stop 1/2, 3/4 release from stop 1/2) and
        ``events`` (rows τ, kind 1 impact / 2 release, stop, residual, impulse; residual is the
        gap over the clearance at an impact, the contact force over its scale at a release).
    initial_state : ndarray, optional
        ``[u; q]`` at τ = 0 (default rest).
    forcing : bool
        Switch the base excitation off.
    event_tol : float
        Event time tolerance relative to the period (Newton is stopped below it and polished
        once more, so the gap at an impact is at round-off level).
    max_events_per_period : int
        Event budget of one period; a run that exceeds it (chattering) ends as ``failed``.
    """
    from worker import kernels as K
    from worker import simulate as S

    settings = settings or S.SolverSettings(method="event")
    event_tol = _check_tol(event_tol)
    max_events_per_period = S._int_in("max_events_per_period", max_events_per_period, 1, 10**9)
    history_periods = S._int_in("history_periods", history_periods, 0, 100_000)
    sys_ = assemble(params)
    N = sys_.ndof
    nx = 2 * N
    n_grid = settings.steps_per_period or DEFAULT_EVENT_GRID
    ea = prepare_event(sys_, n_grid)
    f_scale = 1.0 if forcing else 0.0
    y = np.zeros(nx + 2)
    if initial_state is not None:
        x0 = np.asarray(initial_state, dtype=float)
        if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial_state must be {nx} finite numbers, got shape {x0.shape}")
        y[:nx] = x0
    y[nx] = f_scale
    cap = history_periods * (n_grid + 64)
    hist = np.zeros((cap, EH_COLS))
    xh = np.zeros((cap, nx))
    evlog = np.zeros((cap, EV_COLS))
    out = np.zeros(E_SIZE)
    ring = np.zeros((RING, nx))
    p = params
    if ea.cond > MAX_COND:
        wall = 0.0
        out[E_FAILED] = 4.0
    else:
        t0 = time.perf_counter()
        event_kernel(
            y, ea.nzr, ea.Phi, ea.eh, ea.lam, ea.V, ea.Vi, ea.R, ea.RV, ea.Pin, ea.Qout, sys_.W,
            np.ascontiguousarray(sys_.Minv @ sys_.X), sys_.G, p.g1, p.g2, p.g1 + p.g2 <= 0.0,
            N, n_grid, p.gamma_r, f_scale, sys_.kappa, p.theta, settings.max_periods,
            settings.periodicity_tol, settings.window, settings.near_margin,
            settings.early_stop, 1e-3, event_tol, max_events_per_period,
            hist, xh, evlog, out, ring,
        )  # fmt: skip
        wall = time.perf_counter() - t0
    # the other methods' record layout, so the PointResult is built by the same code
    ko = np.zeros(K.OUT_SIZE)
    names = {
        "S_MAX": E_S_MAX, "S_MIN": E_S_MIN, "S_RE": E_S_RE, "S_IM": E_S_IM, "SB_RE": E_SB_RE,
        "SB_IM": E_SB_IM, "THETA_MEAN_SUM": E_THETA_SUM, "THETA_MEAN_T": E_THETA_T,
        "IMPACTS1": E_IMP1, "IMPACTS2": E_IMP2, "PEAK_IMPULSE": E_PEAK,
        "MEASURED_PERIODS": E_MEASURED, "PERIODS": E_PERIODS, "STEPS": E_PIECES,
        "CONTACT_STEPS": E_IMPACTS, "RESPONSE_PERIOD": E_RESPONSE_PERIOD,
        "CONVERGED": E_CONVERGED, "FAIL_PERIOD": E_FAIL_PERIOD, "COARSE_SKIPPED": E_QUICK,
        "SDOT_MAX": E_SDOT_MAX, "STEADY_PERIOD": E_STEADY,
    }  # fmt: skip
    for name, idx in names.items():
        ko[getattr(K, "O_" + name)] = out[idx]
    failed = int(out[E_FAILED])
    ko[K.O_FAILED] = 1.0 if failed else 0.0
    settings_out = (
        dataclasses.replace(settings, method="event") if settings.method != "event" else settings
    )
    res = S._result(ko, params, settings_out, sys_, wall, n_grid, np.zeros((0, K.H_COLS)),
                    np.zeros((0, nx)), 0)  # fmt: skip
    if failed == 3:
        res.reason = (
            f"event budget exceeded: more than {max_events_per_period} events in period "
            f"{int(out[E_FAIL_PERIOD])} (chattering)"
        )
    elif failed == 5:
        res.reason = (
            f"state diverged (|state| > {MAX_STATE:.0e}) in period {int(out[E_FAIL_PERIOD])}"
        )
    elif failed == 4:
        res.reason = (
            f"event solver: a regime's eigenvector matrix is too ill-conditioned "
            f"(cond {ea.cond:.3g} > {MAX_COND:.0e}; e.g. undamped resonance)"
        )
    if history_periods:
        res.history = _history(hist, xh, evlog, out, params, sys_)
    return res


def _ordered(arr: np.ndarray, count: int) -> np.ndarray:
    cap = arr.shape[0]
    if count > cap:
        return arr[np.r_[count % cap : cap, 0 : count % cap]]
    return arr[:count]


def _history(hist, xh, evlog, out, params, sys_) -> dict[str, np.ndarray]:
    from worker.observables import theta_eff_instantaneous

    count = int(out[E_HIST_COUNT])
    h = _ordered(hist, count)
    x = _ordered(xh, count)
    sdot = h[:, EH_SD]
    sbdot = h[:, EH_SBD]
    return {
        "tau": h[:, EH_TAU],
        "s": h[:, EH_S],
        "w_tip": h[:, EH_W],
        "s_b": h[:, EH_SB],
        "s_dot": sdot,
        "s_b_dot": sbdot,
        "theta_eff": theta_eff_instantaneous(sdot, sbdot, sys_.kappa, params.theta),
        "impulse1": h[:, EH_L1],
        "impulse2": h[:, EH_L2],
        "state": x,
        "kind": h[:, EH_KIND].astype(int),
        "events": _ordered(evlog, int(out[E_EVLOG_COUNT])),
    }


__all__ = [
    "DEFAULT_EVENT_GRID",
    "DEFAULT_EVENT_TOL",
    "DEFAULT_MAX_EVENTS_PER_PERIOD",
    "EventArrays",
    "free_matrix",
    "prepare_event",
    "simulate_event",
    "stuck_matrices",
]
