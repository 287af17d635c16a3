"""One point from start to result: :func:`run_point` runs the engine and builds the
``PointResult`` (with its history when asked for)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from worker.model import System
from worker.observables import theta_eff_harmonic, theta_eff_slope, transmittance_db
from worker.solvers import measure as ms
from worker.solvers.base import KernelRun
from worker.solvers.engine import config as cfg
from worker.solvers.engine.irregular import _db, _se_db
from worker.solvers.engine.loop import _Engine
from worker.solvers.engine.orbits import _Orbit
from worker.solvers.engine.tail import _finite_or_none, _undamped_reason, _with_reference
from worker.solvers.linear import LinearTail
from worker.solvers.settings import PointLimits, PointResult, SolverSettings


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
    if settings.early_stop and settings.linear_tail and tail.proves(x0, cfg.TAIL_HORIZON * T):
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
            response_period=1, impacts_per_period=(0.0, 0.0), contact_fraction=(0.0, 0.0),
            impact_energy=(0.0, 0.0),
            # no impacts: none of the damping's work (ss.amplitude > 0: forced, damped)
            impact_energy_share=0.0 if p.coupling == "full" and ss.amplitude > 0 else None,
            peak_impulse=0.0,
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
            contact_fraction=(float(rows[:, ms.M_CT1].sum() / (len(rows) * T)),
                              float(rows[:, ms.M_CT2].sum() / (len(rows) * T))),
            impact_velocity=_approach(rows[:, ms.M_VIMP1].sum(), rows[:, ms.M_VIMP2].sum(),
                                      rows[:, ms.M_IMP1].sum(), rows[:, ms.M_IMP2].sum()),
            impact_energy=(float(rows[:, ms.M_EN1].sum() / len(rows)),
                           float(rows[:, ms.M_EN2].sum() / len(rows))),
            impact_energy_share=impact_energy_share(
                sys_, run.f_scale if run is not None else 1.0,
                float(rows[:, ms.M_EN1].sum() + rows[:, ms.M_EN2].sum()), h[0], h[1],
            ),
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


def forcing_work(sys_: System, f_scale: float, s_re: float, s_im: float) -> float:
    """W_F = ∫ ṡ F_s dτ, the work of the forcing over whole periods of a response whose s
    returns to its start, from the first harmonic ``S = s_re + i s_im = ∫ s e^{−iγ_rτ} dτ``
    over them (docs/model.md §6): with ``F_s = a sin γ_rτ + b cos γ_rτ`` integration by parts
    (the boundary term ``[s F_s]`` vanishes) gives ``−γ_r (a S_re + b S_im)``."""
    a = f_scale * sys_.f_sin
    b = f_scale * sys_.f_cos
    return -sys_.params.gamma_r * (a * s_re + b * s_im)


def impact_energy_share(sys_: System, f_scale: float, energy: float, s_re: float,
                        s_im: float) -> float | None:  # fmt: skip
    """The impacts' share ``energy / W_F`` of the energy the cell dissipates over whole periods
    (:func:`forcing_work` from the same periods' harmonic). Only ``full`` coupling has the
    energy balance that makes W_F the sum of the dissipations (docs/model.md §4, §6): None in
    ``paper``, and where W_F is not positive beyond its rounding (no forcing; undamped without
    impacts)."""
    if sys_.params.coupling != "full":
        return None
    wf = forcing_work(sys_, f_scale, s_re, s_im)
    g = sys_.params.gamma_r
    size = f_scale * g * (abs(sys_.f_sin * s_re) + abs(sys_.f_cos * s_im))
    if not wf > 1e-12 * size or not math.isfinite(wf):
        return None
    return float(energy / wf)


def _window_mean(a: np.ndarray) -> tuple[tuple[float, float], tuple[float, float] | None]:
    """The mean of per-window values (rows: windows, columns: the two stops) and its standard
    error, the windows as batches (None from one window)."""
    mean = (float(a[:, 0].mean()), float(a[:, 1].mean()))
    if len(a) < 2:
        return mean, None
    se = a.std(axis=0, ddof=1) / math.sqrt(len(a))
    return mean, (float(se[0]), float(se[1]))


def _approach_se(v: np.ndarray, n: np.ndarray) -> tuple[float | None, float | None] | None:
    """The standard error of each stop's mean approach velocity ``Σv/Σn`` over windows with
    sums ``v`` and impact counts ``n`` (the ratio estimator's, windows as batches): None from
    one window, and for a stop with impacts in fewer than two windows."""
    if len(v) < 2:
        return None
    out: list[float | None] = []
    for k in range(2):
        total = float(n[:, k].sum())
        if np.count_nonzero(n[:, k]) < 2:
            out.append(None)
            continue
        r = float(v[:, k].sum()) / total
        resid = v[:, k] - r * n[:, k]
        m = len(v)
        out.append(float(math.sqrt((resid @ resid) / (m * (m - 1))) / (total / m)))
    return out[0], out[1]


def _approach(v1: float, v2: float, n1: float, n2: float) -> tuple[float | None, float | None]:
    """The mean approach velocity of the impacts at each stop (sums over counts; None where a
    stop had none)."""
    return (float(v1 / n1) if n1 > 0 else None, float(v2 / n2) if n2 > 0 else None)


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
    # per window of the stationary span (windows as batches): the impacts per period, the time
    # on each stop and the impacts' energy, their means and standard errors; the approach
    # velocity over all the span's impacts
    T = 2.0 * math.pi / p.gamma_r
    ni = np.array([win.impacts[i] for i in span], dtype=float)
    imp, imp_se = _window_mean(ni / win.window)
    ct, ct_se = _window_mean(np.array([win.contact[i][:2] for i in span]) / (win.window * T))
    en, en_se = _window_mean(np.array([win.contact[i][4:6] for i in span]) / win.window)
    vs = np.array([win.contact[i][2:4] for i in span])
    # the share from the span's measured windows: their energy over their forcing work
    e_meas = sum(float(win.contact[i][4] + win.contact[i][5]) for i in span if win.measured[i])
    return PointResult(
        outcome=outcome, transmittance_db=db, transmittance_db_se=_finite_or_none(_se_db(st)),
        amplitude=st.mean,
        theta_eff=theta_eff_harmonic(complex(h[0], h[1]), complex(h[2], h[3]), kappa, theta),
        theta_eff_slope=theta_eff_slope(h[4], h[5], kappa, theta),
        response_period=0,
        impacts_per_period=imp, impacts_per_period_se=imp_se,
        contact_fraction=ct, contact_fraction_se=ct_se,
        impact_velocity=_approach(*vs.sum(axis=0), *ni.sum(axis=0)),
        impact_velocity_se=_approach_se(vs, ni),
        impact_energy=en, impact_energy_se=en_se,
        impact_energy_share=impact_energy_share(eng.sys, eng.run.f_scale, e_meas, h[0], h[1]),
        peak_impulse=float(max(win.peak[i] for i in span)), floquet_multiplier=None,
        wall_s=0.0, reason=reason, method=eng.s.method, **common,
    )  # fmt: skip
