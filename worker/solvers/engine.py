"""The point engine: how a point ends, the same for every method (docs/solvers.md).

A point starts at its initial state (rest by default) and is advanced in batches of whole
periods by its method's kernel (``base.KernelRun``). It ends as soon as what it would report
is proven:

``linear``
    The linear tail test (``linear.py``) shows that the free motion from the current state can
    never reach a stop again: the steady state is the closed form, reported exactly.
``periodic``
    A period-p orbit with impacts. When the stroboscopic sequence converges geometrically
    (``measure.candidate``), the orbit is extrapolated from it (reduced rank extrapolation, the
    vector-extrapolation method of periodic-steady-state analysis in circuit simulators) and
    confirmed by integrating p periods from the extrapolated state: it must repeat to
    ``periodicity_tol`` (allowing for the estimated contraction), have the same impacts per
    period as the trajectory, and lie where the trajectory's own contraction is heading, so
    only an orbit reached from the point's start is reported. A sequence that repeats by
    itself (``measure.periodicity``) needs no extrapolation, once the repeat is shown not to be
    a shorter period still being approached (:func:`_divisors_steady`). An extrapolated orbit
    must also attract: its monodromy matrix (finite differences) has a spectral radius below 1, the
    reported Floquet multiplier; where the map is not smooth (no Jacobian) the orbit is
    reported only once the trajectory has reached it. The orbit is then measured over p
    periods; an orbit reached by itself gets its monodromy radius too where the map is smooth
    and the check at most triples the point's cost (``_measure_orbit``). Where no radius is
    computed, none is reported: no estimate stands in.
``irregular``
    Cycle-by-cycle statistics: Γ of the mean over periods of each period's half-range
    (max s − min s)/2; the initial transient is cut by the MSER rule; the point ends when the
    standard error of Γ (batch means, batches doubled until their means decorrelate) is below
    ``stat_tol_db`` over at least ``MIN_STATIONARY`` periods (or a quarter of a shorter budget),
    the batch means show no trend, and impacts are still happening in the last quarter of the
    final window. Where the error bar cannot be trusted (undamped, intermittent, almost
    periodic) the reason says so.
``unsettled``
    The period budget ran out first; the numbers are kept and labelled, never called irregular.
``failed``
    Not finite, diverged (``base.KernelRun.failure_reason``), no steady state (undamped), a
    method's own reason, or over the point's budget (``PointLimits``: wall time or steps);
    values are ``None``.

Every result also carries the linear reference ``transmittance_linear_db`` (Γ_lin: the closed
form of the same cell without stops, ``LinearTail.steady``) and ``impact_effect_db`` = Γ − Γ_lin
(exactly 0 for ``linear``; ``None`` where Γ or Γ_lin is missing). A ``failed`` point keeps Γ_lin.
An ``irregular`` point where that impact-free response is admissible too is flagged
``may_be_transient``, with ``impacting_periods``, the periods its impacting motion has lasted.

Every result that is not ``failed`` carries ``final_state``: the state at a period boundary
(forcing phase 0) of what it reports — the orbit's start, the closed-form steady state, or the
end of the run for ``irregular``/``unsettled`` — which a sweep line hands to its next point.

Between batches the engine checks the point's limits and the caller's ``cancelled`` callback
(``PointCancelled``). A batch is shortened when periods are slow, so both are seen well within
a second.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from worker.model import SteadyState, System, pinned_max_re
from worker.numba_cache import on_disk
from worker.observables import theta_eff_harmonic, theta_eff_slope, transmittance_db
from worker.solvers import measure as ms
from worker.solvers.base import ExactMonodromy, KernelRun
from worker.solvers.linear import LinearTail
from worker.solvers.settings import (
    OVER_STEPS,
    OVER_TIME,
    TRANSIENT_NOTE,
    PointCancelled,
    PointLimits,
    PointResult,
    SolverSettings,
)

__all__ = [
    "DIVERGENCE_FACTOR",
    "compile_helpers",
    "MIN_WINDOWS",
    "TRANSIENT_NOTE",
    "SeriesStats",
    "UNTRUSTED_NOTE",
    "budget_for_error",
    "few_batches_factor",
    "linear_reference_db",
    "mser_start",
    "series_stats",
    "rre",
    "run_point",
]

DIVERGENCE_FACTOR = 1e6  # |x|∞ beyond this times the natural scale is divergence
# Part of an irregular point's reason where its standard error cannot be trusted
# (``_Engine._distrust``); ``TRANSIENT_NOTE`` where the motion may be transient.
UNTRUSTED_NOTE = "its standard error cannot be trusted"
MIN_WINDOWS = 8  # windows measured (harmonics, θ_eff) before the earliest irregular claim
# Stationary periods an irregular claim rests on at the fewest, or a quarter of a shorter budget
# (measured from period 100 with the default budget and window: no claim before period 300)
MIN_STATIONARY = 200
MSER_BATCH = 5  # periods per batch of the MSER rule (MSER-5): the transient cut is a multiple
MSER_KEEP = 10  # batches the MSER rule leaves at the fewest (its statistic is noise over fewer)
MIN_BATCHES = 10  # batch means a standard error rests on at the fewest (when they stay correlated)
# The lag-1 autocorrelation of k batch means counts as insignificant below DECORRELATED/√k (its
# spread for independent means is 1/√k), those at lags up to measure.MAX_PERIOD periods below
# (DECORRELATED + 1)/√k (many lags: a stricter bound): batches are doubled until they are
DECORRELATED = 2.0
MAX_TREND = 3.0  # t-statistic of the batch means' trend above which Γ is still drifting
MAX_HALVES = 4.0  # t-statistic of the two halves' difference above which a response is intermittent
# A stationary series whose values repeat every q <= measure.MAX_PERIOD periods to within this
# fraction of their spread (RMS of y_k - y_{k-q} over √2 times their standard deviation, 1 for
# independent values; the lag-q autocorrelation above 0.99) is an almost periodic response:
# its mean moves with slow modulations and changes of level that its record may not show
ALMOST_PERIODIC = 0.1
RECENT = 64  # stroboscopic samples the engine keeps for extrapolation
# An irregular claim also waits while the p-spaced differences of the samples have shrunk at
# each of the last SHRINK_RETURNS returns and SHRINK_FACTOR-fold over them (_shrinking_p); the
# samples kept for it hold that for every p up to the longest period recognised
SHRINK_RETURNS = 6
SHRINK_FACTOR = 10.0
HISTORY = (SHRINK_RETURNS + 2) * ms.MAX_PERIOD
# ... and while, over all the samples kept, the p-spaced differences stay within CREEP_NEAR of
# the state and their largest in each of CREEP_BLOCKS consecutive stretches falls from one
# stretch to the next, to at most CREEP_DROP of the oldest's (_creeping_p): a slow approach (a
# multiplier up to ~0.9992 a period) that shrinks them too little for the tests above, while
# the windows' Γ drifts too smoothly for the trend test. (A response whose differences are
# only modulated slowly, near a period-13 orbit at Figure 5's θ 0.3, gap 1, γ_r 1.2, falls
# by 5-7 % over the stretches while it does.)
CREEP_NEAR = 1e-2
CREEP_BLOCKS = 8
CREEP_DROP = 0.8
MAX_CYCLES = 4  # extrapolate-and-confirm cycles per candidate
MAX_FIT = 1e-2  # a first extrapolation must fit the sequence to this relative residual
MAX_RRE = 8  # samples (p apart) one extrapolation uses at most
# A Newton step on the p-period map (event's exact matrix) may be at most this many times the
# distance a contraction's residual allows (r / (1 − ρ)); longer ones fall back on extrapolation
NEWTON_REACH = 10.0
# The main trajectory accumulates harmonics (for an irregular response's θ_eff) only over the
# windows its statistics can use: the last MIN_WINDOWS before the earliest irregular claim on.
# Orbits are always measured (their own side run).
FD_STEP = 1e-7  # relative state perturbation of the monodromy matrix's finite differences
# The monodromy check of an orbit the trajectory reached by itself may cost at most this many
# times the periods the point has run: at most triple its cost. Orbits reached within a few
# periods of many-mode cells (nx side runs of 40-60 states) would cost 10-15 times more.
CHECK_COST = 2
# Periods per batch while the trajectory approaches an orbit waiting for it (_reached): it is
# seen within this many periods of being reached (a batch costs ~10 µs more than its periods)
PENDING_BATCH = 4
# ... or, for an orbit with a multiplier below 1, once it has been this many times closer to
# the orbit than when the orbit was confirmed at REACH_HOLD returns in a row (a chaotic
# trajectory may pass near an orbit once; and without a multiplier the orbit may be a saddle
# that the trajectory passes along its stable manifold)
REACH_SHRINK = 100.0
REACH_HOLD = 3
# ... or once its last MAX_RRE returns follow the orbit's linearized map to this fraction of
# their distance to it (_follows; also what an extrapolated orbit needs to be reported at once)
LINEAR_FIT = 0.25
# (and the newest within LINEAR_FIT of how much closer the map brings the oldest). Where the map
# brings deviations less than this much closer over MAX_RRE returns (a multiplier near 1),
# pending orbits are also fitted over all the returns the buffer holds (_fit_returns)
SLOW_SHRINK = 0.5
# eigenvector matrices of the map worse conditioned than this: the approach is measured without
# them (_approach_seen)
EIG_COND = 1e8
TAIL_HORIZON = 200  # periods ahead the linear tail proof may search
# Periods (times the orbit's period) without periodicity signals after an unstable orbit was
# reached by the samples: they repeat near it for a while as the trajectory leaves
UNSTABLE_HOLD = 4
# A p-periodic state whose q-spaced differences (q | p) are within this many periodicity_tol may
# still be approaching a period-q orbit: it must show them steady first (_divisors_steady)
AMBIGUOUS = 1e3
BATCH_S = 0.25  # target seconds per batch of periods: how often limits and cancel are seen


# --------------------------------------------------------------------------- numerics


def rre(X: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """Reduced rank extrapolation of a sequence ``X`` (rows oldest → newest, ≥ 3 of them).

    Fits ``Σ γ_j u_j ≈ 0`` (``u_j = x_{j+1} - x_j``, ``Σ γ_j = 1``) by least squares and returns
    ``(x*, ρ, fit)``: the limit ``Σ γ_j x_{j+1}``, the largest modulus among the roots of
    ``Σ γ_j z^j`` (Ritz values of the map's Jacobian: the dominant multiplier), and the
    residual ``|Σ γ_j u_j| / |u_newest|`` of the fit; ``None`` where the fit is not finite.
    Compiled (:func:`_rre`): numpy's small-array calls cost ~150 µs an extrapolation, which
    periodic points repeat several times.
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.shape[0] < 3:
        return None
    xs = np.empty(X.shape[1])
    ok, rho, fit = _rre(X, xs)
    return (xs, rho, fit) if ok else None


@njit(cache=True, nogil=True)
def _rre(X, xs):
    k = X.shape[0] - 1
    n = X.shape[1]
    U = np.empty((k, n))
    for j in range(k):
        for i in range(n):
            U[j, i] = X[j + 1, i] - X[j, i]
    nb = 0.0
    for i in range(n):
        nb += U[k - 1, i] * U[k - 1, i]
    nb = math.sqrt(nb)
    if nb == 0.0:
        for i in range(n):
            xs[i] = X[k, i]
        return True, 0.0, 0.0
    D = np.empty((n, k - 1))
    rhs = np.empty(n)
    for i in range(n):
        for j in range(k - 1):
            D[i, j] = U[j, i] - U[k - 1, i]
        rhs[i] = -U[k - 1, i]
    beta = np.linalg.lstsq(D, rhs, 1e-12)[0]
    gamma = np.empty(k)
    total = 0.0
    for j in range(k - 1):
        gamma[j] = beta[j]
        total += beta[j]
    gamma[k - 1] = 1.0 - total
    for j in range(k):
        if not math.isfinite(gamma[j]):
            return False, 0.0, 0.0
    res = 0.0
    for i in range(n):
        acc = 0.0
        racc = 0.0
        for j in range(k):
            acc += gamma[j] * X[j + 1, i]
            racc += gamma[j] * U[j, i]
        xs[i] = acc
        res += racc * racc
    fit = math.sqrt(res) / nb
    # the roots of Σ γ_j z^j: eigenvalues of its companion matrix (trailing zeros dropped,
    # leading zero coefficients give roots at zero)
    top = k - 1
    while top > 0 and gamma[top] == 0.0:
        top -= 1
    rho = 0.0
    if top > 0:
        C = np.zeros((top, top), dtype=np.complex128)  # complex roots: numba wants the dtype
        for j in range(top):
            C[0, j] = -gamma[top - 1 - j] / gamma[top]
        for j in range(1, top):
            C[j, j - 1] = 1.0
        ev = np.linalg.eigvals(C)
        for z in ev:
            rho = max(rho, abs(z))
    return True, rho, fit


def compile_helpers() -> None:
    """Compile the engine's own compiled helpers into numba's on-disk cache if they are not
    there. A point calls most of them only once it extrapolates an orbit (the statistics' two once
    it may be irregular), so a worker loads them then
    (~0.35 s); ``simulate.warm_up`` calls this so that on a fresh cache the process that warms up
    compiles them once (~12 s on this machine), not every worker at its first periodic point."""
    helpers = (_rre, _converging_p, _shrinking_p, _creeping_p, _divisors_steady, _max_diff,
               _mser_start, _batch_size, _repeat)  # fmt: skip
    if all(on_disk(f) for f in helpers):
        return
    X = np.array([[0.0, 1.0], [1.0, 0.5], [1.5, 0.25], [1.75, 0.125]])
    rre(X)
    _converging_p(X, 1)
    _shrinking_p(X, 4, 1)
    _creeping_p(X, 4, 1)
    _divisors_steady(X, 4, 2, 1e-6, 1e-9)
    _max_diff(X[0], X[1])
    series_stats(X[:, 0])


@functools.cache
def few_batches_factor(k: int) -> float:
    """How much wider a standard error resting on k batch means is reported:
    ``t_{k-1}(0.99865) / 3`` (at least 1), so that ±3 standard errors is the 99.73 % interval
    of Student's t with k - 1 degrees of freedom, as it is of the normal law for many
    batches (k = 8: 1.51; k = 20: 1.15; k = 100: 1.03)."""
    if k < 2:
        return 1.0
    # Imported here: scipy costs ~0.4 s of CPU to import, and only an irregular response's
    # statistics need it (not the process that hands out points, nor most points).
    from scipy.special import stdtrit

    return max(1.0, float(stdtrit(k - 1, 0.99865)) / 3.0)


def budget_for_error(se: float, tol: float, n: int, start: int) -> int:
    """The period budget at which the standard error ``se`` of an irregular Γ, resting on
    ``n`` stationary periods from period ``start`` on, would be down to ``tol``: the error of a
    mean falls as ``1/√n``, so ``start + n·(se/tol)²``, rounded up to a hundred periods. An
    estimate (the batches, and with them the error's own error, change as the span grows)."""
    return int(math.ceil((start + n * (se / tol) ** 2) / 100.0)) * 100


def mser_start(y: np.ndarray, batch: int = MSER_BATCH) -> int:
    """The end of the initial transient of ``y`` by the MSER rule (White's marginal standard
    error rule): over batches of ``batch`` values, the start ``d`` minimising
    ``Var(y[d:]) / len(y[d:])``, leaving at least ``MSER_KEEP`` batches; a multiple of
    ``batch``. A start past the middle says the record is too short for its transient."""
    return int(_mser_start(np.ascontiguousarray(y, dtype=np.float64), batch, MSER_KEEP))


@njit(cache=True, nogil=True)
def _mser_start(y, batch, keep):
    nb = len(y) // batch
    if nb < 2:
        return 0
    means = np.empty(nb)
    for j in range(nb):
        acc = 0.0
        for i in range(j * batch, (j + 1) * batch):
            acc += y[i]
        means[j] = acc / batch
    s1 = 0.0
    s2 = 0.0
    best = np.inf
    d = 0
    last = max(nb - keep, nb // 2)
    for j in range(nb - 1, -1, -1):  # Σ means[j:], Σ means[j:]², from the end
        s1 += means[j]
        s2 += means[j] * means[j]
        if j <= last:
            cnt = nb - j
            stat = max(s2 / cnt - (s1 / cnt) ** 2, 0.0) / cnt
            if stat <= best:  # ties: the earliest start, as argmin
                best = stat
                d = j
    return d * batch


@njit(cache=True, nogil=True)
def _batch_size(z, limit, min_batches, max_lag):
    """The smallest batch size 1, 2, 4, … at which the k batch means (the newest whole batches
    of ``z``) look independent: their lag-1 autocorrelation r₁ at most ``limit/√k``, and at
    every lag up to ``max_lag`` values (a pattern repeating every few values, an almost
    periodic response) at most ``(limit + 1)/√k``; or the largest size that leaves
    ``min_batches``. Returns (size, r₁, whether they look independent)."""
    m = len(z)
    b = 1
    means = np.empty(m)
    while True:
        k = m // b
        off = m - k * b
        mean = 0.0
        for j in range(k):
            acc = 0.0
            for i in range(off + j * b, off + (j + 1) * b):
                acc += z[i]
            means[j] = acc / b
            mean += means[j]
        mean /= k
        ss = 0.0
        for j in range(k):
            means[j] -= mean
            ss += means[j] * means[j]
        r1 = 0.0
        ok = True
        if ss > 0.0:
            for lag in range(1, min(max(1, max_lag // b), k - 1) + 1):
                acc = 0.0
                for j in range(lag, k):
                    acc += means[j] * means[j - lag]
                r = acc / ss
                if lag == 1:
                    r1 = r
                    ok = r <= limit / math.sqrt(k)
                elif r > (limit + 1.0) / math.sqrt(k):
                    ok = False
                if not ok:
                    break
        if ok:
            return b, r1, True
        if m // (2 * b) < min_batches:
            return b, r1, False
        b *= 2


@njit(cache=True, nogil=True)
def _repeat(z, max_q):
    """How close the values of ``z`` come to repeating at a lag q in 1…max_q (up to half the
    series): the smallest RMS of z_k - z_{k-q} over √2 times the standard deviation of z (1 for
    independent values, 0 for a series of period q), and the shortest lag within a tenth of it
    (not a multiple of it that noise made closer)."""
    m = len(z)
    mean = 0.0
    for i in range(m):
        mean += z[i]
    mean /= m
    var = 0.0
    for i in range(m):
        var += (z[i] - mean) ** 2
    var /= m
    if var <= 0.0:
        return 1, 0.0
    top = min(max_q, m // 2)
    ratios = np.ones(top + 1)
    best = 1.0
    for q in range(1, top + 1):
        acc = 0.0
        for i in range(q, m):
            acc += (z[i] - z[i - q]) ** 2
        ratios[q] = math.sqrt(acc / (m - q) / (2.0 * var))
        best = min(best, ratios[q])
    for q in range(1, top + 1):
        if ratios[q] <= 1.1 * best:
            return q, best
    return 0, best


@dataclass(frozen=True)
class SeriesStats:
    """The mean of a stationary series and how far to trust it (:func:`series_stats`)."""

    mean: float  # over the stationary part, y[start:]
    se: float | None  # its standard error; None with fewer than 2 values
    start: int  # the MSER cut: the first stationary value
    n: int  # stationary values, len(y) - start
    batch: int  # values per batch of the batch means (the newest whole batches)
    batches: int
    decorrelated: bool  # the batch means' lag-1 autocorrelation is insignificant
    trend: float  # t-statistic of the batch means' least-squares slope
    halves: float  # t-statistic of the difference between the two halves' means
    warmed_up: bool  # the transient cut lies in the first half (else the record is too short)
    repeat: int  # the lag (≤ measure.MAX_PERIOD) at which the values come closest to repeating
    closeness: float  # how close (:func:`_repeat`): below ALMOST_PERIODIC, almost periodic

    @property
    def steady(self) -> bool:
        """Whether a longer record has nothing to mend: the transient is cut in the first half,
        the batch means decorrelated and the halves agree."""
        return self.warmed_up and self.decorrelated and self.halves <= MAX_HALVES


def series_stats(y: np.ndarray) -> SeriesStats:
    """Mean and standard error of the stationary part of ``y`` (an irregular response's
    per-period half-ranges), with what says whether to trust them (docs/solvers.md).

    The initial transient is cut by :func:`mser_start`. The standard error is that of batch
    means: batches of 1, 2, 4, … values (the newest whole batches of the stationary part)
    until the lag-1 autocorrelation r₁ of the batch means is below ``DECORRELATED/√k`` for k
    batches (``decorrelated``), or until a further doubling would leave fewer than
    ``MIN_BATCHES``. It is widened by ``√((1 + r₁)/(1 − r₁))`` for the correlation left
    (r₁ clipped to [0, 0.95]) and by :func:`few_batches_factor` for the few batches it may
    rest on (their sample variance is itself uncertain). ``trend`` is the batch means' least-
    squares slope over its standard error, ``halves`` the difference between the means of their
    first and second halves over its standard error (both widened for the correlation left):
    a slow transient has a large trend, an intermittent response large halves.
    """
    y = np.ascontiguousarray(y, dtype=np.float64)
    if len(y) == 0:
        return SeriesStats(math.nan, None, 0, 0, 1, 0, False, 0.0, 0.0, False, 0, 1.0)
    d = mser_start(y)
    z = y[d:]
    m = len(z)
    mean = float(z.mean())
    if m < 2:
        return SeriesStats(mean, None, d, m, 1, m, False, 0.0, 0.0, 2 * d <= len(y), 0, 1.0)
    b, r1, decorrelated = _batch_size(z, DECORRELATED, MIN_BATCHES, ms.MAX_PERIOD)
    k = m // b
    means = z[m - k * b :].reshape(k, b).mean(axis=1)
    dev = means - means.mean()
    ss = float(dev @ dev)
    r1 = min(max(r1, 0.0), 0.95)
    inflate = math.sqrt((1.0 + r1) / (1.0 - r1))
    sd = math.sqrt(ss / (k - 1))
    se = sd / math.sqrt(k) * inflate * few_batches_factor(k)
    trend = halves = 0.0
    if k >= 3:
        i = np.arange(k) - (k - 1) / 2.0
        slope = float(i @ dev) / float(i @ i)
        resid = dev - slope * i
        s_res = math.sqrt(float(resid @ resid) / (k - 2))
        se_slope = s_res / math.sqrt(float(i @ i)) * inflate
        trend = abs(slope) / se_slope if se_slope > 0.0 else (math.inf if slope else 0.0)
    if k >= 4:
        h = k // 2
        a, c = means[:h], means[k - h :]
        pooled = math.sqrt((float(((a - a.mean()) ** 2).sum()) + float(((c - c.mean()) ** 2).sum()))
                           / (2 * h - 2))  # fmt: skip
        se_diff = pooled * math.sqrt(2.0 / h) * inflate
        diff = abs(float(a.mean() - c.mean()))
        halves = diff / se_diff if se_diff > 0.0 else (math.inf if diff else 0.0)
    q, closeness = _repeat(z, ms.MAX_PERIOD)
    return SeriesStats(mean, se, d, m, b, k, decorrelated, trend, halves, 2 * d <= len(y), q,
                       closeness)  # fmt: skip


# --------------------------------------------------------------------------- windows


@njit(cache=True, nogil=True)
def _fold_rows(rows: np.ndarray, cur: np.ndarray, count: int) -> bool:
    """Fold a batch of period rows into the open window's aggregate ``cur`` (``count`` periods
    in it so far); whether every row was measured. Compiled: a dozen numpy calls per batch
    cost ~5 % of a point."""
    measured = True
    for i in range(rows.shape[0]):
        cur[ms.M_SMAX] = max(cur[ms.M_SMAX], rows[i, ms.M_SMAX])
        cur[ms.M_SMIN] = min(cur[ms.M_SMIN], rows[i, ms.M_SMIN])
        for j in range(ms.M_S_RE, ms.M_IMP2 + 1):
            cur[j] += rows[i, j]
        cur[ms.M_PEAK] = max(cur[ms.M_PEAK], rows[i, ms.M_PEAK])
        if rows[i, ms.M_LAST_IMPACT] >= 0.0:
            cur[ms.M_LAST_IMPACT] = count + i + rows[i, ms.M_LAST_IMPACT]
        measured = measured and rows[i, ms.M_MEASURED] != 0.0
    return measured


@njit(cache=True, nogil=True)
def _work_sums(rows: np.ndarray) -> tuple[float, float, float]:
    """Steps, contact steps and coarse steps of a batch of period rows (whole numbers: any
    summation order gives the same)."""
    steps = contact = coarse = 0.0
    for i in range(rows.shape[0]):
        steps += rows[i, ms.M_STEPS]
        contact += rows[i, ms.M_CONTACT]
        coarse += rows[i, ms.M_COARSE]
    return steps, contact, coarse


@njit(cache=True, nogil=True)
def _push_recent(imp: np.ndarray, reg: np.ndarray, rows: np.ndarray) -> None:
    """Append a batch's impacts and end regimes to the newest-last buffers of the samples kept
    for extrapolation (the oldest drop out)."""
    n = rows.shape[0]
    size = imp.shape[0]
    k = min(n, size)
    for i in range(size - k):
        imp[i] = imp[i + k]
        reg[i] = reg[i + k]
    for i in range(k):
        src = n - k + i
        imp[size - k + i] = rows[src, ms.M_IMP1] + rows[src, ms.M_IMP2]
        reg[size - k + i] = rows[src, ms.M_REGIME]


@njit(cache=True, nogil=True)
def _push_samples(buffer: np.ndarray, samples: np.ndarray) -> None:
    """Append a batch's stroboscopic samples to a newest-last buffer (the oldest drop out)."""
    n = samples.shape[0]
    size = buffer.shape[0]
    k = min(n, size)
    for i in range(size - k):
        buffer[i] = buffer[i + k]
    for i in range(k):
        buffer[size - k + i] = samples[n - k + i]


@njit(cache=True, nogil=True)
def _shrinking_p(history: np.ndarray, n: int, max_period: int) -> int:
    """The smallest p whose p-spaced differences of the newest-last samples (the last ``n`` of
    ``history`` valid) shrank at each of the last SHRINK_RETURNS returns and SHRINK_FACTOR-fold
    over them: the response converges steadily to a period-p orbit (0: none). Chaos shrinks
    seven differences in a row by chance about once in 5,040 tries of one p."""
    last = history.shape[0] - 1
    for p in range(1, max_period + 1):
        if (SHRINK_RETURNS + 1) * p >= n:
            break
        newest = _max_diff(history[last], history[last - p])
        prev = newest
        steady = True
        for j in range(1, SHRINK_RETURNS + 1):
            d = _max_diff(history[last - j * p], history[last - (j + 1) * p])
            if d <= prev:
                steady = False
                break
            prev = d
        if steady and newest * SHRINK_FACTOR <= prev:
            return p
    return 0


@njit(cache=True, nogil=True)
def _size(x: np.ndarray) -> float:
    """max |x|, at least 1e-300: the scale differences of states are relative to."""
    m = 1e-300
    for i in range(x.shape[0]):
        m = max(m, abs(x[i]))
    return m


@njit(cache=True, nogil=True)
def _creeping_p(history: np.ndarray, n: int, max_period: int) -> int:
    """The smallest p whose p-spaced differences of the newest-last samples (the last ``n`` of
    ``history`` valid) are all within CREEP_NEAR of the state and whose largest in each of
    CREEP_BLOCKS consecutive stretches of at least a return fell from the stretch before, to at
    most CREEP_DROP of the oldest's: the response creeps towards a period-p orbit (0: none).
    Chaos keeps its differences near the state's size; a quasi-periodic response keeps their
    stretches' largest level."""
    last = history.shape[0] - 1
    scale = _size(history[last])
    for p in range(1, max_period + 1):
        width = (n - p) // CREEP_BLOCKS  # differences per stretch
        if width < p:
            break
        prev = first = np.inf
        creeps = True
        for b in range(CREEP_BLOCKS - 1, -1, -1):  # the oldest stretch first
            top = _envelope(history, last - b * width, p, width)
            if top > CREEP_NEAR * scale or top >= prev:
                creeps = False
                break
            if b == CREEP_BLOCKS - 1:
                first = top
            prev = top
        if creeps and prev <= CREEP_DROP * first:
            return p
    return 0


@njit(cache=True, nogil=True)
def _envelope(history: np.ndarray, end: int, q: int, width: int) -> float:
    """The largest q-spaced difference of the ``width`` samples of ``history`` ending at row
    ``end``: over a whole return of a period-p orbit it sees every phase of a rotating
    deviation."""
    m = 0.0
    for j in range(width):
        m = max(m, _max_diff(history[end - j], history[end - j - q]))
    return m


@njit(cache=True, nogil=True)
def _divisors_steady(history: np.ndarray, n: int, p: int, near: float, tol: float) -> bool:
    """Whether the newest of the newest-last samples (the last ``n`` of ``history`` valid),
    found to repeat after p periods, is a period-p state rather than one still approaching a
    period-q orbit, q a proper divisor of p. Near such an orbit, a mode whose multiplier is near
    a (p/q)-th root of unity hardly shows in the p-spaced differences, while the q-spaced ones
    still shrink with it (Figure 5 at θ 0.5, gap 0.1, γ_r 3.42: period 2 reported, the state 22
    times farther from the period-1 orbit than periodicity_tol); a period-p orbit keeps its
    q-spaced differences. So wherever a q-spaced difference is within ``near`` (relative; and
    beyond 10·``tol``, the kernel's own divisor test) its envelope over the last return (the
    largest of the last p; a deviation that rotates makes single differences rise and fall) must
    be that of a return as long ago as the samples reach to 10 % (a multiple of p periods, at
    least 2p: about 300 when they are all kept, where a slow mode's differences shrink by more
    wherever its multiplier is below 0.9997)."""
    last = history.shape[0] - 1
    scale = _size(history[last])
    for q in range(1, p):
        if p % q:
            continue
        e0 = _max_diff(history[last], history[last - q])
        if e0 > near * scale or e0 <= 10.0 * tol * scale:
            continue
        back = (n - 1 - q - p) // p * p
        if back < 2 * p:
            return False
        now = _envelope(history, last, q, p)
        then = _envelope(history, last - back, q, p)
        if abs(then - now) > 0.1 * now:
            return False
    return True


def _own_period(history: np.ndarray, n: int, p: int) -> int:
    """The period of the orbit whose approach the p-spaced differences of the newest-last
    samples (the last ``n`` of ``history`` valid) show: the smallest divisor q of p whose
    q-spaced differences shrank about as much over the samples (the largest in the newest of
    CREEP_BLOCKS stretches against the oldest's, at most halfway from the p-spaced ones'
    fraction to 1), else p. A period-1 orbit approached along a multiplier λ near −1 makes the
    2-spaced differences (1 − λ²)/2 of the 1-spaced ones, so the tests see them first, though
    both shrink alike (a random cell's unsettled reason named a period-2 orbit that a longer run
    shows is period 1); the q-spaced differences of a period-p orbit keep the orbit's own size.
    Only the name in a reason depends on it."""
    width = (n - p) // CREEP_BLOCKS
    if p < 2 or width < p:
        return p
    last = history.shape[0] - 1
    old = last - (CREEP_BLOCKS - 1) * width

    def fraction(k: int) -> float:
        before = _envelope(history, old, k, width)
        return _envelope(history, last, k, width) / before if before > 0.0 else math.inf

    fp = fraction(p)
    if not fp < 1.0:
        return p
    for q in range(1, p):
        if p % q == 0 and fraction(q) <= 0.5 * (1.0 + fp):
            return q
    return p


def _exact_radius(exact: ExactMonodromy | None) -> float | None:
    """The spectral radius of a method's exact monodromy matrix (None without one, or where
    its eigenvalues are not finite)."""
    if exact is None:
        return None
    ev = np.linalg.eigvals(exact.matrix)
    return float(np.max(np.abs(ev))) if np.all(np.isfinite(ev)) else None


def _newton_step(exact: ExactMonodromy | None, res: np.ndarray, r: float,
                 rho: float) -> np.ndarray | None:  # fmt: skip
    """Newton's step ``δ = (J − I)⁻¹ res`` towards the fixed point of the p-period map from a
    state x with residual ``res = F(x) − x`` (``r = |res|∞``; ``rho`` < 1 the contraction the
    sequence shows); None where it is not to be trusted: no exact matrix (other methods, a
    refused replay), one at a shifted section (an orbit that starts stuck on a stop: the map at
    τ = 0 is one-sided), ``J − I`` singular, or a step longer than ``NEWTON_REACH·r/(1 − rho)``
    (a contraction's fixed point is within about ``r/(1 − rho)`` of x: a longer step left the
    linear regime, or the map is near neutral there). J's eigenvalues are not computed: they
    cost more than the step (~70 µs); the orbit's multiplier comes from its measuring run."""
    if exact is None or exact.shifted:
        return None
    J = exact.matrix
    try:
        step = np.linalg.solve(J - np.eye(J.shape[0]), res)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(step)) or np.max(np.abs(step)) > NEWTON_REACH * r / (1.0 - rho):
        return None
    return step


def _follows(
    M: np.ndarray,
    X: np.ndarray,
    x0: np.ndarray,
    chained: bool = True,
    frame: Callable[[], tuple[float, tuple | None]] | None = None,
) -> bool:
    """Whether the samples ``X`` (one map step apart, oldest first) follow the orbit's
    linearized map towards its state ``x0`` (``M`` the map's matrix there): the deviations
    ``D = X − x0`` must be what the linear map makes of the first one, ``D_j ≈ M^j D_0``
    (``chained``; else of the one before, ``D_j ≈ M D_{j−1}``), to ``LINEAR_FIT·|D_j|`` at
    every step. Samples that stay near an orbit without approaching it (an orbit of another
    period around it, chaos beside it) fit no linear map: even one step misses by a good
    part of the deviation (Figure 5 at θ 0.3, gap 0.3, γ_r 1.54: 0.57 of it, where a stable
    period-1 orbit is circled by the period-3 orbit the trajectory settles on), and chaos that
    fits three steps one at a time by chance does not fit seven chained (θ 0.5, gap 1,
    γ_r 1.04). A trajectory approaching the orbit fits to ~1 % (the median at Figure 5's
    orbits), less as it gets closer. Chained, the newest sample must also have come as much
    closer as the map brings it, to ``LINEAR_FIT`` of that approach: near a
    multiplier of modulus 1 the map hardly moves a deviation closer, and a fit of positions
    alone is passed by samples on a nearby orbit. ``frame``: gives :func:`eigen_frame` of M
    where the caller keeps it (a pending orbit's matrix is fitted again at every batch);
    called only where the samples fit the map step by step."""
    D = X - x0
    pred = D[0]
    for j in range(1, len(D)):
        pred = M @ (pred if chained else D[j - 1])
        if np.max(np.abs(D[j] - pred)) > LINEAR_FIT * np.max(np.abs(D[j])):
            return False
    if chained and len(D) >= 2:
        # The approach the map predicts over the samples must be seen too: where the
        # multiplier is near 1 in modulus, the deviation hardly shrinks, and samples on another
        # orbit close around this one fit its position (nightly paper-params, θ 0.5, σ 0.03,
        # γ_s 0.8, ξ 0.08, γ_r 1: a period-1 orbit of multiplier -0.9995 fitted to 13 % by
        # samples approaching the period-2 orbit around it; the map brings them 0.6 % closer
        # over the 8 samples, and they came 12 % closer). The approach is measured at the
        # newest sample's phase: the max-norm of a turning deviation swings
        # with the turn (fourfold for a multiplier pair turning a seventh of a turn a period,
        # at a random cell at θ 9.15, 9 modes, γ_r 0.818), and compared at two phases it
        # measured the turn.
        rho, turn = eigen_frame(M) if frame is None else frame()
        return _approach_seen(rho, turn, D[0], pred, D[-1] - pred, len(D) - 1)
    return len(D) >= 2


def eigen_frame(M: np.ndarray) -> tuple[float, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """A map's spectral radius (inf where its eigenvalues are not finite) and what turns a
    deviation as the map does without shrinking it: the eigenvector matrix V, its inverse and
    the multipliers' phases ``λ/|λ|`` (None where V's condition is above ``EIG_COND``: M nearly
    defective)."""
    w, V = np.linalg.eig(M)
    if not np.all(np.isfinite(w)):
        return math.inf, None
    a = np.abs(w)
    rho = float(np.max(a))
    try:
        W = np.linalg.inv(V)
    except np.linalg.LinAlgError:
        return rho, None
    # the 1-norm condition number: exact, and cheaper than the 2-norm's SVD
    if not np.linalg.norm(V, 1) * np.linalg.norm(W, 1) < EIG_COND:
        return rho, None
    return rho, (V, W, np.where(a > 0.0, w / np.where(a > 0.0, a, 1.0), 1.0))


def _approach_seen(rho: float, turn: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
                   first: np.ndarray, pred: np.ndarray, miss: np.ndarray,
                   steps: int) -> bool:  # fmt: skip
    """Whether a sample met the prediction ``pred = M^steps·first`` of a map that contracts
    (spectral radius ``rho``) to ``LINEAR_FIT`` of the approach the map predicts (``miss``: the
    sample minus ``pred``). The approach is measured at the prediction's phase: how far the
    prediction is from where the map would have turned ``first`` without shrinking it (``turn``
    from :func:`eigen_frame`; each mode turned by its multiplier's phase), so the sample must be
    four times nearer the contracted prediction than the neutral one. Without ``turn`` (M
    nearly defective) it is what the slowest contraction takes off the prediction,
    ``(ρ^-steps − 1)·|pred|`` (stricter: the faster modes' share left out)."""
    if not rho < 1.0:
        return False  # not a contraction: no approach to see
    if turn is not None:
        V, W, u = turn
        neutral = (V @ (u**steps * (W @ first))).real
        closer = float(np.max(np.abs(neutral - pred)))
    else:
        closer = (rho**-steps - 1.0) * float(np.max(np.abs(pred)))
    return bool(np.max(np.abs(miss)) <= LINEAR_FIT * closer)


def _unstable(o: _Orbit) -> bool:
    """Whether an orbit's multiplier shows it repels (a trajectory whose samples repeat near it
    came along its stable directions and will leave)."""
    return o.multiplier is not None and o.multiplier > 1.0


def _impacts(rows: np.ndarray) -> float:
    """Impacts on both stops over the periods of ``rows`` (whole numbers: sums are exact)."""
    return float(rows[:, ms.M_IMP1].sum() + rows[:, ms.M_IMP2].sum())


def _spread(X: np.ndarray, x0: np.ndarray) -> float:
    """The largest distance (max-norm) of the states ``X`` from ``x0``."""
    return float(np.max(np.abs(X - x0)))


@njit(cache=True, nogil=True)
def _max_diff(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| (exact: no rounding but the differences')."""
    m = 0.0
    for i in range(a.shape[0]):
        m = max(m, abs(a[i] - b[i]))
    return m


@njit(cache=True, nogil=True)
def _converging_p(r: np.ndarray, max_period: int) -> int:
    """:meth:`_Engine._converging` on the full buffer ``r`` of stroboscopic samples (newest
    last). Compiled: its ~60 small numpy calls cost ~100 µs a check."""
    n = r.shape[0]
    scale = 0.0
    for i in range(r.shape[1]):
        scale = max(scale, abs(r[n - 1, i]))
    if scale == 0.0:
        scale = 1.0
    half = n // 2
    for p in range(1, max_period + 1):
        now = _max_diff(r[n - 1], r[n - 1 - p])
        before = _max_diff(r[n - 1 - half], r[n - 1 - half - p])
        if now <= 1e-6 * scale or now <= 1e-2 * before:
            return p
    return 0


@dataclass
class _Windows:
    """Per-window aggregates of the period rows, and every period's half-range of s (the
    irregular statistics)."""

    window: int
    impacts: list[tuple[float, float]] = field(default_factory=list)
    peak: list[float] = field(default_factory=list)
    harm: list[np.ndarray] = field(default_factory=list)  # S_re, S_im, Sb_re, Sb_im, VV, VB
    measured: list[bool] = field(default_factory=list)
    last_impact: list[float] = field(default_factory=list)  # position in the window, -1 none
    cur: np.ndarray = field(default_factory=lambda: np.zeros(ms.ROW))
    count: int = 0
    all_measured: bool = True
    # (max s − min s)/2 of every period from the start, the first ``periods`` entries valid
    half_range: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    periods: int = 0
    first_measured: int = -1  # the first period measured (exact extrema), -1 none yet
    # the last stats() and the (first, periods) it was computed for: a claim reads them up to
    # three times (converged?, its reason, its result) without new periods in between
    _stats: tuple[tuple[int, int], SeriesStats] | None = None

    def __post_init__(self) -> None:
        self._open()

    def _open(self) -> None:
        self.cur = np.zeros(ms.ROW)
        self.cur[ms.M_SMAX] = -np.inf
        self.cur[ms.M_SMIN] = np.inf
        self.cur[ms.M_LAST_IMPACT] = -1.0
        self.count = 0
        self.all_measured = True

    def add(self, rows: np.ndarray) -> None:
        """Add a batch of period rows (a batch never crosses a window boundary)."""
        n = len(rows)
        if not n:
            return
        if self.periods + n > len(self.half_range):
            grown = np.zeros(max(2 * len(self.half_range), self.periods + n))
            grown[: self.periods] = self.half_range[: self.periods]
            self.half_range = grown
        self.half_range[self.periods : self.periods + n] = 0.5 * (
            rows[:, ms.M_SMAX] - rows[:, ms.M_SMIN]
        )
        if self.first_measured < 0 and rows[-1, ms.M_MEASURED] != 0.0:
            self.first_measured = self.periods + int(np.argmax(rows[:, ms.M_MEASURED] != 0.0))
        self.periods += n
        self.all_measured &= bool(_fold_rows(rows, self.cur, self.count))
        self.count += n
        if self.count >= self.window:
            self._close()

    def _close(self) -> None:
        c = self.cur
        self.impacts.append((c[ms.M_IMP1], c[ms.M_IMP2]))
        self.peak.append(c[ms.M_PEAK])
        self.harm.append(c[ms.M_S_RE : ms.M_VB + 1].copy())
        self.measured.append(self.all_measured)
        self.last_impact.append(c[ms.M_LAST_IMPACT])
        self._open()

    def __len__(self) -> int:
        return len(self.impacts)

    @property
    def first(self) -> int:
        """The first period the statistics use: the first measured one (its extrema exact,
        where unmeasured periods have those of an interpolant), or the first of all while
        fewer than two periods are measured."""
        f = self.first_measured
        return f if 0 <= f <= self.periods - 2 else 0

    def stats(self) -> SeriesStats:
        """:func:`series_stats` of the half-ranges of the periods from :attr:`first` on."""
        span = (self.first, self.periods)
        if self._stats is None or self._stats[0] != span:
            self._stats = (span, series_stats(self.half_range[span[0] : span[1]]))
        return self._stats[1]


def _db(amplitude: float, base_scale: float) -> float:
    """Γ of a mean half-range (-inf for none)."""
    return 20.0 * math.log10(amplitude / base_scale) if amplitude > 0.0 else -math.inf


def _se_db(st: SeriesStats) -> float | None:
    """The standard error of Γ = 20 log10(mean/θγ_s) (dB), to first order."""
    if st.se is None or not st.mean > 0.0:
        return None
    return 20.0 / math.log(10.0) * st.se / st.mean


# --------------------------------------------------------------------------- the engine


@dataclass
class _Orbit:
    x0: np.ndarray  # the state at the orbit's start (forcing phase 0)
    rows: np.ndarray  # p rows measured from x0
    p: int
    multiplier: float | None


@dataclass
class _Pending:
    # confirmed, but its attraction not proven: the map is not smooth there, or the
    # trajectory's samples do not (yet) follow its linearized map (_follows)
    orbit: _Orbit
    found_at: float  # the trajectory's distance to it when it was confirmed
    # what is reported as its multiplier once the trajectory has reached it: the one that
    # found it attracting, or the exact matrix's spectral radius where that exists but did not
    # decide (an orbit that starts stuck on a stop); None: no Jacobian
    multiplier: float | None = None
    # the q-period map's matrix at the orbit's start where the multiplier came from one: the
    # orbit is also reached once the trajectory's returns follow it
    matrix: np.ndarray | None = None
    frame: tuple[float, tuple | None] | None = None  # eigen_frame(matrix), once needed

    def eigen(self) -> tuple[float, tuple | None]:
        """The matrix's :func:`eigen_frame`, computed once."""
        if self.frame is None:
            self.frame = eigen_frame(self.matrix)
        return self.frame

    def eigen_power(self, k: int) -> tuple[float, tuple | None]:
        """The :func:`eigen_frame` of the matrix's k-th power (the p-period map of a q-periodic
        orbit, k = p/q): the same eigenvectors, the multipliers' moduli and phases to the k-th
        power."""
        rho, turn = self.eigen()
        if turn is None:
            return rho**k, None
        V, W, u = turn
        return rho**k, (V, W, u**k)


class _Engine:
    def __init__(self, run: KernelRun, sys_: System, tail: LinearTail,
                 settings: SolverSettings, limits: PointLimits,
                 cancelled: Callable[[], bool] | None) -> None:  # fmt: skip
        self.run = run
        self.limits = limits
        self.cancelled = cancelled
        self.t0 = time.perf_counter()
        self.stride = settings.window  # periods per batch, shortened when periods are slow
        self.sys = sys_
        self.p = sys_.params
        self.tail = tail
        self.s = settings
        self.nx = run.nx
        w = settings.window
        self.rows = np.zeros((w, ms.ROW))
        self.samples = np.zeros((w, self.nx))
        # Stroboscopic samples, newest last: HISTORY for _shrinking_p, the last RECENT of them
        # (a view: one buffer, shifted once a batch) for extrapolation and the other tests
        self.history = np.zeros((HISTORY, self.nx))
        self.nhistory = 0
        self.recent = self.history[HISTORY - RECENT :]
        self.recent_imp = np.zeros(RECENT)  # impacts in each of those periods
        self.recent_reg = np.zeros(RECENT)
        self.nrecent = 0
        self.windows = _Windows(w)
        self.period = 0  # periods of the main trajectory
        # set with an irregular claim: the impact-free response is admissible too (_irregular)
        self.may_be_transient = False
        self.work = dict(periods=0, steps=0, contact_steps=0, coarse_steps=0)
        self.checks = (
            (ms.CHECK_LINEAR if run.lin_gate > 0.0 and settings.linear_tail else 0)
            | ms.CHECK_PERIODIC
            | (ms.CHECK_CANDIDATE if settings.extrapolate else 0)
            | (ms.CHECK_QUIET if tail.usable and settings.linear_tail else 0)
        ) if settings.early_stop else 0  # fmt: skip
        self.quiet_backoff = 1
        self.hold_periodic = 0  # no periodicity signal before this period (_unstable)
        self.passed_unstable: _Orbit | None = None  # the last such orbit (the reason names it)
        self.backoff = 4
        # The stroboscopic states (q, nx) of every orbit checked for attraction: found
        # unstable, or pending. Not tried again: a later fit may land on any of its q states.
        self.tried: list[np.ndarray] = []
        # Orbits confirmed where the map is not smooth (no Jacobian, so attraction is not
        # proven): reported only once the trajectory itself reaches one (_reached)
        self.pending: list[_Pending] = []
        # Both gaps zero: the tip is pinned for good and the motion is linear (constrained)
        self.pinned_re = pinned_max_re(sys_) if self.p.g1 == 0.0 and self.p.g2 == 0.0 else None

    # ------------------------------------------------------------------ bookkeeping

    def _absorb(self, rows: np.ndarray, samples: np.ndarray, main: bool) -> None:
        n = len(rows)
        steps, contact, coarse = _work_sums(rows)
        self.work["periods"] += n
        self.work["steps"] += int(steps)
        self.work["contact_steps"] += int(contact)
        self.work["coarse_steps"] += int(coarse)
        if not main or n == 0:
            return
        self.windows.add(rows)
        _push_samples(self.history, samples)
        self.nhistory = min(HISTORY, self.nhistory + n)
        _push_recent(self.recent_imp, self.recent_reg, rows)
        self.nrecent = min(RECENT, self.nrecent + n)
        self.period += n

    def _side_run(self, x0: np.ndarray, n: int, measure: bool = True,
                  exact: bool = False,
                  ) -> tuple[np.ndarray, np.ndarray, ExactMonodromy | None] | None:  # fmt: skip
        """Integrate n periods from x0, measured unless told otherwise; with ``exact`` the
        method's exact monodromy matrix of the same run where it has one (else None). Returns
        (rows, samples, matrix), or None if the run stopped (the caller saves/restores the
        run)."""
        rows = np.zeros((n, ms.ROW))
        samples = np.zeros((n, self.nx))
        J, done, code = self.run.run_from(x0, n, measure, exact, rows, samples)
        self._absorb(rows[:done], samples[:done], main=False)
        if code != ms.END_NONE or done < n:
            return None
        return rows, samples, J

    # ------------------------------------------------------------------ the main loop

    def run_to_end(self) -> tuple[str, object]:
        s = self.s
        w = s.window
        # Measured from a window's start (the last MIN_WINDOWS windows before the earliest
        # irregular claim): a window is measured whole or not at all, so what it holds never
        # depends on where a batch starts (batches are cut short by the clock, _pace).
        first = max(2 * w, s.max_periods // 4 - MIN_WINDOWS * w)
        measure_from = -(-first // w) * w
        # The batch an unpaced run would make ends at `goal`, and it has these `checks`. The
        # clock may cut it into shorter batches (_pace); between those only the limits and
        # cancel are looked at, so the work a point reports never depends on the machine's
        # load (were every cut a batch end, a loaded machine would see a pending orbit's reach
        # sooner: audits/batch_cuts.py).
        goal = 0
        while self.period < s.max_periods:
            if self.period >= goal:
                n = min(w - self.period % w, s.max_periods - self.period)
                if self.pending and self._approaching() is not None:
                    n = min(n, PENDING_BATCH)  # seen soon after the trajectory reaches it
                goal = self.period + n
                checks = self.checks
                if self.period < self.hold_periodic:
                    checks &= ~ms.CHECK_PERIODIC
            n = min(goal - self.period, self.stride)
            measure = self.period >= measure_from
            t = time.perf_counter()
            done, code, p = self.run.advance(n, measure, checks, self.rows, self.samples)
            self._pace(done, time.perf_counter() - t)
            self.rows[:done, ms.M_MEASURED] = 1.0 if measure else 0.0
            self._absorb(self.rows[:done], self.samples[:done], main=True)
            if code == ms.END_NONE and self.period < goal:
                over = self._over_budget()  # cut short by the clock: nothing else to look at
                if over:
                    return "failed", over
                continue
            goal = 0  # a batch end: the kernel stopped, or the unpaced batch is done
            reached = self._reached(1.0) if self.pending else None
            if reached is None and code == ms.END_PERIODIC and self.pending:
                # the trajectory repeats by itself: if that is a pending orbit, its extrapolated
                # start is the more accurate one (10×: the slack of the divisor test)
                reached = self._reached(10.0)
            if reached is not None:
                return self._classify_orbit(reached)
            if code == ms.END_LINEAR:
                return self._linear_or_undamped()
            if code == ms.END_QUIET:
                # impacts just stopped: try to prove they never come back
                if self._proves(self.run.x):
                    return self._linear_or_undamped()
                self.run.kst[ms.K_NEXT_QUIET] = self.run.kst[ms.K_PERIOD] + self.quiet_backoff
                self.quiet_backoff = min(2 * self.quiet_backoff, 32)
            elif code == ms.END_PERIODIC and not self._period_proven(p):
                self.hold_periodic = self.period + p  # not yet: look again a return later
            elif code == ms.END_PERIODIC:
                orbit = self._measure_orbit(self.run.x.copy(), p)
                if orbit is not None and not _unstable(orbit):
                    return self._classify_orbit(orbit)
                if orbit is not None:
                    # an unstable orbit, approached along its stable directions: the trajectory
                    # leaves it. Not signalled again while it is near. (The case that showed
                    # it, Figure 5 at θ 0.3, gap 0.7, γ_r 1.18, "period 6, multiplier 1.053",
                    # was a period-3 orbit past its period doubling, which _period_proven now
                    # refuses before measuring. With periodicity_tol 1e-6 its samples repeat
                    # after 3 periods, and the reason names that period-3 orbit.)
                    self.hold_periodic = self.period + UNSTABLE_HOLD * p
                    self.passed_unstable = orbit
            elif code == ms.END_CANDIDATE:
                orbit = self._extrapolate(p)
                if orbit is not None:
                    return self._classify_orbit(orbit)
                # back off: try again after a few more periods of contraction (at most 16:
                # with up to 64 a slowly contracting orbit waited up to 64 periods for its next
                # try; 16 saves ~7 % of the periodic points' periods, same orbits)
                self.run.kst[ms.K_NEXT_TRY] = self.run.kst[ms.K_PERIOD] + self.backoff
                self.backoff = min(2 * self.backoff, 16)
            elif code != ms.END_NONE:
                return "failed", self.run.failure_reason(code)
            over = self._over_budget()
            if over:
                return "failed", over
            if self.period % w == 0 and self.checks and self._irregular_converged():
                return self._irregular()
        return self._at_budget()

    def _pace(self, done: int, dt: float) -> None:
        """Shorten the batches when periods are slow (limits and cancel are seen between
        batches); batches never grow beyond a window, so fast points run as before."""
        if dt > BATCH_S and done > 0:
            self.stride = max(1, int(done * BATCH_S / dt))

    def _over_budget(self) -> str:
        """Why the point must stop now ("" if it may go on); raises on cancel."""
        if self.cancelled is not None and self.cancelled():
            raise PointCancelled(f"cancelled in period {self.period}")
        elapsed = time.perf_counter() - self.t0
        if elapsed > self.limits.wall_s:
            return (f"{OVER_TIME}{self.limits.wall_s:g} s per point exceeded after "
                    f"{self.period} periods ({self.work['steps']} steps)")  # fmt: skip
        if self.work["steps"] > self.limits.steps:
            return (f"{OVER_STEPS}{self.limits.steps} steps per point exceeded after "
                    f"{self.period} periods")  # fmt: skip
        return ""

    # ------------------------------------------------------------------ outcomes

    def _linear_or_undamped(self) -> tuple[str, object]:
        if self.tail.damped:
            return "linear", None
        return "failed", _undamped_reason(self.tail, self.period)

    def _proves(self, x: np.ndarray) -> bool:
        """The linear tail proof from x (when the settings allow it)."""
        T = 2.0 * math.pi / self.p.gamma_r
        return self.s.linear_tail and self.tail.proves(x, TAIL_HORIZON * T)

    def _period_proven(self, p: int) -> bool:
        """A repeat after p periods (the kernel's ``measure.periodicity``) is a period-p state,
        not one still approaching a period-q orbit, q | p (:func:`_divisors_steady`)."""
        tol = self.s.periodicity_tol
        return _divisors_steady(self.history, self.nhistory, p, AMBIGUOUS * tol, tol)

    def _measure_orbit(self, x0: np.ndarray, p: int) -> _Orbit | None:
        """The orbit the trajectory reached by itself (its samples repeat), measured over p
        periods from x0, or from one Newton step closer (:meth:`_polish`). Its multiplier is
        the exact monodromy matrix's spectral radius where the method has one and it is below 1
        (``event``: from the measuring run itself, at no cost); else the finite differences'
        where the map is smooth and they at most triple the point's cost (``CHECK_COST``); the
        exact one at zero gaps; else none: no Jacobian, a check too costly, or early stop off (a
        fixed budget, as the paper's scheme, runs nothing more). No estimate stands in: the
        sequence's contraction d_k/d_{k-p} is off by up to 0.12 at Figure 5's long orbits
        (periods 18-39)."""
        snap = self.run.save()
        try:
            got = self._side_run(x0, p, exact=self.s.early_stop)
            if got is None:
                return None
            if self.s.early_stop and self.s.extrapolate:
                x0, got = self._polish(x0, p, got)
            check = self.s.early_stop and self.nx * p <= CHECK_COST * self.work["periods"]
            lam, _ = self._multiplier(x0, p, got[1][p - 1], _impacts(got[0]), got[2], check)
            if lam is not None and math.isinf(lam):
                return None  # over the point's limits: the main loop fails it
            return _Orbit(x0.copy(), got[0], p, lam)
        finally:
            self.run.restore(snap)

    def _polish(self, x0: np.ndarray, p: int, got: tuple) -> tuple[np.ndarray, tuple]:
        """A reached orbit's start one Newton step on the exact matrix closer to the orbit, where
        that step is longer than ``periodicity_tol``, and its measuring run ``got`` replaced by
        one from there if that repeats better with the same impacts; else both unchanged. The
        periodicity test bounds the distance to the orbit by the sequence's observed
        contraction, which a multiplier near a p-th root of unity hides (Figure 5: 6.7e-9 of the
        state at one of its 44 reached orbits)."""
        rows, samples, J = got
        r = _max_diff(samples[-1], x0)
        # the contraction is not known here (the periodicity test's estimate is what may be
        # fooled): the loosest bound; the run from the new start decides
        step = _newton_step(J, samples[-1] - x0, r, 0.999)
        if step is None or np.max(np.abs(step)) <= self.s.periodicity_tol * np.max(np.abs(x0)):
            return x0, got
        x1 = x0 - step
        again = self._side_run(x1, p, exact=True)
        if again is None or _impacts(again[0]) != _impacts(rows) or \
                _max_diff(again[1][-1], x1) >= r:  # fmt: skip
            return x0, got
        return x1, again

    def _multiplier(self, x0: np.ndarray, q: int, fx0: np.ndarray, impacts: float,
                    exact: ExactMonodromy | None, check: bool = True, decides: bool = False,
                    ) -> tuple[float | None, np.ndarray | None]:  # fmt: skip
        """The dominant Floquet multiplier of the q-periodic orbit through ``x0``: at zero gaps
        the pinned system's exact one, at no cost (:meth:`_pinned_multiplier`; side runs would
        only find a perturbed tip leaving the stops); else the spectral radius of ``exact``,
        the method's exact monodromy matrix of the q-period map from the orbit's own run
        (``event/monodromy.py``), where it is below 1; else, when ``check``, the finite differences'
        (:meth:`_monodromy_radius`: None without a Jacobian, inf over the point's limits);
        else None. Nothing runs with early stop off (a fixed budget, as the paper's scheme).
        A radius of 1 or more is left to the finite differences, which tell an unstable orbit
        from a map that is not smooth (as before the exact matrix).

        ``decides``: the multiplier decides whether an extrapolated orbit is reported now.
        For an orbit that starts stuck on a stop (the matrix at its first release) the finite
        differences still decide, as before that matrix: where they find no Jacobian the
        orbit waits until the trajectory reaches it (which kept a stable orbit beside a
        chaotic trajectory from being reported); where they find it attracting, the exact
        radius is the value.

        Also returns the q-period map's matrix at ``x0`` (τ = 0) the multiplier came from:
        ``exact``'s where its section is τ = 0, else the finite differences' (None: pinned,
        none run, or no Jacobian)."""
        if self.pinned_re is not None:
            return self._pinned_multiplier(q), None
        if not self.s.early_stop:
            return None, None
        radius = _exact_radius(exact)
        if radius is not None and radius < 1.0 and not (decides and exact.shifted):
            return radius, None if exact.shifted else exact.matrix
        lam, J = self._monodromy_radius(x0, q, fx0, impacts) if check else (None, None)
        if radius is not None and radius < 1.0 and lam is not None and lam < 1.0:
            return radius, J
        return lam, J

    def _monodromy_radius(self, x0: np.ndarray, p: int, fx0: np.ndarray, impacts: float,
                          ) -> tuple[float | None, np.ndarray | None]:  # fmt: skip
        """The dominant Floquet multiplier's modulus of the p-periodic orbit through ``x0``
        (``fx0``: the state p periods after it): the spectral radius of the monodromy matrix,
        the p-period map's Jacobian, by forward differences of ``nx`` unmeasured side runs
        (the caller saves/restores the run): for methods without an exact matrix, orbits that
        start leaving a stop (or on one they are not stuck on until a release), and radii of
        1 or more. None where the map is not smooth at ``x0``: a
        perturbed run has other impacts than the orbit (``impacts`` over p periods), or a
        radius of 1 or more is not reproduced with ten times the step (a jump of the map, a
        sticking or grazing contact, makes the differences grow like 1/step); inf when the
        point's limits ran out meanwhile (it then fails with that reason). With it, the
        matrix (None with no radius)."""
        lam, J = self._fd_radius(x0, p, fx0, impacts, FD_STEP)
        if lam is None or lam < 1.0 or math.isinf(lam):
            return lam, J
        again, _ = self._fd_radius(x0, p, fx0, impacts, 10.0 * FD_STEP)
        if again is None or abs(again - lam) > 0.01 * lam:
            return None, None
        return lam, J

    def _fd_radius(self, x0: np.ndarray, p: int, fx0: np.ndarray, impacts: float,
                   step: float) -> tuple[float | None, np.ndarray | None]:  # fmt: skip
        """:meth:`_monodromy_radius` with one relative ``step``, without the jump test."""
        h = step * float(np.max(np.abs(x0)))
        J = np.empty((self.nx, self.nx))
        for i in range(self.nx):
            # nx·p periods can be long (20 modes: 42 side runs): the point's limits and cancel
            # are seen between them; inf rejects the orbit, and the main loop then fails the
            # point with the reason
            if self._over_budget():
                return math.inf, None
            x = x0.copy()
            x[i] += h
            got = self._side_run(x, p, measure=False)
            if got is None:
                return None, None
            rows, samples, _ = got
            if _impacts(rows) != impacts:
                return None, None
            J[:, i] = (samples[-1] - fx0) / h
        ev = np.linalg.eigvals(J)
        return (float(np.max(np.abs(ev))), J) if np.all(np.isfinite(ev)) else (None, None)

    def _tried(self, x: np.ndarray, rel: float) -> bool:
        """Whether ``x`` is within ``rel`` of its size of a state of an orbit already checked
        (rejected as unstable, or waiting for the trajectory to reach it)."""
        near = rel * float(np.max(np.abs(x)))
        return any(_max_diff(u, x) <= near for pts in self.tried for u in pts)

    def _pinned_multiplier(self, q: int) -> float | None:
        """Both gaps zero: the admissible set is ``Wᵀu = 0``, so the tip stays pinned, the
        motion is the constrained linear system's, and when that is damped its one periodic
        response attracts every state, with multiplier ``e^{q·T·max Re λ}`` over q periods
        (the finite differences cannot show it: a perturbed tip leaves the stops). None
        otherwise (undamped, or gaps not zero)."""
        if self.pinned_re is None or self.pinned_re >= 0.0:
            return None
        return math.exp(q * 2.0 * math.pi / self.p.gamma_r * self.pinned_re)

    def _distance(self, o: _Orbit) -> float:
        """How far the trajectory is from orbit ``o`` now (its latest return; inf before it
        has q samples)."""
        back = self._returns(o, 1)
        return back[0] if back else math.inf

    def _returns(self, o: _Orbit, k: int) -> list[float]:
        """The trajectory's distance to orbit ``o`` at its last k returns, newest first (empty
        before it has k·q samples)."""
        X = self._return_states(o, k)
        return [] if X is None else [_max_diff(x, o.x0) for x in X[::-1]]

    def _return_index(self, o: _Orbit, k: int) -> list[int] | None:
        """Where in ``recent`` the trajectory's last k returns to orbit ``o`` are, oldest
        first: the one of its last q samples nearest ``o``'s start, and the samples q, 2q, …
        before it (None before it has k·q samples)."""
        q = o.p
        if self.nrecent < k * q:
            return None
        last = [_max_diff(x, o.x0) for x in self.recent[RECENT - q :]]
        j = RECENT - q + int(np.argmin(last))
        return [j - i * q for i in range(k - 1, -1, -1)]

    def _return_states(self, o: _Orbit, k: int) -> np.ndarray | None:
        """The trajectory's states at its last k returns to orbit ``o``, oldest first (None
        before it has k·q samples)."""
        idx = self._return_index(o, k)
        return None if idx is None else self.recent[idx]

    def _on_branch_within(self, o: _Orbit, radius: float) -> bool:
        """Whether every kept return of the trajectory within ``radius`` of orbit ``o`` came
        over the orbit's branch of the map (its impacts over the q periods before it). A fit of
        the orbit's linearized map (:func:`_follows`) shows an approach only inside a ball where
        that map holds; a return as close with other impacts shows a branch change there (a
        grazing contact), which the fit's samples may have missed by chance (a random cell at
        θ 9.15, 9 modes, full coupling, γ_r 0.818: its period-1 orbit of 7 impacts a period and
        multiplier 0.9967 is circled by the period-7 orbit the trajectory settles on, an 8th,
        grazing impact every few periods; 8 returns in a row without one fit the map to 0.3 %,
        and the orbit, 7e-4 dB off, is not the answer)."""
        q = o.p
        idx = self._return_index(o, self.nrecent // q)
        if idx is None:
            return True
        first = RECENT - self.nrecent  # the oldest kept sample
        at = np.array([i for i in idx if i - q + 1 >= first], dtype=np.int64)
        if at.size == 0:
            return True
        near = np.max(np.abs(self.recent[at] - o.x0), axis=1) <= radius
        return bool(np.all(self._impacts_before(at, q)[near] == _impacts(o.rows[:q])))

    def _impacts_before(self, idx: list[int] | np.ndarray, q: int) -> np.ndarray:
        """The impacts over the q periods before each sample ``idx`` of ``recent`` (whole
        numbers: the differences of their running sum are exact; fewer periods before the
        buffer's first)."""
        cum = np.concatenate(([0.0], np.cumsum(self.recent_imp)))
        i = np.asarray(idx, dtype=np.int64) + 1
        return cum[i] - cum[np.maximum(i - q, 0)]

    def _reached(self, slack: float) -> _Orbit | None:
        """A pending orbit the trajectory has reached: it is on the orbit to
        ``slack·periodicity_tol`` (1: what a sequence that repeats by itself must show), or,
        where its multiplier proves it attracting, it has been ``REACH_SHRINK`` times closer
        than when the orbit was confirmed at its last ``REACH_HOLD`` returns (it is attracted
        there, not passing by), with the pending multiplier. An attracting orbit whose
        linearized map the trajectory did not follow when it was confirmed is also reached
        once its last returns follow it (:func:`_follows`).

        An orbit without a multiplier must be reached to ``periodicity_tol``: at a random cell
        (``orbit_audit.py --random 3000 --seed 5``, θ 3.43, γ_r 0.446) the trajectory came 300
        times closer to a saddle orbit along its stable manifold, 2.3e-6 of the state, and then
        left it for the stable orbit beside it (3.4e-6 dB away) at ~1.025 a period."""
        for pend in self.pending:
            o = pend.orbit
            near = slack * self.s.periodicity_tol * float(np.max(np.abs(o.x0)))
            attracting = pend.multiplier is not None and pend.multiplier < 1.0
            back = self._returns(o, REACH_HOLD) if attracting else None
            if self._distance(o) <= near or (back and max(back) <= pend.found_at / REACH_SHRINK):
                return replace(o, multiplier=pend.multiplier)
            if pend.matrix is not None:
                for k in self._fit_returns(o.p, pend.multiplier):
                    X = self._return_states(o, k)
                    if X is not None and _follows(pend.matrix, X, o.x0, frame=pend.eigen) and (
                        self._on_branch_within(o, _spread(X, o.x0))
                    ):  # fmt: skip
                        return replace(o, multiplier=pend.multiplier)
        return None

    @staticmethod
    def _fit_returns(q: int, lam: float) -> tuple[int, ...]:
        """How many of a q-periodic orbit's last returns chained fits use (multiplier
        ``lam``): MAX_RRE; where the map shrinks deviations less than SLOW_SHRINK over those
        (a multiplier near 1: the motion to be seen is small) also all the buffer holds."""
        short = min(MAX_RRE, RECENT // q)
        if lam ** (MAX_RRE - 1) <= SLOW_SHRINK or short == RECENT // q:
            return (short,)
        return (short, RECENT // q)

    def _approaching(self) -> _Orbit | None:
        """The pending orbit the trajectory is closer to than when it was confirmed, or whose
        linearized map its last returns follow step by step, if any: a response on its way to
        an orbit is not irregular (Figure 5 at θ 0.5, gap 0.1, γ_r 3.8: a period-8 orbit whose
        sequence fitted the map to 0.4 % at its newest steps, but not chained from its oldest
        sample, 60 times farther out)."""
        for pd in self.pending:
            if self._distance(pd.orbit) < pd.found_at:
                return pd.orbit
            if pd.matrix is not None:
                X = self._return_states(pd.orbit, REACH_HOLD + 1)
                if X is not None and _follows(pd.matrix, X, pd.orbit.x0, chained=False):
                    return pd.orbit
        return None

    def _extrapolate(self, p: int) -> _Orbit | None:
        """Extrapolate the p-periodic limit of the sequence, then confirm it by integration."""
        avail = self.nrecent // p
        if avail < 4:
            return None
        # newest first: sample indices p apart; keep those on the newest sample's branch of the
        # map (same impacts over the p periods before it, same contact state at it)
        idx = list(range(RECENT - 1, RECENT - 1 - p * min(avail, MAX_RRE), -p))
        blocks = self._impacts_before(idx, p).tolist()
        regs = [self.recent_reg[i] for i in idx]
        keep = 1
        while keep < len(idx) and blocks[keep] == blocks[0] and regs[keep] == regs[0]:
            keep += 1
        if keep < 3:
            return None
        X = self.recent[idx[:keep][::-1]]
        d1 = _max_diff(X[-1], X[-2])
        fit = rre(X)
        if fit is None or fit[2] > MAX_FIT or fit[1] >= 0.999:
            return None  # the sequence is not (yet) a linear contraction: no side runs
        rho0 = fit[1]
        if self._tried(fit[0], 1e-3):
            return None  # an orbit already checked (any candidate p): no side runs
        snap = self.run.save()
        try:
            r_prev = math.inf
            for _ in range(MAX_CYCLES):
                if fit is None:
                    return None
                xs, rho, _ = fit
                rho = min(max(rho, rho0), 0.999)
                if not np.all(np.isfinite(xs)):
                    return None
                # confirmed by a measured run (measuring changes no state, to the bit: the run
                # that confirms is the orbit's measurement, one run less than confirming
                # unmeasured and measuring again), with the method's exact matrix of the
                # p-period map where it has one (the Newton step below)
                got = self._side_run(xs, p, exact=True)
                if got is None:
                    return None
                rows, samples, J = got
                scale = float(np.max(np.abs(xs)))
                r = _max_diff(samples[-1], xs)
                if _impacts(rows) != blocks[0]:
                    return None  # another branch of the map: not the orbit being approached
                # how far the orbit may be: what the residual and the sequence's contraction
                # allow, and Newton's next step where there is one (it sees a slow mode of the
                # map that the sequence's Ritz values miss)
                step = _newton_step(J, samples[-1] - xs, r, rho)
                far = r / (1.0 - rho)
                if step is not None:
                    far = max(far, float(np.max(np.abs(step))))
                if far <= self.s.periodicity_tol * scale:
                    e = _max_diff(X[-1], xs)
                    # where the trajectory's own contraction is heading (10× slack)
                    if e <= 10.0 * d1 / (1.0 - rho) + self.s.periodicity_tol * scale:
                        # a p-periodic fixed point may be q-periodic, q | p
                        q = next(q for q in range(1, p + 1) if p % q == 0 and (
                            q == p or _max_diff(samples[q - 1], xs)
                            <= 10.0 * self.s.periodicity_tol * scale))  # fmt: skip
                        # The confirming run is the orbit's measurement (rows, samples, J).
                        # Only an attracting orbit can be the one the trajectory approaches:
                        # extrapolation also converges to unstable fixed points (a period-1
                        # orbit past its period doubling), and the Ritz values of a short
                        # sequence miss the slowest mode (0.41 where the map has 0.64) or
                        # add spurious ones (above 1 where it has 0.55). Where the map is not
                        # smooth (None: sticking, grazing, jumps; undamped zero gaps) attraction
                        # is not proven: the orbit waits until the trajectory reaches it (a
                        # confirmation alone proves no attraction).
                        if self._tried(xs, 1e-6):
                            return None  # checked already, from another candidate p
                        if q < p:  # the q-period map's own matrix: one run of q periods
                            qrun = self._side_run(xs, q, measure=False, exact=True)
                            J = None if qrun is None else qrun[2]
                        lam, M = self._multiplier(xs, q, samples[q - 1], _impacts(rows[:q]),
                                                  J, decides=True)  # fmt: skip
                        orbit = _Orbit(xs.copy(), rows, q, lam)
                        # An attracting orbit is the one the trajectory approaches only if
                        # its samples follow the orbit's linearized map:
                        # a stable orbit may be circled by another orbit or by chaos that
                        # never reaches it, and a slowly contracting sequence cannot tell.
                        # (M is None only at zero gaps, where every state is attracted.)
                        attracting = lam is not None and lam < 1.0
                        # the q-period map's eigenvectors, computed at most once: for the
                        # fit of the p-period map here and, if it waits, the pending orbit's
                        pend = _Pending(orbit, 0.0, lam, None if M is None else M.copy())
                        if attracting and (M is None or (
                            _follows(np.linalg.matrix_power(M, p // q), X, xs,
                                     frame=functools.partial(pend.eigen_power, p // q))
                            and self._on_branch_within(orbit, _spread(X, xs))
                        )):  # fmt: skip
                            return orbit
                        # unstable, or its attraction not proven: not checked again
                        self.tried.append(samples[:q].copy())
                        if attracting and M is not None:
                            pend.found_at = self._distance(orbit)
                            self.pending.append(pend)
                        elif lam is None:
                            radius = _exact_radius(J)
                            self.pending.append(_Pending(
                                orbit, self._distance(orbit),
                                radius if radius is not None and radius < 1.0 else None,
                            ))  # fmt: skip
                        return None
                    return None
                if r > 0.5 * r_prev:
                    return None  # the cycles stopped converging
                r_prev = r
                if step is not None:
                    fit = (xs - step, rho, 0.0)
                    continue
                # no usable matrix: continue the sequence from x* (one unmeasured run, sampled
                # every p periods) and extrapolate again
                more = len(X) - 2
                got = self._side_run(samples[-1], more * p, measure=False)
                if got is None:
                    return None
                fit = rre(np.vstack([xs, samples[-1], got[1][p - 1 :: p]]))
            return None
        finally:
            self.run.restore(snap)

    def _classify_orbit(self, orbit: _Orbit) -> tuple[str, object]:
        rows = orbit.rows
        if _impacts(rows) == 0 and self._proves(orbit.x0):
            return self._linear_or_undamped()
        return "periodic", orbit

    def _irregular_converged(self) -> bool:
        win = self.windows
        # Transient chaos can look stationary for hundreds of periods before it settles on an
        # orbit: an irregular response is claimed only after a quarter of the budget.
        if not len(win) or self.period < self.s.max_periods // 4:
            return False
        guard = self.s.transient_guard
        if guard is not None and self.period < guard and self._linear_admissible():
            return False  # the user's longer guard, where the chaos may die out
        if not self._impacts_continue():
            return False
        return self._stats_converged()

    def _stats_converged(self, final: bool = False) -> bool:
        """Enough stationary periods, no trend, a standard error within the tolerance, and the
        stroboscopic sequence not converging to an orbit; before the budget's end also batch
        means that decorrelated and halves that agree (a longer run may mend those)."""
        st = self.windows.stats()
        se = _se_db(st)
        return (se is not None and st.n >= self._min_stationary() and se <= self.s.stat_tol_db
                and st.trend <= MAX_TREND and (final or st.steady)
                and self._converging() == 0 and self._approaching() is None)  # fmt: skip

    def _min_stationary(self) -> int:
        """Stationary periods an irregular claim needs: ``MIN_STATIONARY``, or a quarter of a
        budget too short for that."""
        return min(MIN_STATIONARY, self.s.max_periods // 4)

    def _distrust(self, st: SeriesStats) -> str:
        """Why the standard error of these statistics cannot be trusted ("" if it can): the
        transient cut lies past the middle of the record, the batch means never decorrelated
        (a modulation slower than a tenth of the span), the values nearly repeat (an almost
        periodic response), the halves disagree (intermittency), or the cell is undamped
        (energy leaves only at impacts: the motion may change its character over far longer
        spans than any run; docs/accuracy.md)."""
        if not st.warmed_up:
            return (f"the initial transient takes more than half of the {st.start + st.n} "
                    "periods measured (the MSER rule): the record may be too short")  # fmt: skip
        if not st.decorrelated:
            return (f"its per-period amplitudes are still correlated over batches of {st.batch} "
                    f"periods ({st.batches} batches): a slow modulation (almost periodic or "
                    "intermittent)")  # fmt: skip
        if st.closeness < ALMOST_PERIODIC:
            return (f"its per-period amplitudes nearly repeat every {st.repeat} periods (their "
                    f"differences {st.closeness:.2g} of those of independent values): an almost "
                    "periodic response, whose slow changes its record may not show")  # fmt: skip
        if st.halves > MAX_HALVES:
            return (f"the two halves of its {st.n} stationary periods differ by {st.halves:.3g} "
                    "standard errors: an intermittent response")  # fmt: skip
        if not self.tail.damped:
            return ("the cell is undamped: energy leaves it only at impacts, and its motion may "
                    "change its character over far longer spans than this run")  # fmt: skip
        return ""

    def _converging(self) -> int:
        """The smallest p whose p-spaced differences of the stroboscopic samples have shrunk a
        hundredfold over the last half of the samples kept, or are already within 1e-6 of the
        state: the response is approaching (or is) a period-p orbit, not irregular (0: none).
        Every p the samples kept hold twice over (p ≤ 31): a slowly contracting period-17 orbit
        was claimed irregular while p ≤ 8 was watched. Or, over a longer history, the smallest
        p (≤ 40) whose differences shrank steadily (:func:`_shrinking_p`): a
        period-13 orbit of multiplier 0.62 shrank them 130-fold over its last 10 returns, but
        only 80-fold over 128 periods, and was claimed irregular at 260 periods."""
        if self.nrecent < RECENT:
            return 0
        p = int(_converging_p(self.recent, min(ms.MAX_PERIOD, RECENT // 2 - 1)))
        p = p or int(_shrinking_p(self.history, self.nhistory, ms.MAX_PERIOD))
        return p or int(_creeping_p(self.history, self.nhistory, ms.MAX_PERIOD))

    def _linear_admissible(self) -> bool:
        """Whether the impact-free steady state is admissible too (damped, and its tip clear
        of the stops): irregular motion here may be transient chaos that dies out into it."""
        tail = self.tail
        return tail.steady is not None and tail.damped and tail.amp < tail.gate

    def _irregular(self) -> tuple[str, str]:
        """Claim an irregular response. Its reason says where its standard error cannot be
        trusted (``UNTRUSTED_NOTE``); where the impact-free steady state is admissible too, the
        motion may be transient chaos that a longer run would see die out: the claim is flagged
        (``may_be_transient``) and its reason says so."""
        self.may_be_transient = self._linear_admissible()
        ss = self.tail.steady
        why = self._distrust(self.windows.stats())
        parts = [f"{UNTRUSTED_NOTE}: {why}" if why else ""]
        if ss is not None and self.may_be_transient:
            parts.append(
                f"the impact-free response (Γ = {ss.transmittance_db:.4g} dB) is admissible "
                f"here too: {TRANSIENT_NOTE}"
            )
        return "irregular", "; ".join(x for x in parts if x)

    def _impacts_continue(self) -> bool:
        win = self.windows
        return sum(win.impacts[-1]) > 0 and win.last_impact[-1] >= 0.75 * win.window

    def _at_budget(self) -> tuple[str, object]:
        """The budget ran out (or early stop was off): classify what the run shows."""
        run = self.run
        x = run.x.copy()
        if self._proves(x):
            return self._linear_or_undamped()
        n = min(self.nrecent, ms.RING)
        if n >= 3:
            ring = np.zeros((ms.RING, self.nx))
            last = self.period
            for j in range(n):
                ring[(last - j) % ms.RING] = self.recent[RECENT - 1 - j]
            p = ms.periodicity(ring, n, last, x, self.s.periodicity_tol, self.nx)
            if p > 0 and self._period_proven(p):
                orbit = self._measure_orbit(x, p)
                if orbit is not None and not _unstable(orbit):
                    return self._classify_orbit(orbit)
        if self.tail.steady is None and self.windows.impacts and sum(self.windows.impacts[-1]) == 0:
            return "failed", (
                f"no steady state: undamped resonance (γ_r = {self.p.gamma_r:g} on a natural "
                f"frequency with ξ = ξ_b = 0): the response grows without bound and no impact "
                f"limited it within {self.period} periods"
            )
        if len(self.windows) and self._impacts_continue() and self._stats_converged(final=True):
            return self._irregular()
        return "unsettled", self._unsettled_reason()

    def _unsettled_reason(self) -> str:
        win = self.windows
        what = f"the budget of {self.s.max_periods} periods ran out"
        near = self._approaching()
        if near is not None:
            return what + (f" before the trajectory reached the period-{near.p} orbit extrapolated "
                           "from it, which is reported only once reached: its attraction from "
                           "here is not proven (the period map is not smooth there, or the "
                           "trajectory does not follow its linearization)")  # fmt: skip
        if not len(win):
            return what + " before a whole window was measured"
        if sum(win.impacts[-1]) == 0:
            return what + ": no impacts in the final window, but the linear tail is not proven"
        if not self._impacts_continue():
            return what + ": impacts stopped inside the final window (a transient)"
        st = win.stats()
        se = _se_db(st)
        if se is None or st.n < self._min_stationary():
            return what + f" with {st.n} stationary periods (< {self._min_stationary()})"
        if st.trend > MAX_TREND:
            return what + f": Γ still drifts (trend t = {st.trend:.3g}): a slow transient"
        p = self._converging()
        p = _own_period(self.history, self.nhistory, p) if p else 0
        u = self.passed_unstable
        if p and u is not None and p % u.p == 0:
            return what + (f" while the response was near an unstable period-{u.p} orbit "
                           f"(multiplier {u.multiplier:.4g}), which it leaves")  # fmt: skip
        if p:
            return what + f" while the response was still converging to a period-{p} orbit"
        tol = self.s.stat_tol_db
        need = budget_for_error(se, tol, st.n, win.periods - st.n)  # the span ends now
        return what + (f": standard error of Γ {se:.3g} dB > {tol:g} dB (it falls as "
                       f"1/√periods: about {need:,} periods would reach it; raise "
                       "max_periods)")  # fmt: skip


# --------------------------------------------------------------------------- results


def _undamped_reason(tail: LinearTail, period: int) -> str:
    return (
        f"no steady state: the cell is undamped (largest Re λ = {tail.max_re:.3g}) and from "
        f"period {period} on the tip provably never reaches a stop, so its free vibration "
        "never decays"
    )


def _finite_or_none(v: float | None) -> float | None:
    return v if v is not None and math.isfinite(v) else None


def linear_reference_db(steady: SteadyState | None) -> float | None:
    """Γ_lin: the closed-form transmittance of the cell without stops, or ``None`` where there
    is none (an undamped resonance, or no forcing: a zero amplitude has no dB value)."""
    if steady is None:
        return None
    amp = steady.amplitude
    if not (math.isfinite(amp) and amp > 0.0):
        return None
    return _finite_or_none(steady.transmittance_db)


def _with_reference(res: PointResult, tail: LinearTail) -> PointResult:
    """``res`` with Γ_lin and the impact effect Γ − Γ_lin filled in."""
    lin = linear_reference_db(tail.steady)
    res.transmittance_linear_db = lin
    if lin is None or res.transmittance_db is None:
        res.impact_effect_db = None
    elif res.outcome == "linear":
        res.impact_effect_db = 0.0  # Γ is the closed form itself: exactly no effect
    else:
        res.impact_effect_db = _finite_or_none(res.transmittance_db - lin)
    return res


def _overflowed(run: KernelRun) -> bool:
    """Whether the run's history buffer dropped rows (more than it was sized for)."""
    return int(run.kst[ms.K_HIST]) > run.hist.shape[0]


def _rerun(run: KernelRun, start: np.ndarray, periods: int, cap: int) -> None:
    """Run ``periods`` periods from ``start`` again (unmeasured), keeping the last ``cap``
    history rows (0: none)."""
    run.reset(start)
    run.keep_history(cap)
    if periods > 0:
        run.advance(periods, False, 0, np.zeros((periods, ms.ROW)), np.zeros((periods, run.nx)))


def _record_history(run: KernelRun, start: np.ndarray, periods: int) -> None:
    """Record the history of ``periods`` periods from ``start``, whole: the buffer is sized
    for the steps and up to ``history_rows_per_period`` events a period, and a chattering
    orbit has more, so an overflow is run again with room for every row it wrote."""
    cap = periods * run.history_rows_per_period()
    while True:
        _rerun(run, start, periods, cap)
        if not _overflowed(run):
            return
        cap = int(run.kst[ms.K_HIST])


def run_point(make_run: Callable[[], KernelRun], sys_: System, tail: LinearTail,
              settings: SolverSettings, x0: np.ndarray, history_periods: int = 0,
              limits: PointLimits | None = None,
              cancelled: Callable[[], bool] | None = None) -> PointResult:  # fmt: skip
    """Run one point to its proven end and build its result (see the module docstring).

    ``make_run`` prepares the method's kernel run; it is not called for a point whose start is
    already proven to be in the linear tail (unless a history is asked for). ``limits`` bound
    the point's cost; ``cancelled()`` true makes it raise :class:`PointCancelled`."""
    t0 = time.perf_counter()
    p = sys_.params
    T = 2.0 * math.pi / p.gamma_r
    run: KernelRun | None = None
    eng: _Engine | None = None
    if settings.early_stop and settings.linear_tail and tail.proves(x0, TAIL_HORIZON * T):
        # the start is already in the linear tail: nothing to simulate
        outcome, info = ("linear", None) if tail.damped else ("failed", _undamped_reason(tail, 0))
        work = dict(periods=0, steps=0, contact_steps=0, coarse_steps=0)
        steady_period = 0
    else:
        run = make_run()
        run.reset(x0)
        eng = _Engine(run, sys_, tail, settings, limits or PointLimits(), cancelled)
        if history_periods and not settings.early_stop:
            run.keep_history(history_periods * run.history_rows_per_period())
        outcome, info = eng.run_to_end()
        work = eng.work
        steady_period = eng.period
    common = dict(
        periods=work["periods"], steps=work["steps"], contact_steps=work["contact_steps"],
        coarse_steps=work["coarse_steps"], steady_period=steady_period,
        steps_per_period=run.spp if run is not None else 0,
    )  # fmt: skip
    kappa, theta = sys_.kappa, p.theta
    history_start: np.ndarray | None = None
    if outcome == "failed":
        res = PointResult.failure(settings.method, str(info), **common)
    elif outcome == "linear":
        ss = tail.steady
        assert ss is not None
        res = PointResult(
            outcome="linear", transmittance_db=ss.transmittance_db, transmittance_db_se=None,
            amplitude=ss.amplitude, theta_eff=ss.theta_eff, theta_eff_slope=ss.theta_eff,
            response_period=1, impacts_per_period=(0.0, 0.0), peak_impulse=0.0,
            floquet_multiplier=math.exp(tail.max_re * T), wall_s=0.0, reason="",
            method=settings.method, **common,
        )  # fmt: skip
        history_start = tail.xp0
    elif outcome == "periodic":
        orbit: _Orbit = info  # type: ignore[assignment]
        rows = orbit.rows
        amp = 0.5 * (rows[:, ms.M_SMAX].max() - rows[:, ms.M_SMIN].min())
        h = rows[:, ms.M_S_RE : ms.M_VB + 1].sum(axis=0)
        res = PointResult(
            outcome="periodic",
            transmittance_db=transmittance_db(amp, p.base_scale) if amp > 0 else None,
            transmittance_db_se=None, amplitude=float(amp),
            theta_eff=theta_eff_harmonic(complex(h[0], h[1]), complex(h[2], h[3]), kappa, theta),
            theta_eff_slope=theta_eff_slope(h[4], h[5], kappa, theta),
            response_period=orbit.p,
            impacts_per_period=(float(rows[:, ms.M_IMP1].sum() / len(rows)),
                                float(rows[:, ms.M_IMP2].sum() / len(rows))),
            peak_impulse=float(rows[:, ms.M_PEAK].max()),
            floquet_multiplier=_finite_or_none(orbit.multiplier), wall_s=0.0, reason="",
            method=settings.method, **common,
        )  # fmt: skip
        if res.transmittance_db is None:
            res = PointResult.failure(settings.method, "no motion of the outer mass", **common)
        history_start = orbit.x0
    else:
        assert eng is not None and run is not None
        res = _statistics_result(eng, outcome, str(info or ""), common, kappa, theta)
        if res.outcome == "irregular" and eng.may_be_transient:
            res.may_be_transient = True
            res.impacting_periods = eng.period
        history_start = run.x.copy()
    # the state a sweep line hands on: a period boundary of the reported response (the
    # history, when asked for, starts there too)
    if history_start is not None and not res.failed:
        res.final_state = np.array(history_start, dtype=float)
    offset = 0.0  # a history re-run from a later period end: its start on the main run's clock
    if history_periods and outcome != "failed" and settings.early_stop:
        if run is None:
            run = make_run()
        _record_history(run, history_start, history_periods)
    elif history_periods and run is not None and eng is not None and _overflowed(run):
        # early stop off: the main run recorded its last periods, but with more events than
        # budgeted the oldest rows dropped out. Run them again from their first period end:
        # a kept sample, or for a history longer than the HISTORY - 1 samples kept, the state
        # the trajectory had there, reached again from the start (not for a failed point: it
        # may have run out of its limits, and its history stays cut).
        back = min(history_periods, eng.period)
        start = None
        if eng.nhistory > back:
            start = eng.history[-1 - back].copy()
        elif outcome != "failed":
            _rerun(run, x0, eng.period - back, 0)
            start = run.x.copy()
        if start is not None:
            _record_history(run, start, back)
            offset = (eng.period - back) * T
    if history_periods and run is not None:
        res.history = run.history(p, kappa)
        res.history["tau"] = res.history["tau"] + offset
    _with_reference(res, tail)
    res.wall_s = time.perf_counter() - t0
    return res


def _statistics_result(eng: _Engine, outcome: str, reason: str, common: dict,
                       kappa: float, theta: float) -> PointResult:  # fmt: skip
    """Γ, its standard error and the rest from the per-period statistics (irregular,
    unsettled)."""
    win = eng.windows
    p = eng.p
    if not len(win):
        return PointResult.failure(eng.s.method, reason or "no window measured", **common)
    st = win.stats()
    db = _db(st.mean, p.base_scale)
    if not math.isfinite(db):
        return PointResult.failure(eng.s.method, "no motion of the outer mass", **common)
    # the windows that lie in the stationary span, whole (θ_eff, the peak impulse)
    span = range(min(-(-(win.first + st.start) // win.window), len(win) - 1), len(win))
    h = sum((win.harm[i] for i in span if win.measured[i]), np.zeros(6))
    imp = win.impacts[-1]
    return PointResult(
        outcome=outcome, transmittance_db=db, transmittance_db_se=_finite_or_none(_se_db(st)),
        amplitude=st.mean,
        theta_eff=theta_eff_harmonic(complex(h[0], h[1]), complex(h[2], h[3]), kappa, theta),
        theta_eff_slope=theta_eff_slope(h[4], h[5], kappa, theta),
        response_period=0,
        impacts_per_period=(float(imp[0] / win.window), float(imp[1] / win.window)),
        peak_impulse=float(max(win.peak[i] for i in span)), floquet_multiplier=None,
        wall_s=0.0, reason=reason, method=eng.s.method, **common,
    )  # fmt: skip
