"""A point's budget and cancel (worker/solvers/engine/): limits hold, batches do not matter."""

from __future__ import annotations

import pytest

from worker.model import CellParams
from worker.simulate import (
    PointCancelled,
    PointLimits,
    SolverSettings,
    simulate_chunk,
    simulate_point,
)
from worker.solvers.engine import config as cfg
from worker.solvers.engine import loop
from worker.solvers.event.driver import EventRun

# An irregular point: runs hundreds of periods before it may end (tests/worker/test_engine.py).
IRREGULAR = dict(theta=1.0, xi=0.02, g1=0.5, g2=0.5, sigma=0.05, gamma_s=1.0, gamma_r=2.2)
PERIODIC = dict(theta=0.3, xi=0.05, g1=0.1, g2=0.1, sigma=0.05, gamma_s=1.0, gamma_r=2.05)
# Irregular too, and its Γ moved with where batches started before windows were measured whole.
IRREGULAR_A = {**PERIODIC, "gamma_r": 2.2}


def test_a_point_over_its_step_budget_fails_with_the_reason():
    r = simulate_point(CellParams(**IRREGULAR), limits=PointLimits(steps=50))
    assert r.outcome == "failed" and r.transmittance_db is None
    assert "step budget of 50 steps per point exceeded" in r.reason
    # it stopped at the first check: one window of periods, not the whole budget
    assert 0 < r.periods <= SolverSettings().window


def test_a_point_over_its_time_limit_fails_with_the_reason():
    r = simulate_point(CellParams(**IRREGULAR), limits=PointLimits(wall_s=1e-6))
    assert r.outcome == "failed"
    assert "time limit of 1e-06 s per point exceeded" in r.reason
    assert r.periods <= SolverSettings().window


def test_the_default_limits_leave_ordinary_points_alone():
    r = simulate_point(CellParams(**IRREGULAR))
    assert r.outcome == "irregular" and r.periods > SolverSettings().window


@pytest.mark.parametrize(
    "bad", [dict(wall_s=0.0), dict(wall_s=-1.0), dict(steps=0), dict(wall_s=float("nan"))]
)
def test_limits_are_checked(bad):
    field = next(iter(bad))
    with pytest.raises(ValueError, match=field):
        PointLimits(**bad)


def test_cancel_stops_a_running_point():
    calls = []

    def cancelled() -> bool:
        calls.append(1)
        return len(calls) >= 3

    with pytest.raises(PointCancelled, match="cancelled in period"):
        simulate_point(CellParams(**IRREGULAR), cancelled=cancelled)
    assert len(calls) == 3


def test_a_cancelled_chunk_returns_only_the_points_it_finished():
    # Far stops: every point starts in its linear tail, so cancel is only asked between points.
    pts = [{**PERIODIC, "g1": 1e6, "g2": 1e6, "gamma_r": g} for g in (1.5, 2.0, 2.5, 3.0)]
    calls = []

    def third_call() -> bool:
        calls.append(1)
        return len(calls) >= 3

    out = simulate_chunk(pts, cancelled=third_call)
    full = simulate_chunk(pts)
    assert len(full) == 4 and all(r["outcome"] == "linear" for r in full)
    assert len(out) == 2
    assert [r["transmittance_db"] for r in out] == [r["transmittance_db"] for r in full[:2]]


def test_a_chunk_passes_its_limits_to_every_point():
    pts = [{**IRREGULAR}, {**IRREGULAR, "gamma_r": 2.25}]
    out = simulate_chunk(pts, limits={"steps": 50})
    assert len(out) == 2
    assert all(r["outcome"] == "failed" and "step budget" in r["reason"] for r in out)


@pytest.mark.parametrize("method", ["event", "exponential", "euler"])
def test_short_batches_give_the_same_numbers_to_the_bit(monkeypatch, method):
    # Slow periods shorten the batches between limit checks (loop._Engine._pace, by the clock), so
    # where a batch starts must change nothing: the kernels carry their state over exactly,
    # and a window is measured whole or not at all. (Before, a batch starting inside the
    # window where measuring begins measured part of it: an irregular Γ moved by ~1e-8 dB
    # with the machine's load.)
    settings = SolverSettings(method=method)
    pts = (("irr", IRREGULAR), ("irr_a", IRREGULAR_A), ("per", PERIODIC))
    ref = {k: simulate_point(CellParams(**p), settings).as_dict() for k, p in pts}
    monkeypatch.setattr(cfg, "BATCH_S", 0.0)  # every batch counts as slow: one period each
    short = {k: simulate_point(CellParams(**p), settings).as_dict() for k, p in pts}
    assert ref["irr"]["outcome"] == ref["irr_a"]["outcome"] == "irregular"
    assert ref["per"]["outcome"] == "periodic"
    for k in ref:
        ref[k].pop("wall_s"), short[k].pop("wall_s")
        assert short[k] == ref[k]


@pytest.mark.parametrize("gamma_r", [2.3624161073825505, 0.9697986577181208])
def test_short_batches_see_a_pending_orbit_reached_in_the_same_period(monkeypatch, gamma_r):
    # A pending orbit (confirmed where the map is not smooth) is reported once the trajectory
    # reaches it, looked at at the ends of the batches an unpaced run makes, never at a cut by
    # the clock: were it looked at there, the reach would be seen sooner under load (the same
    # orbit with fewer periods, steps and another steady_period; audits/batch_cuts.py). These
    # two points (gaps 0.1 and 0.3) report the same work to the bit with one-period batches.
    kw = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, gamma_r=gamma_r)
    gap = 0.1 if gamma_r > 2.0 else 0.3
    point = CellParams(g1=gap, g2=gap, **kw)
    settings = SolverSettings(max_periods=100, periodicity_tol=1e-13)
    ref = simulate_point(point, settings).as_dict()
    monkeypatch.setattr(cfg, "BATCH_S", 0.0)
    short = simulate_point(point, settings).as_dict()
    assert ref["outcome"] == "periodic"
    ref.pop("wall_s"), short.pop("wall_s")
    assert short == ref


def _steps_at_monodromy(monkeypatch) -> list[int]:
    """Record the point's steps each time the finite-difference monodromy check of an orbit
    starts; the exact matrix is taken away, so the check runs (as for methods without one and
    orbits that start on a stop)."""
    run_from = EventRun.run_from
    monkeypatch.setattr(
        EventRun, "run_from", lambda self, x0, n, measure, exact, *arrays: run_from(
            self, x0, n, measure, False, *arrays)
    )  # fmt: skip
    seen: list[int] = []
    inner = loop._Engine._fd_radius

    def fd_radius(self, *args):
        seen.append(self.work["steps"])
        return inner(self, *args)

    monkeypatch.setattr(loop._Engine, "_fd_radius", fd_radius)
    return seen


def test_limits_hold_during_the_monodromy_check(monkeypatch):
    # The check of an extrapolated orbit integrates nx side runs (42 for 20 modes) before the
    # point can end: a step budget that runs out among them fails the point with the reason
    seen = _steps_at_monodromy(monkeypatch)
    free = simulate_point(CellParams(**PERIODIC))
    assert free.outcome == "periodic" and len(seen) == 1
    budget = seen[0] + 1  # over after the first side run of the check
    r = simulate_point(CellParams(**PERIODIC), limits=PointLimits(steps=budget))
    assert r.outcome == "failed" and "step budget" in r.reason
    assert r.steps < free.steps


def test_cancel_is_seen_during_the_monodromy_check(monkeypatch):
    seen = _steps_at_monodromy(monkeypatch)
    polls_in_check: list[int] = []

    def cancelled() -> bool:
        if seen:  # the check has started
            polls_in_check.append(1)
        return len(polls_in_check) >= 2

    with pytest.raises(PointCancelled):
        simulate_point(CellParams(**PERIODIC), cancelled=cancelled)
    assert len(polls_in_check) == 2


class _SlowClock:
    """A clock on which every reading is a second after the last: every batch looks slow."""

    def __init__(self) -> None:
        self.now = 0.0

    def perf_counter(self) -> float:
        self.now += 1.0
        return self.now


def test_slow_batches_are_cut_short(monkeypatch):
    # Where periods are slow, the batches between limit checks shrink to about BATCH_S of
    # work, so cancel is seen within a few periods, not a window of them (20 periods here).
    monkeypatch.setattr(loop, "time", _SlowClock())
    polls = []

    def cancelled() -> bool:
        polls.append(1)
        return len(polls) >= 6

    window = SolverSettings().window
    with pytest.raises(PointCancelled, match=r"cancelled in period (\d+)") as info:
        simulate_point(CellParams(**IRREGULAR), limits=PointLimits(wall_s=3600.0),
                       cancelled=cancelled)  # fmt: skip
    period = int(str(info.value).rsplit(" ", 1)[-1])
    assert period < window + 10  # unpaced, six polls would come six windows in


@pytest.mark.parametrize("gamma_r", [2.3624161073825505, 0.9697986577181208])
def test_a_reached_pending_orbit_is_seen_within_pending_batch_periods(monkeypatch, gamma_r):
    # Once the trajectory is seen approaching a pending orbit (at a batch end) the batches are
    # PENDING_BATCH periods long: the point reports the orbit at most 8 periods after
    # one-period batches do, with the same numbers (window-long batches: up to a window later).
    kw = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, gamma_r=gamma_r)
    gap = 0.1 if gamma_r > 2.0 else 0.3
    point = CellParams(g1=gap, g2=gap, **kw)
    settings = SolverSettings(max_periods=100, periodicity_tol=1e-13)
    got = simulate_point(point, settings)
    monkeypatch.setattr(cfg, "PENDING_BATCH", 1)
    soonest = simulate_point(point, settings)
    assert got.outcome == soonest.outcome == "periodic"
    assert got.transmittance_db == soonest.transmittance_db
    assert 0 <= got.steady_period - soonest.steady_period <= 8
