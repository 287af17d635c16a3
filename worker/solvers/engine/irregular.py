"""Irregular statistics: the mean of the per-period half-ranges, its error bar, and when a
claim may rest on them (docs/solvers.md, "Irregular points"; docs/accuracy.md).

:func:`series_stats` cuts the initial transient (MSER), takes batch means until they
decorrelate and widens the standard error for the correlation left and the few batches it may
rest on. :class:`_Windows` aggregates the period rows per window. :class:`IrregularClaims`
decides when the engine may claim ``irregular`` and why an error bar cannot be trusted.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from worker.solvers import measure as ms
from worker.solvers.engine import config as cfg
from worker.solvers.settings import TRANSIENT_NOTE

# Part of an irregular point's reason where its standard error cannot be trusted
# (``IrregularClaims._distrust``); ``TRANSIENT_NOTE`` where the motion may be transient.
UNTRUSTED_NOTE = "its standard error cannot be trusted"


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


def mser_start(y: np.ndarray, batch: int = cfg.MSER_BATCH) -> int:
    """The end of the initial transient of ``y`` by the MSER rule (White's marginal standard
    error rule): over batches of ``batch`` values, the start ``d`` minimising
    ``Var(y[d:]) / len(y[d:])``, leaving at least ``MSER_KEEP`` batches; a multiple of
    ``batch``. A start past the middle says the record is too short for its transient."""
    return int(_mser_start(np.ascontiguousarray(y, dtype=np.float64), batch, cfg.MSER_KEEP))


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
    warmed_up: bool  # the transient cut lies in the first half (else the record is too short)
    repeat: int  # the lag (≤ measure.MAX_PERIOD) at which the values come closest to repeating
    closeness: float  # how close (:func:`_repeat`): below ALMOST_PERIODIC, almost periodic

    @property
    def steady(self) -> bool:
        """Whether a longer record has nothing to mend: the transient is cut in the first half
        and the batch means decorrelated."""
        return self.warmed_up and self.decorrelated


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
    squares slope over its standard error (widened for the correlation left): a slow transient
    has a large trend. (An intermittent response shows as batch means that stay correlated.)
    """
    y = np.ascontiguousarray(y, dtype=np.float64)
    if len(y) == 0:
        return SeriesStats(math.nan, None, 0, 0, 1, 0, False, 0.0, False, 0, 1.0)
    d = mser_start(y)
    z = y[d:]
    m = len(z)
    mean = float(z.mean())
    if m < 2:
        return SeriesStats(mean, None, d, m, 1, m, False, 0.0, 2 * d <= len(y), 0, 1.0)
    b, r1, decorrelated = _batch_size(z, cfg.DECORRELATED, cfg.MIN_BATCHES, ms.MAX_PERIOD)
    k = m // b
    means = z[m - k * b :].reshape(k, b).mean(axis=1)
    dev = means - means.mean()
    ss = float(dev @ dev)
    r1 = min(max(r1, 0.0), 0.95)
    inflate = math.sqrt((1.0 + r1) / (1.0 - r1))
    sd = math.sqrt(ss / (k - 1))
    se = sd / math.sqrt(k) * inflate * few_batches_factor(k)
    trend = 0.0
    if k >= 3:
        i = np.arange(k) - (k - 1) / 2.0
        slope = float(i @ dev) / float(i @ i)
        resid = dev - slope * i
        s_res = math.sqrt(float(resid @ resid) / (k - 2))
        se_slope = s_res / math.sqrt(float(i @ i)) * inflate
        trend = abs(slope) / se_slope if se_slope > 0.0 else (math.inf if slope else 0.0)
    q, closeness = _repeat(z, ms.MAX_PERIOD)
    return SeriesStats(mean, se, d, m, b, k, decorrelated, trend, 2 * d <= len(y), q,
                       closeness)  # fmt: skip


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
        for j in range(ms.M_CT1, ms.M_EN2 + 1):
            cur[j] += rows[i, j]
        if rows[i, ms.M_LAST_IMPACT] >= 0.0:
            cur[ms.M_LAST_IMPACT] = count + i + rows[i, ms.M_LAST_IMPACT]
        measured = measured and rows[i, ms.M_MEASURED] != 0.0
    return measured


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
    # time on stop 1 and 2, approach velocities summed at stop 1 and 2, the impacts' energy
    # at stop 1 and 2
    contact: list[np.ndarray] = field(default_factory=list)
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
        self.contact.append(c[ms.M_CT1 : ms.M_EN2 + 1].copy())
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


class IrregularClaims:
    """When the engine may claim an irregular response, and what its reason says (a mixin of
    ``loop._Engine``, whose ``windows``, ``tail`` and settings ``s`` it reads)."""

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
        means that decorrelated (a longer run may mend that)."""
        st = self.windows.stats()
        se = _se_db(st)
        return (se is not None and st.n >= self._min_stationary() and se <= self.s.stat_tol_db
                and st.trend <= cfg.MAX_TREND and (final or st.steady)
                and self._converging() == 0 and self._approaching() is None)  # fmt: skip

    def _min_stationary(self) -> int:
        """Stationary periods an irregular claim needs: ``MIN_STATIONARY``, or a quarter of a
        budget too short for that."""
        return min(cfg.MIN_STATIONARY, self.s.max_periods // 4)

    def _distrust(self, st: SeriesStats) -> str:
        """Why the standard error of these statistics cannot be trusted ("" if it can): the
        transient cut lies past the middle of the record, the batch means never decorrelated
        (a modulation slower than a tenth of the span), the values nearly repeat (an almost
        periodic response), or the cell is undamped
        (energy leaves only at impacts: the motion may change its character over far longer
        spans than any run; docs/accuracy.md)."""
        if not st.warmed_up:
            return (f"the initial transient takes more than half of the {st.start + st.n} "
                    "periods measured (the MSER rule): the record may be too short")  # fmt: skip
        if not st.decorrelated:
            return (f"its per-period amplitudes are still correlated over batches of {st.batch} "
                    f"periods ({st.batches} batches): a slow modulation (almost periodic or "
                    "intermittent)")  # fmt: skip
        if st.closeness < cfg.ALMOST_PERIODIC:
            return (f"its per-period amplitudes nearly repeat every {st.repeat} periods (their "
                    f"differences {st.closeness:.2g} of those of independent values): an almost "
                    "periodic response, whose slow changes its record may not show")  # fmt: skip
        if not self.tail.damped:
            return ("the cell is undamped: energy leaves it only at impacts, and its motion may "
                    "change its character over far longer spans than this run")  # fmt: skip
        return ""

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
