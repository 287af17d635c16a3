"""One measurement layout for every method, and the rules applied at the end of each period.

Every kernel (``euler``, ``exponential``, ``event``) advances whole excitation periods and, for
each period ``k`` of a batch, fills one row ``rows[k]`` of the layout below and one
stroboscopic sample ``samples[k]`` (the state ``[u; q]`` at the period's end, forcing phase 0).
What a point reports is computed from these rows by the point engine (``engine.py``), the same
code for every method.

At the end of each period a kernel calls :func:`period_end`, which applies the checks that may
end a batch early: a state that is not finite or has diverged, a linear tail proven impact-free
(``linear_tail_bound``), a stroboscopic sequence that repeats (``periodicity``), or one that
converges geometrically to a repeating state (``candidate``: the engine then extrapolates).

Kernels are ``@njit(**KERNEL_JIT)``, their helpers ``@njit(cache=True, nogil=True)``; nothing
here allocates.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.core.cpu import CPUTargetOptions

#: numba options of the period kernels (``event_kernel``, ``euler_kernel``,
#: ``exponential_kernel``). Without the runtime's reference counting (the private option
#: ``_nrt``, which the helpers they call are compiled with too, where this numba has it): the
#: kernels allocate nothing, and the atomic updates of their arrays' counts at every helper's
#: entry and exits took ~20 % of an impacting period of ``event``. Every method gets it, so the
#: paper's scheme is measured as fast as it can be too.
KERNEL_JIT: dict[str, bool] = dict(cache=True, nogil=True)
if hasattr(CPUTargetOptions, "_nrt"):
    KERNEL_JIT["_nrt"] = False

# --------------------------------------------------------------------------- the row layout

M_SMAX = 0  # largest s in the period (refined between samples)
M_SMIN = 1  # smallest s
M_S_RE = 2  # ∫ s e^{-iγ(τ - τ_k)} dτ over the period (τ_k its start): real part
M_S_IM = 3
M_SB_RE = 4  # the same for s_b
M_SB_IM = 5
M_VV = 6  # ∫ ṡ² dτ (the velocity phase portrait: theta_eff_slope, θ_ps)
M_VB = 7  # ∫ ṡ_b ṡ dτ
M_IMP1 = 8  # contact episodes begun at stop 1 in the period
M_IMP2 = 9  # … at stop 2
M_PEAK = 10  # largest contact impulse
M_STEPS = 11  # steps (event: pieces) taken
M_CONTACT = 12  # steps that needed a contact solve (event: impacts)
M_COARSE = 13  # free-flight steps taken whole (event: intervals cleared by the cheap test)
M_LAST_IMPACT = 14  # phase (0…1) of the period's last impact, -1 if none
M_REGIME = 15  # contact state at the period's end: 0 free, 1/2 on stop 1/2
M_XNORM = 16  # |x|∞ at the period's end
M_TAIL = 17  # bound of |w_tip| over all later time (linear tail test), -1 if not evaluated
M_MEASURED = 18  # 1 if harmonics and the phase-portrait integrals were accumulated
M_CT1 = 19  # time on stop 1 in the period (event: stuck; time stepping: steps held by impulses)
M_CT2 = 20  # … on stop 2
M_VIMP1 = 21  # sum of the tip's approach velocities of the impacts counted at stop 1
M_VIMP2 = 22  # … at stop 2
M_EN1 = 23  # energy the impulses at stop 1 took in the period: Σ ½(v⁻² − v⁺²)/G
M_EN2 = 24  # … at stop 2
ROW = 25

# --------------------------------------------------------------------------- kernel state

# Entries of ``kst``, the small float array a kernel keeps between batches.
K_PERIOD = 0  # periods done since the start
K_RING = 1  # stroboscopic samples stored in the ring
K_NEXT_TRY = 2  # first period at which a convergence candidate may be signalled again
K_CONTACT = 3  # contact episode in progress: 0 none, 1/2 at stop 1/2
K_HIST = 4  # history rows written
K_NEXT_QUIET = 5  # first period at which a quiet period may be signalled again
K_IMPACTED = 6  # 1 if a period had impacts since the last quiet signal (or the start)
K_METHOD = 7  # first entry a method may use for its own state
KST_SIZE = 18

# --------------------------------------------------------------------------- period-end codes

END_NONE = 0  # the batch ran all its periods
END_NONFINITE = 1  # the state stopped being finite
END_DIVERGED = 2  # |x|∞ exceeded the divergence limit
END_LINEAR = 3  # the linear tail test proved that no stop is ever reached again
END_PERIODIC = 4  # the stroboscopic sequence repeats with period p
END_CANDIDATE = 5  # converging geometrically to a p-periodic state: worth extrapolating
END_QUIET = 8  # an impact-free period ending off the stops, after impacts since the last one
END_CHATTER = 6  # event: more events in a period than the budget
END_ILLCOND = 7  # event: a regime could not be propagated accurately

# Bit flags of which checks ``period_end`` applies.
CHECK_LINEAR = 1
CHECK_PERIODIC = 2
CHECK_CANDIDATE = 4
CHECK_QUIET = 8

# Longest response period looked for: an orbit that repeats (``periodicity``). Orbits of period
# 9, 10, 11 and 24 occur in the nightly suite and in Figure 5 (docs/solvers.md); a shorter
# search would leave them to the window statistics, as irregular with standard errors of 1e-8 dB.
MAX_PERIOD = 40
# Longest period whose geometric approach is extrapolated (``candidate``; ``engine._extrapolate``
# needs four p-spaced samples of the 64 it keeps).
MAX_CANDIDATE = 8
NOISE = 1e-12  # relative size of a state difference that is integration noise (event times)
RING = 2 * MAX_PERIOD + 1  # stroboscopic samples kept: periodicity looks 2p back
assert RING >= 3 * MAX_CANDIDATE + 1, "candidates look 3p back"
OPEN_FRAC = 1e-3  # a contact episode ends once the gap has opened to this fraction of it

# Gauss–Legendre nodes and weights on [0, 1] (4 points: exact for polynomials of degree 7), for
# the phase-portrait integrals of the time-stepping methods' steps.
GL_NODES = np.array([0.0694318442029737, 0.3300094782075719, 0.6699905217924281,
                     0.9305681557970263])  # fmt: skip
GL_WEIGHTS = np.array([0.1739274225687269, 0.3260725774312731, 0.3260725774312731,
                       0.1739274225687269])  # fmt: skip


@njit(cache=True, nogil=True)
def begin_row(rows, k):
    """Start the measurement row of a period."""
    for c in range(ROW):
        rows[k, c] = 0.0
    rows[k, M_SMAX] = -np.inf
    rows[k, M_SMIN] = np.inf
    rows[k, M_LAST_IMPACT] = -1.0
    rows[k, M_TAIL] = -1.0


@njit(cache=True, nogil=True)
def close_row(rows, k, smin, smax, h, vv, vb, imp1, imp2, peak, last, nsteps, ncontact, ncoarse,
              regime):  # fmt: skip
    """Write a period's measurements into its row: the range of ``s``, the first harmonics
    ``h`` (S_re, S_im, Sb_re, Sb_im), the phase-portrait integrals, impacts, the peak impulse,
    the last impact's phase, the work counts and the regime at the period's end. Kernels keep
    them in local variables during the period and store them once: stores to the rows inside
    the step loop would keep the compiler from holding the state in registers."""
    rows[k, M_SMIN] = smin
    rows[k, M_SMAX] = smax
    for j in range(4):
        rows[k, M_S_RE + j] = h[j]
    rows[k, M_VV] = vv
    rows[k, M_VB] = vb
    rows[k, M_IMP1] = imp1
    rows[k, M_IMP2] = imp2
    rows[k, M_PEAK] = peak
    rows[k, M_LAST_IMPACT] = last
    rows[k, M_STEPS] = nsteps
    rows[k, M_CONTACT] = ncontact
    rows[k, M_COARSE] = ncoarse
    rows[k, M_REGIME] = regime


@njit(cache=True, nogil=True)
def close_impacts(rows, k, ct1, ct2, vimp1, vimp2, en1, en2):
    """Write a period's time on each stop, the sums of its impacts' approach velocities and
    the energy its impulses took at each stop (after :func:`close_row`; a kernel that does not
    measure them leaves them 0)."""
    rows[k, M_CT1] = ct1
    rows[k, M_CT2] = ct2
    rows[k, M_VIMP1] = vimp1
    rows[k, M_VIMP2] = vimp2
    rows[k, M_EN1] = en1
    rows[k, M_EN2] = en2


@njit(cache=True, nogil=True, inline="always")
def dot(a, x, n):
    """Σ a[i] x[i] over the first n entries."""
    acc = 0.0
    for i in range(n):
        acc += a[i] * x[i]
    return acc


@njit(cache=True, nogil=True)
def cubic_minmax(f0, d0, f1, d1, ln):
    """(min, argmin, max, argmax) over [0, ln] of the cubic Hermite interpolant of (f, ḟ)."""
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
    # p(s) = a s³ + b s² + c s + f0 on s ∈ [0, 1], p'(0) = d0 ln, p'(1) = d1 ln
    c = d0 * ln
    a = 2.0 * f0 + c - 2.0 * f1 + d1 * ln
    b = 3.0 * (f1 - f0) - 2.0 * c - d1 * ln
    qa = 3.0 * a
    qb = 2.0 * b
    r0 = -1.0
    r1 = -1.0
    if abs(qa) < 1e-300:
        if abs(qb) > 1e-300:
            r0 = -c / qb
    else:
        disc = qb * qb - 4.0 * qa * c
        if disc >= 0.0:
            qq = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))  # the stable pair of roots
            r0 = qq / qa
            if qq != 0.0:
                r1 = c / qq
    for s in (r0, r1):
        if 0.0 < s < 1.0:
            p = ((a * s + b) * s + c) * s + f0
            if p < fmin:
                fmin = p
                tmin = s * ln
            if p > fmax:
                fmax = p
                tmax = s * ln
    return fmin, tmin, fmax, tmax


@njit(cache=True, nogil=True)
def hermite_hull(f0, d0, f1, d1, ln):
    """(lo, hi) enclosing :func:`cubic_minmax`'s min and max without its square root and
    divisions: the cubic is a convex combination of its Bernstein control points f0,
    f0 + d0·ln/3, f1 - d1·ln/3, f1, whose range, widened by 1e-13 of their size (more than the
    rounding of the cubic's value at its extrema), holds both. A test that the cubic stays on
    one side of a level that passes on the hull passes on the cubic too, so it may be tried
    first."""
    e0 = d0 * ln / 3.0
    e1 = d1 * ln / 3.0
    b1 = f0 + e0
    b2 = f1 - e1
    w = 1e-13 * (abs(f0) + abs(f1) + abs(e0) + abs(e1))
    return min(min(f0, f1), min(b1, b2)) - w, max(max(f0, f1), max(b1, b2)) + w


@njit(cache=True, nogil=True)
def cubic_above(f0, d0, f1, d1, ln, a, b):
    """Whether ``min - a - b > 0``, the minimum over [0, ln] of the cubic Hermite interpolant of
    (f, ḟ): on its :func:`hermite_hull` first, then by :func:`cubic_minmax` (the same decision;
    most tests that pass, pass on the hull, without a square root or a division)."""
    if hermite_hull(f0, d0, f1, d1, ln)[0] - a - b > 0.0:
        return True
    return cubic_minmax(f0, d0, f1, d1, ln)[0] - a - b > 0.0


@njit(cache=True, nogil=True)
def cubic_inside(f0, d0, f1, d1, ln, lo, hi, pad):
    """Whether the cubic Hermite interpolant of (f, ḟ) on [0, ln] stays ``pad`` inside
    (lo, hi): ``max + pad < hi`` and ``min - pad > lo``, on the hull first as
    :func:`cubic_above`."""
    m, mx = hermite_hull(f0, d0, f1, d1, ln)
    if mx + pad < hi and m - pad > lo:
        return True
    m, _, mx, _ = cubic_minmax(f0, d0, f1, d1, ln)
    return mx + pad < hi and m - pad > lo


@njit(cache=True, nogil=True, inline="always")
def add_extrema(rows, k, lo, hi):
    """Widen the period's range of s to [lo, hi]."""
    if hi > rows[k, M_SMAX]:
        rows[k, M_SMAX] = hi
    if lo < rows[k, M_SMIN]:
        rows[k, M_SMIN] = lo


@njit(cache=True, nogil=True, inline="always")
def add_impulses(rows, kst, k, l1, l2, phase):
    """Count contact episodes: one begins with an impulse at a stop not already in contact."""
    contact = kst[K_CONTACT]
    if l1 > 0.0 and contact != 1.0:
        rows[k, M_IMP1] += 1.0
        rows[k, M_LAST_IMPACT] = phase
    if l2 > 0.0 and contact != 2.0:
        rows[k, M_IMP2] += 1.0
        rows[k, M_LAST_IMPACT] = phase
    peak = max(l1, l2)
    if peak > rows[k, M_PEAK]:
        rows[k, M_PEAK] = peak
    if l1 > 0.0:
        kst[K_CONTACT] = 1.0
    elif l2 > 0.0:
        kst[K_CONTACT] = 2.0


@njit(cache=True, nogil=True, inline="always")
def release_if_open(kst, w, g1, g2):
    """End the contact episode once the tip has opened its stop's gap by ``OPEN_FRAC``, so a
    scheme's chatter at a release is not counted as new impacts."""
    c = kst[K_CONTACT]
    if (c == 1.0 and g1 - w > OPEN_FRAC * g1) or (c == 2.0 and g2 + w > OPEN_FRAC * g2):
        kst[K_CONTACT] = 0.0


@njit(cache=True, nogil=True)
def record(hist, xh, kst, tau, s, w, sb, v, vb, l1, l2, kind, x, nx):
    """Append one history sample to the ring buffer (no-op when no history is kept)."""
    cap = hist.shape[0]
    if cap == 0:
        return
    j = int(kst[K_HIST]) % cap
    hist[j, 0] = tau
    hist[j, 1] = s
    hist[j, 2] = w
    hist[j, 3] = sb
    hist[j, 4] = v
    hist[j, 5] = vb
    hist[j, 6] = l1
    hist[j, 7] = l2
    hist[j, 8] = kind
    for i in range(nx):
        xh[j, i] = x[i]
    kst[K_HIST] += 1.0


H_COLS = 9  # τ, s, w_tip, s_b, ṡ, ṡ_b, impulse 1, impulse 2, kind

#: The channels of a time history (``simulate_point(..., history_periods=n)``), described.
HISTORY_FIELDS = {
    "tau": "non-dimensional time tau since the start of the recorded stretch",
    "s": "displacement s of the outer mass",
    "w_tip": "beam tip deflection w_tip relative to the mass",
    "s_b": "mean beam deflection s_b (Eq. 34b)",
    "s_dot": "velocity of the outer mass",
    "s_b_dot": "rate of the mean beam deflection",
    "theta_eff": "instantaneous effective mass ratio (Eq. 36); missing where singular",
    "impulse1": "contact impulse at stop 1 in the step (event: over the piece)",
    "impulse2": "contact impulse at stop 2 in the step (event: over the piece)",
    "kind": "sample kind: 0 step or grid point, 1/2 impact at stop 1/2, 3/4 release from "
    "stop 1/2 (event method)",
}


# --------------------------------------------------------------------------- period end


@njit(cache=True, nogil=True)
def linear_tail_bound(x, nx, lin_L, lin_xp):
    """Σ_k |c_k|: a bound, for all later time, of the tip's deviation from the closed-form
    steady state, where ``c = lin_L (x - x_p)`` are the decaying modes' tip coefficients."""
    acc = 0.0
    for m in range(lin_L.shape[0]):
        z = 0j
        for j in range(nx):
            z += lin_L[m, j] * (x[j] - lin_xp[j])
        acc += abs(z)
    return acc


@njit(cache=True, nogil=True)
def _dist(ring, a, b, nx):
    d = 0.0
    for i in range(nx):
        d = max(d, abs(ring[a, i] - ring[b, i]))
    return d


@njit(cache=True, nogil=True)
def periodicity(ring, nring, period, x, tol, nx):
    """Smallest p in 1…MAX_PERIOD with x_k ≈ x_{k-p}, allowing for the remaining transient.

    ``d1 = |x_k - x_{k-p}|`` must be within ``tol·|x|∞``, and so must the transient still to
    decay, ``d1·ρ/(1 - ρ)`` with ``ρ = d1/d2`` the observed contraction over p periods.
    """
    scale = 1e-300
    for i in range(nx):
        scale = max(scale, abs(x[i]))
    cur = period % RING
    for p in range(1, MAX_PERIOD + 1):
        if nring < 2 * p + 1:
            break
        a = (period - p) % RING
        b = (period - 2 * p) % RING
        d1 = _dist(ring, cur, a, nx)
        if d1 > tol * scale:
            continue
        if d1 <= NOISE * scale:  # repeats to the integration's own noise: nothing to wait for
            return _smallest_divisor(ring, period, tol, nx, p, scale)
        d2 = _dist(ring, a, b, nx)
        if d2 > 0.0:
            rho = d1 / d2
            if rho < 0.95 and d1 / (1.0 - rho) <= tol * scale:
                return _smallest_divisor(ring, period, tol, nx, p, scale)
    return 0


@njit(cache=True, nogil=True)
def _smallest_divisor(ring, period, tol, nx, p, scale):
    """A p-periodic state found while a slow transient lingers may really be q-periodic, q | p."""
    cur = period % RING
    for q in range(1, p):
        if p % q == 0 and _dist(ring, cur, (period - q) % RING, nx) <= 10.0 * tol * scale:
            return q
    return p


@njit(cache=True, nogil=True)
def candidate(ring, nring, period, nx):
    """Smallest p whose p-spaced differences shrink geometrically over the last three steps and
    are already small: the sequence is converging to a p-periodic state (0: none)."""
    scale = 1e-300
    cur = period % RING
    for i in range(nx):
        scale = max(scale, abs(ring[cur, i]))
    for p in range(1, MAX_CANDIDATE + 1):
        if nring < 3 * p + 1:
            break
        a = (period - p) % RING
        b = (period - 2 * p) % RING
        c = (period - 3 * p) % RING
        d1 = _dist(ring, cur, a, nx)
        if d1 > 0.05 * scale:
            continue
        d2 = _dist(ring, a, b, nx)
        d3 = _dist(ring, b, c, nx)
        if d1 < 0.98 * d2 and d2 < 0.98 * d3:
            return p
    return 0


@njit(cache=True, nogil=True)
def period_end(x, nx, rows, samples, k, ring, kst, lin_L, lin_xp, lin_amp, lin_gate, checks,
               div_limit, tol):  # fmt: skip
    """Close period ``k`` of a batch: sample, then the checks that may end the batch.

    Returns ``(code, p)``: an ``END_*`` code and, for ``END_PERIODIC``/``END_CANDIDATE``, the
    period found. ``kst[K_PERIOD]`` must already count this period.
    """
    big = 0.0
    for i in range(nx):
        v = x[i]
        if not math.isfinite(v):
            return END_NONFINITE, 0
        big = max(big, abs(v))
        samples[k, i] = v
    rows[k, M_XNORM] = big
    if big > div_limit:
        return END_DIVERGED, 0
    if checks & CHECK_LINEAR:
        tail = lin_amp + linear_tail_bound(x, nx, lin_L, lin_xp)
        rows[k, M_TAIL] = tail
        if tail < lin_gate:
            return END_LINEAR, 0
    period = int(kst[K_PERIOD])
    slot = period % RING
    for i in range(nx):
        ring[slot, i] = x[i]
    kst[K_RING] += 1.0
    nring = int(kst[K_RING])
    if checks & CHECK_PERIODIC:
        p = periodicity(ring, nring, period, x, tol, nx)
        if p > 0:
            return END_PERIODIC, p
    impacted = rows[k, M_IMP1] + rows[k, M_IMP2] > 0.0
    if impacted:
        kst[K_IMPACTED] = 1.0
    if checks & CHECK_CANDIDATE and period >= kst[K_NEXT_TRY]:
        p = candidate(ring, nring, period, nx)
        if p > 0:
            return END_CANDIDATE, p
    # The flag outlives the engine's back-off: impacts that end while a quiet period may not be
    # signalled are still followed by a proof at the first quiet period after it (a signal only
    # at an impacting period's successor left those runs to the cheap bound, ~15 periods later).
    if (checks & CHECK_QUIET and kst[K_IMPACTED] == 1.0 and not impacted
            and rows[k, M_REGIME] == 0.0 and period >= kst[K_NEXT_QUIET]):  # fmt: skip
        kst[K_IMPACTED] = 0.0
        return END_QUIET, 0
    return END_NONE, 0
