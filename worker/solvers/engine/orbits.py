"""Orbit search and proof: how a point is shown to end on a periodic orbit (docs/solvers.md).

Two ways in. A stroboscopic sequence that repeats by itself (``measure.periodicity``) is a
period-p state once :func:`_divisors_steady` shows it is not still approaching a shorter
period; the orbit is measured over p periods (:meth:`OrbitSearch._measure_orbit`). A sequence
that converges geometrically (``measure.candidate``) is extrapolated (:func:`rre`, with Newton
steps on an exact monodromy matrix) and confirmed by integration
(:meth:`OrbitSearch._extrapolate`); such an orbit is reported only where it attracts and the
trajectory's samples follow its linearized map (:func:`_follows`), else it waits as a pending
orbit until the trajectory reaches it (:meth:`OrbitSearch._reached`).

Also here: the tests that say the response is still approaching some orbit (so not irregular):
:func:`_converging_p`, :func:`_shrinking_p`, :func:`_creeping_p`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from worker.solvers import measure as ms
from worker.solvers.base import ExactMonodromy
from worker.solvers.engine import config as cfg


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


@njit(cache=True, nogil=True)
def _shrinking(history: np.ndarray, n: int, max_period: int, returns: int, factor: float) -> int:
    """The smallest p whose p-spaced differences of the newest-last samples (the last ``n`` of
    ``history`` valid) shrank at each of the last SHRINK_RETURNS returns and SHRINK_FACTOR-fold
    over them: the response converges steadily to a period-p orbit (0: none). Chaos shrinks
    seven differences in a row by chance about once in 5,040 tries of one p."""
    last = history.shape[0] - 1
    for p in range(1, max_period + 1):
        if (returns + 1) * p >= n:
            break
        newest = _max_diff(history[last], history[last - p])
        prev = newest
        steady = True
        for j in range(1, returns + 1):
            d = _max_diff(history[last - j * p], history[last - (j + 1) * p])
            if d <= prev:
                steady = False
                break
            prev = d
        if steady and newest * factor <= prev:
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
def _creeping(history: np.ndarray, n: int, max_period: int, near: float, blocks: int,
              drop: float) -> int:  # fmt: skip
    """The smallest p whose p-spaced differences of the newest-last samples (the last ``n`` of
    ``history`` valid) are all within CREEP_NEAR of the state and whose largest in each of
    CREEP_BLOCKS consecutive stretches of at least a return fell from the stretch before, to at
    most CREEP_DROP of the oldest's: the response creeps towards a period-p orbit (0: none).
    Chaos keeps its differences near the state's size; a quasi-periodic response keeps their
    stretches' largest level."""
    last = history.shape[0] - 1
    scale = _size(history[last])
    for p in range(1, max_period + 1):
        width = (n - p) // blocks  # differences per stretch
        if width < p:
            break
        prev = first = np.inf
        creeps = True
        for b in range(blocks - 1, -1, -1):  # the oldest stretch first
            top = _envelope(history, last - b * width, p, width)
            if top > near * scale or top >= prev:
                creeps = False
                break
            if b == blocks - 1:
                first = top
            prev = top
        if creeps and prev <= drop * first:
            return p
    return 0


def _shrinking_p(history: np.ndarray, n: int, max_period: int) -> int:
    """:func:`_shrinking` with ``cfg.SHRINK_RETURNS`` and ``cfg.SHRINK_FACTOR``."""
    return int(_shrinking(history, n, max_period, cfg.SHRINK_RETURNS, cfg.SHRINK_FACTOR))


def _creeping_p(history: np.ndarray, n: int, max_period: int) -> int:
    """:func:`_creeping` with ``cfg.CREEP_NEAR``, ``cfg.CREEP_BLOCKS`` and ``cfg.CREEP_DROP``."""
    return int(_creeping(history, n, max_period, cfg.CREEP_NEAR, cfg.CREEP_BLOCKS, cfg.CREEP_DROP))


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
    width = (n - p) // cfg.CREEP_BLOCKS
    if p < 2 or width < p:
        return p
    last = history.shape[0] - 1
    old = last - (cfg.CREEP_BLOCKS - 1) * width

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
    if not np.all(np.isfinite(step)) or np.max(np.abs(step)) > cfg.NEWTON_REACH * r / (1.0 - rho):
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
        if np.max(np.abs(D[j] - pred)) > cfg.LINEAR_FIT * np.max(np.abs(D[j])):
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
    if not np.linalg.norm(V, 1) * np.linalg.norm(W, 1) < cfg.EIG_COND:
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
    return bool(np.max(np.abs(miss)) <= cfg.LINEAR_FIT * closer)


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


class OrbitSearch:
    """The engine's orbit search and proof (a mixin of ``loop._Engine``, whose state it reads:
    the sample buffers ``history``/``recent``, the kernel run, the settings ``s``, the
    ``pending`` and ``tried`` orbits)."""

    def _period_proven(self, p: int) -> bool:
        """A repeat after p periods (the kernel's ``measure.periodicity``) is a period-p state,
        not one still approaching a period-q orbit, q | p (:func:`_divisors_steady`)."""
        tol = self.s.periodicity_tol
        return _divisors_steady(self.history, self.nhistory, p, cfg.AMBIGUOUS * tol, tol)

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
            check = self.s.early_stop and self.nx * p <= cfg.CHECK_COST * self.work["periods"]
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
        lam, J = self._fd_radius(x0, p, fx0, impacts, cfg.FD_STEP)
        if lam is None or lam < 1.0 or math.isinf(lam):
            return lam, J
        again, _ = self._fd_radius(x0, p, fx0, impacts, 10.0 * cfg.FD_STEP)
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
        last = [_max_diff(x, o.x0) for x in self.recent[cfg.RECENT - q :]]
        j = cfg.RECENT - q + int(np.argmin(last))
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
        first = cfg.RECENT - self.nrecent  # the oldest kept sample
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
            back = self._returns(o, cfg.REACH_HOLD) if attracting else None
            if self._distance(o) <= near or (
                back and max(back) <= pend.found_at / cfg.REACH_SHRINK
            ):
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
        short = min(cfg.MAX_RRE, cfg.RECENT // q)
        if lam ** (cfg.MAX_RRE - 1) <= cfg.SLOW_SHRINK or short == cfg.RECENT // q:
            return (short,)
        return (short, cfg.RECENT // q)

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
                X = self._return_states(pd.orbit, cfg.REACH_HOLD + 1)
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
        idx = list(range(cfg.RECENT - 1, cfg.RECENT - 1 - p * min(avail, cfg.MAX_RRE), -p))
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
        if fit is None or fit[2] > cfg.MAX_FIT or fit[1] >= 0.999:
            return None  # the sequence is not (yet) a linear contraction: no side runs
        rho0 = fit[1]
        if self._tried(fit[0], 1e-3):
            return None  # an orbit already checked (any candidate p): no side runs
        snap = self.run.save()
        try:
            r_prev = math.inf
            for _ in range(cfg.MAX_CYCLES):
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

    def _converging(self) -> int:
        """The smallest p whose p-spaced differences of the stroboscopic samples have shrunk a
        hundredfold over the last half of the samples kept, or are already within 1e-6 of the
        state: the response is approaching (or is) a period-p orbit, not irregular (0: none).
        Every p the samples kept hold twice over (p ≤ 31): a slowly contracting period-17 orbit
        was claimed irregular while p ≤ 8 was watched. Or, over a longer history, the smallest
        p (≤ 40) whose differences shrank steadily (:func:`_shrinking_p`): a
        period-13 orbit of multiplier 0.62 shrank them 130-fold over its last 10 returns, but
        only 80-fold over 128 periods, and was claimed irregular at 260 periods."""
        if self.nrecent < cfg.RECENT:
            return 0
        p = int(_converging_p(self.recent, min(ms.MAX_PERIOD, cfg.RECENT // 2 - 1)))
        p = p or int(_shrinking_p(self.history, self.nhistory, ms.MAX_PERIOD))
        return p or int(_creeping_p(self.history, self.nhistory, ms.MAX_PERIOD))
