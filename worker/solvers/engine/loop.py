"""The engine's time loop: batches of whole periods through a method's kernel, the checks at a
batch's end, the point's limits and cancel, and what the run shows when its budget runs out.

``_Engine`` combines the loop with its three concerns: :class:`~.orbits.OrbitSearch`,
:class:`~.irregular.IrregularClaims` and :class:`~.tail.TailProof`.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numba import njit

from worker.model import System, pinned_max_re
from worker.numba_cache import on_disk
from worker.solvers import measure as ms
from worker.solvers.base import ExactMonodromy, KernelRun
from worker.solvers.engine import config as cfg
from worker.solvers.engine.irregular import (
    IrregularClaims,
    _batch_size,
    _mser_start,
    _repeat,
    _se_db,
    _Windows,
    budget_for_error,
    series_stats,
)
from worker.solvers.engine.orbits import (
    OrbitSearch,
    _converging_p,
    _creeping,
    _divisors_steady,
    _max_diff,
    _Orbit,
    _own_period,
    _Pending,
    _rre,
    _shrinking,
    _unstable,
    rre,
)
from worker.solvers.engine.tail import TailProof
from worker.solvers.linear import LinearTail
from worker.solvers.settings import (
    OVER_STEPS,
    OVER_TIME,
    PointCancelled,
    PointLimits,
    SolverSettings,
)


def compile_helpers() -> None:
    """Compile the engine's own compiled helpers into numba's on-disk cache if they are not
    there. A point calls most of them only once it extrapolates an orbit (the statistics' two once
    it may be irregular), so a worker loads them then
    (~0.35 s); ``simulate.warm_up`` calls this so that on a fresh cache the process that warms up
    compiles them once (~12 s on this machine), not every worker at its first periodic point."""
    helpers = (_rre, _converging_p, _shrinking, _creeping, _divisors_steady, _max_diff,
               _mser_start, _batch_size, _repeat)  # fmt: skip
    if all(on_disk(f) for f in helpers):
        return
    X = np.array([[0.0, 1.0], [1.0, 0.5], [1.5, 0.25], [1.75, 0.125]])
    rre(X)
    _converging_p(X, 1)
    _shrinking(X, 4, 1, cfg.SHRINK_RETURNS, cfg.SHRINK_FACTOR)
    _creeping(X, 4, 1, cfg.CREEP_NEAR, cfg.CREEP_BLOCKS, cfg.CREEP_DROP)
    _divisors_steady(X, 4, 2, 1e-6, 1e-9)
    _max_diff(X[0], X[1])
    series_stats(X[:, 0])


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


class _Engine(OrbitSearch, IrregularClaims, TailProof):
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
        self.history = np.zeros((cfg.HISTORY, self.nx))
        self.nhistory = 0
        self.recent = self.history[cfg.HISTORY - cfg.RECENT :]
        self.recent_imp = np.zeros(cfg.RECENT)  # impacts in each of those periods
        self.recent_reg = np.zeros(cfg.RECENT)
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
        self.nhistory = min(cfg.HISTORY, self.nhistory + n)
        _push_recent(self.recent_imp, self.recent_reg, rows)
        self.nrecent = min(cfg.RECENT, self.nrecent + n)
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
        first = max(2 * w, s.max_periods // 4 - cfg.MIN_WINDOWS * w)
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
                    n = min(n, cfg.PENDING_BATCH)  # seen soon after the trajectory reaches it
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
                    self.hold_periodic = self.period + cfg.UNSTABLE_HOLD * p
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
        if dt > cfg.BATCH_S and done > 0:
            self.stride = max(1, int(done * cfg.BATCH_S / dt))

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
                ring[(last - j) % ms.RING] = self.recent[cfg.RECENT - 1 - j]
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
        if st.trend > cfg.MAX_TREND:
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
