"""Roots and extrema of real sums of exponentials, ``f(t) = off + Re Σ_k c_k e^{λ_k t}``.

Within one regime every observable of the event solver (a gap, a contact force, ``ṡ``) is such
a sum, so events are its roots. The search is rigorous: a piece ``[lo, hi]`` is clear when the
minimum of the cubic Hermite interpolant of ``(f, ḟ)`` from both ends, minus the bound
``len⁴/384 · Σ|c_k||λ_k|⁴ max e^{Re λ_k t}`` of its interpolation error, stays positive;
otherwise it is split in four, leftmost first, so the first root is the one found. A sign
change on a short piece is refined by safeguarded Newton; a tangential touch (grazing) is
found as the exact minimum of a tiny piece.

The sums passed in may be *reduced*: one member of each complex-conjugate pair of ``λ``, with
its coefficient doubled (``Re(c e^{λt} + c̄ e^{λ̄t}) = Re(2c e^{λt})``), which halves the work
and changes nothing above (each bound term is ``|2c|``, the pair's true bound).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.solvers.measure import cubic_above, cubic_minmax

STACK = 160  # pieces the search may hold (depth ~ 4 per level)
# lo, hi, f and ḟ at both ends, the slow modes' f and ḟ at both ends, the row of the split
# table (``split_table``) that holds e^{λ·hi} (-1: none), the piece's place in the first two
# splits of an aligned search (0: the whole interval, 1-4: its quarters, -1: elsewhere)
STACK_COLS = 12
SPLITS = 15  # inner points of the first two splits of a search on [0, h]: 3 + 4·3
STIFF = 20.0  # |λ|·length beyond which a mode counts as stiff over a search interval


@njit(cache=True, nogil=True)
def cexp(z):
    """e^z of a finite z: ``cmath.exp`` without its branches for infinite and NaN parts (the
    same value; the search never sees those, the kernel ends a run on a non-finite state).

    Every regime has a mode on the imaginary axis (the forcing oscillator, λ = iγ) and a stuck
    one a mode at λ = 0: there the exponential or the sine and cosine (~25 % and ~75 % of the
    cost) are skipped. Bit for bit the same value: e^{±0} = 1, cos(±0) = 1 and
    sin(±0)·r = r·(±0)."""
    if z.real == 0.0:
        return complex(math.cos(z.imag), math.sin(z.imag))
    r = math.exp(z.real)
    if z.imag == 0.0:
        return complex(r, r * z.imag)
    return complex(r * math.cos(z.imag), r * math.sin(z.imag))


@njit(cache=True, nogil=True)
def cabs(z):
    """|z| by the plain square root where its squares neither overflow nor underflow (hypot's
    scaling is several times slower), within an ulp of ``abs(z)``."""
    x = abs(z.real)
    y = abs(z.imag)
    m = max(x, y)
    if 1e-150 < m < 1e150:
        return math.sqrt(x * x + y * y)
    return math.hypot(x, y)


@njit(cache=True, nogil=True)
def ev(c, lam, nz, off, t):
    """f(t) and ḟ(t)."""
    f = off
    d = 0.0
    for k in range(nz):
        e = c[k] * cexp(lam[k] * t)
        f += e.real
        d += (e * lam[k]).real
    return f, d


@njit(cache=True, nogil=True)
def _ev_at(c, lam, E, nz, off):
    """:func:`ev` at the t whose ``E = e^{λt}`` is given: the same f and ḟ bit for bit."""
    f = off
    d = 0.0
    for k in range(nz):
        e = c[k] * E[k]
        f += e.real
        d += (e * lam[k]).real
    return f, d


@njit(cache=True, nogil=True)
def ev3(c, lam, nz, off, t):
    """f(t), ḟ(t) and f̈(t)."""
    f = off
    d = 0.0
    dd = 0.0
    for k in range(nz):
        e = c[k] * cexp(lam[k] * t)
        el = e * lam[k]
        f += e.real
        d += el.real
        dd += (el * lam[k]).real
    return f, d, dd


@njit(cache=True, nogil=True)
def bound4(w4, lam, nz, lo, hi):
    """Rigorous bound of the cubic Hermite interpolation error of f on [lo, hi];
    ``w4[k] = |c_k| |λ_k|⁴`` (from :func:`bound_weights`)."""
    acc = 0.0
    for k in range(nz):
        r = lam[k].real
        acc += w4[k] * (1.0 if r <= 0.0 and lo >= 0.0 else math.exp(max(r * lo, r * hi)))
    ln = hi - lo
    return acc * ln * ln * ln * ln / 384.0


@njit(cache=True, nogil=True)
def bound_weights(c, lam, nz, w4):
    """w4[k] = |c_k| |λ_k|⁴, the weights of :func:`bound4`."""
    for k in range(nz):
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        w4[k] = cabs(c[k]) * m2 * m2


@njit(cache=True, nogil=True)
def refine(c, lam, nz, off, lo, hi, flo, fhi, tol_t):
    """Root of f in [lo, hi] with f(lo) > 0 >= f(hi): Halley's iteration (the second derivative
    costs no exponential more than the first), safeguarded by the bracket, until a step is
    within ``tol_t``. Its convergence is cubic, so that last step leaves an error far below
    tol_t and needs no evaluation after it (Newton needed one more: ~4 evaluations a root,
    now ~3)."""
    if fhi == 0.0:
        return hi
    a = lo
    b = hi
    t = lo + (hi - lo) * flo / (flo - fhi)  # regula falsi start
    if not (a < t < b):
        t = 0.5 * (a + b)
    for _ in range(200):
        f, d, dd = ev3(c, lam, nz, off, t)
        if f > 0.0:
            a = t
        else:
            b = t
        if f == 0.0:
            return t
        tn = -1.0
        den = 2.0 * d * d - f * dd
        if den != 0.0:
            tn = t - 2.0 * f * d / den
        if not (a < tn < b) and d != 0.0:
            tn = t - f / d
        if not (a < tn < b):
            tn = 0.5 * (a + b)
        step = abs(tn - t)
        t = tn
        if step <= tol_t or b - a <= 4e-16 * max(abs(a), abs(b)):
            return t
    return t


@njit(cache=True, nogil=True)
def crit(c, lam, nz, lo, hi, dlo, dhi, guess):
    """A critical point (ḟ = 0) in [lo, hi]; Newton safeguarded by the bracket if there is one."""
    if dlo * dhi > 0.0:
        return guess
    a = lo
    b = hi
    up = dlo < 0.0  # ḟ increasing through zero: a minimum
    t = guess if lo < guess < hi else 0.5 * (lo + hi)
    for _ in range(100):
        _, d, dd = ev3(c, lam, nz, 0.0, t)
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


@njit(cache=True, nogil=True)
def first_root(c, lam, nz, off, t0, t1, tol_t, stack, w4):
    """First t in [t0, t1] where f reaches zero, or -1 if f > 0 throughout (proven).

    ``stack`` (STACK × STACK_COLS) and ``w4`` (>= nz) are scratch arrays. Where some mode
    turns through several cycles over the interval (stiff high modes: its λ⁴ makes the
    Hermite error bound useless), the search bounds those modes by their size instead."""
    if _stiff(c, lam, nz, t1 - t0):
        cut2 = (4.43 / (t1 - t0)) ** 2
        f0, d0, fs0, ds0 = _ev_split(c, lam, nz, off, t0, cut2)
        if f0 <= 0.0:
            return t0
        f1, d1, fs1, ds1 = _ev_split(c, lam, nz, off, t1, cut2)
        return _first_root_split(c, lam, nz, off, t0, t1, tol_t, stack, w4, f0, d0, fs0, ds0,
                                 f1, d1, fs1, ds1)  # fmt: skip
    f0, d0 = ev(c, lam, nz, off, t0)
    if f0 <= 0.0:
        return t0
    f1, d1 = ev(c, lam, nz, off, t1)
    return _first_root_plain(c, lam, nz, off, t0, t1, tol_t, stack, w4, f0, d0, f1, d1)


@njit(cache=True, nogil=True)
def first_root_end(c, lam, E, nz, off, t0, t1, tol_t, stack, w4):
    """:func:`first_root` on [t0, t1] with ``E = e^{λ·t1}`` given (the same values as
    ``cexp(λ·t1)``): the end t1 costs no exponentials, the same f and ḟ bit for bit."""
    total = t1 - t0
    if _stiff(c, lam, nz, total):
        cut2 = (4.43 / total) ** 2
        f0, d0, fs0, ds0 = _ev_split(c, lam, nz, off, t0, cut2)
        if f0 <= 0.0:
            return t0
        f1 = fs1 = off
        d1 = ds1 = 0.0
        for k in range(nz):  # as _ev_split at t1
            e = c[k] * E[k]
            er = e.real
            dr = (e * lam[k]).real
            f1 += er
            d1 += dr
            if lam[k].real * lam[k].real + lam[k].imag * lam[k].imag <= cut2:
                fs1 += er
                ds1 += dr
        return _first_root_split(c, lam, nz, off, t0, t1, tol_t, stack, w4, f0, d0, fs0, ds0,
                                 f1, d1, fs1, ds1)  # fmt: skip
    f0, d0 = ev(c, lam, nz, off, t0)
    if f0 <= 0.0:
        return t0
    f1, d1 = _ev_at(c, lam, E, nz, off)
    return _first_root_plain(c, lam, nz, off, t0, t1, tol_t, stack, w4, f0, d0, f1, d1)


@njit(cache=True, nogil=True)
def first_root_whole(c, lam, E, nz, off, ln, tol_t, stack, w4, P=None):
    """:func:`first_root` on [0, ln] with ``E = e^{λ·ln}`` given: the ends cost no
    exponentials. ``P``, when given, is ``split_table``'s rows for ln (a whole sub-grid
    interval): the inner points of the first two splits cost none either (the same f and ḟ,
    so the same root, bit for bit)."""
    stiff = _stiff(c, lam, nz, ln)
    cut2 = (4.43 / ln) ** 2 if stiff else math.inf
    f0 = fs0 = f1 = fs1 = off
    d0 = ds0 = d1 = ds1 = 0.0
    for k in range(nz):  # as _ev_split at 0 and at ln
        cl = c[k] * lam[k]
        e = c[k] * E[k]
        f0 += c[k].real
        d0 += cl.real
        er = e.real
        dr = (e * lam[k]).real
        f1 += er
        d1 += dr
        if lam[k].real * lam[k].real + lam[k].imag * lam[k].imag <= cut2:
            fs0 += c[k].real
            ds0 += cl.real
            fs1 += er
            ds1 += dr
    if f0 <= 0.0:
        return 0.0
    if stiff:
        return _first_root_split(c, lam, nz, off, 0.0, ln, tol_t, stack, w4, f0, d0, fs0, ds0,
                                 f1, d1, fs1, ds1)  # fmt: skip
    return _first_root_plain(c, lam, nz, off, 0.0, ln, tol_t, stack, w4, f0, d0, f1, d1, P)


@njit(cache=True, nogil=True)
def _stiff(c, lam, nz, total):
    """Whether some mode of the sum turns through more than ~3 cycles over ``total``."""
    for k in range(nz):
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        if m2 * total * total > STIFF * STIFF and c[k] != 0:
            return True
    return False


@njit(cache=True, nogil=True)
def _push_quarters(stack, sp, lo, hi, ln, flo, dlo, fhi, dhi):
    """Push ``[lo, hi]`` (``ln = hi - lo``; row ``sp``, the piece just taken off) split in
    four, right to left so the leftmost piece is examined first; returns the new stack top. The
    inner points are left NaN, each evaluated when the piece ending there is examined (and
    passed to the next piece): a search that stops at a root never evaluates the points right
    of it. Each piece also gets its split-table row and place (``STACK_COLS``)."""
    place = stack[sp, 11]
    for i in range(3, -1, -1):
        if place == 0.0:  # a quarter of the whole interval
            stack[sp, 10] = i if i < 3 else -1.0
            stack[sp, 11] = 1.0 + i
        elif place >= 1.0:  # a sixteenth
            stack[sp, 10] = 3.0 + 3.0 * (place - 1.0) + i if i < 3 else -1.0
            stack[sp, 11] = -1.0
        else:
            stack[sp, 10] = -1.0
            stack[sp, 11] = -1.0
        stack[sp, 0] = lo + ln * i / 4.0
        stack[sp, 1] = lo + ln * (i + 1) / 4.0 if i < 3 else hi
        stack[sp, 2] = flo if i == 0 else math.nan
        stack[sp, 3] = dlo if i == 0 else math.nan
        stack[sp, 4] = fhi if i == 3 else math.nan
        stack[sp, 5] = dhi if i == 3 else math.nan
        sp += 1
    return sp


@njit(cache=True, nogil=True)
def split_points(h, out):
    """The ``SPLITS`` inner points of the first two splits of a search on [0, h], in the rows
    :func:`_push_quarters` gives them, computed by it: the very numbers a search evaluates."""
    st = np.empty((8, STACK_COLS))
    st[0, 11] = 0.0  # the whole interval
    _push_quarters(st, 0, 0.0, h, h - 0.0, math.nan, math.nan, math.nan, math.nan)
    for i in range(4):  # quarter i is in row 3 - i
        q = 3 - i
        if i < 3:
            out[int(st[q, 10])] = st[q, 1]
        st[4, 11] = st[q, 11]
        lo = st[q, 0]
        hi = st[q, 1]
        _push_quarters(st, 4, lo, hi, hi - lo, math.nan, math.nan, math.nan, math.nan)
        for j in range(3):
            out[int(st[7 - j, 10])] = st[7 - j, 1]


@njit(cache=True, nogil=True)
def split_table(lam, nk, h, out):
    """``out[r, j, k] = e^{λ_rk t_j}`` at the ``split_points`` t_j of [0, h], for every
    regime r: what a search on a whole sub-grid interval would evaluate there (``cexp`` of
    the same product)."""
    pts = np.empty(SPLITS)
    split_points(h, pts)
    for r in range(lam.shape[0]):
        for j in range(SPLITS):
            for k in range(nk[r]):
                out[r, j, k] = cexp(lam[r, k] * pts[j])


@njit(cache=True, nogil=True)
def _first_root_plain(c, lam, nz, off, t0, t1, tol_t, stack, w4, f0, d0, f1, d1, P=None):
    """:func:`first_root` with the Hermite cubic of the whole sum and its error bound (f and
    ḟ at both ends given, f(t0) > 0). ``P``: ``split_table`` rows for [t0, t1] = [0, h]."""
    bound_weights(c, lam, nz, w4)
    total = t1 - t0
    tiny = 1e-9 * total
    _first_piece(stack, t0, t1, f0, d0, f1, d1)
    stack[0, 10] = -1.0
    stack[0, 11] = -1.0 if P is None else 0.0
    sp = 1
    while sp > 0:
        sp -= 1
        lo, hi, flo, dlo, fhi, dhi = _piece(stack, sp)
        if flo <= 0.0:
            return lo
        if math.isnan(fhi):  # an inner point of a split: evaluated now, for both its pieces
            if P is None:
                fhi, dhi = ev(c, lam, nz, off, hi)
            else:
                row = int(stack[sp, 10])
                if row >= 0:
                    fhi, dhi = _ev_at(c, lam, P[row], nz, off)
                else:
                    fhi, dhi = ev(c, lam, nz, off, hi)
            if sp > 0:
                stack[sp - 1, 2] = fhi
                stack[sp - 1, 3] = dhi
        ln = hi - lo
        if fhi <= 0.0:
            # sign change; a long piece may hide an earlier touch, so look closer first
            if ln <= 0.0625 * total or sp >= STACK - 5:
                return refine(c, lam, nz, off, lo, hi, flo, fhi, tol_t)
        else:
            if cubic_above(flo, dlo, fhi, dhi, ln, bound4(w4, lam, nz, lo, hi), 0.0):
                continue
            if ln <= tiny or sp >= STACK - 5:
                t = _touch(c, lam, nz, off, lo, hi, flo, dlo, fhi, dhi, ln, tol_t)
                if t >= 0.0:
                    return t
                continue
        sp = _push_quarters(stack, sp, lo, hi, ln, flo, dlo, fhi, dhi)
    return -1.0


@njit(cache=True, nogil=True)
def _first_piece(stack, t0, t1, f0, d0, f1, d1):
    """The search's first piece, [t0, t1] with f and ḟ at both ends, in the stack's row 0."""
    stack[0, 0] = t0
    stack[0, 1] = t1
    stack[0, 2] = f0
    stack[0, 3] = d0
    stack[0, 4] = f1
    stack[0, 5] = d1


@njit(cache=True, nogil=True, inline="always")  # the search's innermost loop
def _piece(stack, sp):
    """The piece in the stack's row ``sp``: lo, hi, and f and ḟ at both ends (f(hi) NaN: an
    inner point of a split, not evaluated yet)."""
    return stack[sp, 0], stack[sp, 1], stack[sp, 2], stack[sp, 3], stack[sp, 4], stack[sp, 5]


@njit(cache=True, nogil=True)
def _touch(c, lam, nz, off, lo, hi, flo, dlo, fhi, dhi, ln, tol_t):
    """The root on a piece too short to split (or with the stack full), positive at both ends:
    where f's minimum there (from the Hermite cubic's, refined) is not above zero, the first
    root before it; else -1 (a piece clear of zero)."""
    tmin = cubic_minmax(flo, dlo, fhi, dhi, ln)[1]
    tc = crit(c, lam, nz, lo, hi, dlo, dhi, lo + tmin)
    fc, _ = ev(c, lam, nz, off, tc)
    if fc <= 0.0:
        return refine(c, lam, nz, off, lo, tc, flo, fc, tol_t)
    return -1.0


@njit(cache=True, nogil=True)
def _ev_split(c, lam, nz, off, t, cut2):
    """f, ḟ and the same over the slow modes only (|λ|² <= cut2)."""
    f = off
    d = 0.0
    fs = off
    ds = 0.0
    for k in range(nz):
        e = c[k] * cexp(lam[k] * t)
        er = e.real
        dr = (e * lam[k]).real
        f += er
        d += dr
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        if m2 <= cut2:
            fs += er
            ds += dr
    return f, d, fs, ds


@njit(cache=True, nogil=True)
def _decayed_clear(c, lam, nz, w4, lo, hi, ln, l4, slow, flo, dlo, fhi, dhi, sf0, sd0, sf1, sd1):
    """The two tests of :func:`_first_root_split` again, with the fast modes' bounds taken
    where the piece starts (``|c e^{λt}| <= |c| e^{Re λ·lo}`` on [lo, hi] for Re λ <= 0)
    rather than at t = 0. Tried only after both fail: one exponential per fast mode. A stiff,
    damped mode excited by an impact has decayed long before most of the interval, yet its
    size at t = 0 and its |λ|⁴ kept every later piece from being cleared, so the search split
    down to tiny pieces (hundreds of µs an event with 17 modes)."""
    fast4 = 0.0
    fast = 0.0
    for k in range(nz):
        if w4[k] < 0.0:  # a fast mode (marked by the caller)
            r = lam[k].real
            g = math.exp(r * lo) if r <= 0.0 else math.exp(r * hi)
            fast4 -= w4[k] * g
            fast += cabs(c[k]) * g
    if cubic_above(flo, dlo, fhi, dhi, ln, (slow + fast4) * l4, 0.0):
        return True
    return cubic_above(sf0, sd0, sf1, sd1, ln, slow * l4, fast)


@njit(cache=True, nogil=True)
def _first_root_split(c, lam, nz, off, t0, t1, tol_t, stack, w4, f0, d0, fs0, ds0, f1, d1, fs1,
                      ds1):  # fmt: skip
    """:func:`first_root` where a piece may also be proven clear by the Hermite cubic of the
    slow modes minus its error bound and minus the fast modes' size (Σ_fast |c_k|, which does
    not shrink with the piece, but which their decay makes small once they are damped). f and
    ḟ at both ends are given, of the whole sum and of the slow modes (|λ| (t1 - t0) <= 4.43),
    with f(t0) > 0."""
    total = t1 - t0
    cut2 = (4.43 / total) ** 2
    bfast = 0.0
    for k in range(nz):
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        a = cabs(c[k])
        w4[k] = a * m2 * m2
        if m2 > cut2:
            r = lam[k].real
            bfast += a * (1.0 if r <= 0.0 else math.exp(r * total))
            w4[k] = -w4[k]  # marks a fast mode for the slow bound
    tiny = 1e-9 * total
    _first_piece(stack, t0, t1, f0, d0, f1, d1)
    stack[0, 6] = fs0
    stack[0, 7] = ds0
    stack[0, 8] = fs1
    stack[0, 9] = ds1
    stack[0, 11] = -1.0  # no split table
    sp = 1
    while sp > 0:
        sp -= 1
        lo, hi, flo, dlo, fhi, dhi = _piece(stack, sp)
        if flo <= 0.0:
            return lo
        if math.isnan(fhi):  # as in _first_root_plain
            fhi, dhi, sfh, sdh = _ev_split(c, lam, nz, off, hi, cut2)
            stack[sp, 8] = sfh
            stack[sp, 9] = sdh
            if sp > 0:
                stack[sp - 1, 2] = fhi
                stack[sp - 1, 3] = dhi
                stack[sp - 1, 6] = sfh
                stack[sp - 1, 7] = sdh
        ln = hi - lo
        if fhi <= 0.0:
            if ln <= 0.0625 * total or sp >= STACK - 5:
                return refine(c, lam, nz, off, lo, hi, flo, fhi, tol_t)
        else:
            full = 0.0
            slow = 0.0
            for k in range(nz):
                r = lam[k].real
                g = 1.0 if r <= 0.0 and lo >= 0.0 else math.exp(max(r * lo, r * hi))
                full += abs(w4[k]) * g
                if w4[k] >= 0.0:
                    slow += w4[k] * g
            l4 = ln * ln * ln * ln / 384.0
            if cubic_above(flo, dlo, fhi, dhi, ln, full * l4, 0.0):
                continue
            if cubic_above(stack[sp, 6], stack[sp, 7], stack[sp, 8], stack[sp, 9], ln,
                           slow * l4, bfast):  # fmt: skip
                continue
            if lo > 0.0 and _decayed_clear(c, lam, nz, w4, lo, hi, ln, l4, slow, flo, dlo, fhi,
                                           dhi, stack[sp, 6], stack[sp, 7], stack[sp, 8],
                                           stack[sp, 9]):  # fmt: skip
                continue
            if ln <= tiny or sp >= STACK - 5:
                t = _touch(c, lam, nz, off, lo, hi, flo, dlo, fhi, dhi, ln, tol_t)
                if t >= 0.0:
                    return t
                continue
        lsf = stack[sp, 6]
        lsd = stack[sp, 7]
        hsf = stack[sp, 8]
        hsd = stack[sp, 9]
        top = _push_quarters(stack, sp, lo, hi, ln, flo, dlo, fhi, dhi)
        for i in range(4):  # the slow modes' values at the ends alike (piece i in row top-1-i)
            row = top - 1 - i
            stack[row, 6] = lsf if i == 0 else math.nan
            stack[row, 7] = lsd if i == 0 else math.nan
            stack[row, 8] = hsf if i == 3 else math.nan
            stack[row, 9] = hsd if i == 3 else math.nan
        sp = top
    return -1.0


@njit(cache=True, nogil=True)
def clear_sums(c, lam, E, nz, ln):
    """What :func:`clear_test` needs of the sum ``Re Σ c_k e^{λ_k t}`` on [0, ln], with
    ``E = e^{λ·ln}`` given (no exponentials evaluated but growing modes' size): its value and
    slope at both ends, of the whole sum and of its slow modes (|λ| ln <= 4.43), the error
    bound weights of both, and the size of the fast modes. Negating c negates the first eight
    and keeps the rest, so both stops of a gap share one call."""
    f0 = 0.0
    d0 = 0.0
    f1 = 0.0
    d1 = 0.0
    fs0 = 0.0
    ds0 = 0.0
    fs1 = 0.0
    ds1 = 0.0
    acc = 0.0
    acc_s = 0.0
    bfast = 0.0
    cut2 = (4.43 / ln) ** 2
    for k in range(nz):
        cl = c[k] * lam[k]
        ce = c[k] * E[k]
        a0 = c[k].real
        b0 = cl.real
        a1 = ce.real
        b1 = (cl * E[k]).real
        f0 += a0
        d0 += b0
        f1 += a1
        d1 += b1
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        grow = 1.0 if lam[k].real <= 0.0 else math.exp(lam[k].real * ln)
        w = cabs(c[k]) * grow
        acc += w * m2 * m2
        if m2 > cut2:
            bfast += w
        else:
            fs0 += a0
            ds0 += b0
            fs1 += a1
            ds1 += b1
            acc_s += w * m2 * m2
    return f0, d0, f1, d1, fs0, ds0, fs1, ds1, acc, acc_s, bfast


@njit(cache=True, nogil=True)
def clear_test(sums, off, sgn, ln):
    """True if ``off + sgn·Re Σ c_k e^{λ_k t} > 0`` on [0, ln] is proven from
    ``sums = clear_sums(c, …)``: by the Hermite cubic of the whole sum and its error bound, or
    by that of the slow modes with the fast modes bounded by their size."""
    f0, d0, f1, d1, fs0, ds0, fs1, ds1, acc, acc_s, bfast = sums
    f0 = off + sgn * f0
    f1 = off + sgn * f1
    if f0 <= 0.0 or f1 <= 0.0:
        return False
    l4 = ln * ln * ln * ln / 384.0
    if cubic_above(f0, sgn * d0, f1, sgn * d1, ln, acc * l4, 0.0):
        return True
    if bfast == 0.0:
        return False
    return cubic_above(off + sgn * fs0, sgn * ds0, off + sgn * fs1, sgn * ds1, ln, acc_s * l4,
                       bfast)  # fmt: skip


@njit(cache=True, nogil=True)
def clear_whole(c, lam, E, nz, off, ln):
    """True if f > 0 on [0, ln] is proven, with ``E = e^{λ·ln}`` given (no exponentials
    evaluated): by the Hermite cubic of the whole sum and its error bound, or by that of the
    slow modes with the fast modes (|λ| ln > 4.43) bounded by their size."""
    return clear_test(clear_sums(c, lam, E, nz, ln), off, 1.0, ln)


@njit(cache=True, nogil=True)
def skip_start(c, lam, nz, off, h, gap):
    """A t in (0, h] from which the search for f's next root may start after f left zero (a
    release, a departure from a stop), or -1.

    Roots in (0, t) are round-off, not events: f grows like t² or, where the contact force
    and so the second derivative vanish together (a release), like t³ from round-off. First,
    without an exponential: with the derivatives d0…d3 at 0 and B >= |f⁗| on [0, h], f is
    above P(t) = d0 + d1 t + d2 t²/2 + d3 t³/6 - B t⁴/24; P rises from where its leading term
    is clearly above the round-off level, ta, to a tb fixed by B, so f has no root in
    [ta, tb] and the search starts at tb (well clear of zero: a search starting near the
    round-off level cost ~10 evaluations a release). Where that does not hold, the smaller of
    ta and an eightfold sequence from h·8⁻¹³ at which f is clearly positive. Where f is a
    ``gap``, only once it is proven not to dip below -1e-9·scale before that
    (:func:`_above_until`), else -1: the gap closes first, a contact, not a departure. (A
    contact force may be below zero for a while: the stick it starts is taken where leaving
    the stop has failed, the gap opening no further than round-off.)"""
    scale = abs(off)
    d0 = off
    d1 = 0.0
    d2 = 0.0
    d3 = 0.0
    b4 = 0.0
    for k in range(nz):
        a = cabs(c[k])
        scale += a
        l1 = c[k] * lam[k]
        l2 = l1 * lam[k]
        d0 += c[k].real
        d1 += l1.real
        d2 += l2.real
        d3 += (l2 * lam[k]).real
        m2 = lam[k].real * lam[k].real + lam[k].imag * lam[k].imag
        grow = 1.0 if lam[k].real <= 0.0 else math.exp(lam[k].real * h)
        b4 += a * m2 * m2 * grow
    eps = 1e-12 * scale
    best = -1.0
    if d3 > 0.0:  # d1, d2 at round-off: P' >= d3 t²/4 - |d1| - |d2| t up to t = 1.5 d3/B
        ta = 2.0 * (6.0 * eps / d3) ** (1.0 / 3.0)
        tb = min(h, 1.5 * d3 / b4) if b4 > 0.0 else h
        if (ta < tb and 0.25 * d3 * ta * ta > abs(d1) + abs(d2) * tb
                and _taylor_low(d0, d1, d2, d3, b4, ta) > eps):  # fmt: skip
            best = tb
    if d2 > 0.0:  # P' >= d2 t/2 - |d1| while |d3| t/2 + B t²/6 <= d2/2
        ta = 2.0 * math.sqrt(2.0 * eps / d2)
        qa = b4 / 6.0
        qb = 0.5 * abs(d3)
        tb = h
        if qa > 0.0:
            tb = min(h, (math.sqrt(qb * qb + 2.0 * qa * d2) - qb) / (2.0 * qa))
        elif qb > 0.0:
            tb = min(h, 0.5 * d2 / qb)
        if (ta < tb and tb > best and 0.5 * d2 * ta > abs(d1)
                and _taylor_low(d0, d1, d2, d3, b4, ta) > eps):  # fmt: skip
            best = tb
    if best > 0.0:
        return best
    tmin = h * 8.0**-13
    # a gap this far below zero before it is clearly open is a contact (the test's bound on
    # what round-off may do)
    dip = 1e-9 * scale if gap else math.inf
    if d2 > 0.0:
        t = min(max(2.0 * math.sqrt(2.0 * eps / d2), tmin), h)
        f, _ = ev(c, lam, nz, off, t)
        if f > eps:
            return t if not gap or _above_until(c, lam, nz, off, dip, tmin, t) else -1.0
    t = tmin
    while t <= h * (1.0 + 1e-12):
        f, _ = ev(c, lam, nz, off, t)
        if f < -dip:
            return -1.0  # it closes first: a contact, not a departure
        if f > eps:
            return t if not gap or _above_until(c, lam, nz, off, dip, tmin, t) else -1.0
        t *= 8.0
    return -1.0


@njit(cache=True, nogil=True)
def _above_until(c, lam, nz, off, dip, t0, t1):
    """Whether f > -dip on all of [t0, t1] (proven by :func:`first_root`): a sampled value
    above zero says nothing of a dip between the samples, which would be a real contact
    that the search, starting at t1, never saw."""
    stack = np.empty((STACK, STACK_COLS))
    w4 = np.empty(nz)
    return first_root(c, lam, nz, off + dip, t0, t1, 1e-9 * (t1 - t0), stack, w4) < 0.0


@njit(cache=True, nogil=True)
def _taylor_low(d0, d1, d2, d3, b4, t):
    """The lower bound d0 + d1 t + d2 t²/2 + d3 t³/6 - B t⁴/24 of f(t) (:func:`skip_start`)."""
    return d0 + t * (d1 + t * (0.5 * d2 + t * (d3 / 6.0 - b4 * t / 24.0)))


@njit(cache=True, nogil=True)
def phi1(x, ln):
    """(e^{x·ln} - 1)/x, stable for small x·ln."""
    z = x * ln
    if z.real * z.real + z.imag * z.imag < 1e-6:  # |z| < 1e-3 without a hypot
        return ln * (1.0 + z / 2.0 * (1.0 + z / 3.0 * (1.0 + z / 4.0 * (1.0 + z / 5.0))))
    return (cexp(z) - 1.0) / x
