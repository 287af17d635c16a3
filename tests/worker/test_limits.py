"""A point's budget and cancel (worker/solvers/engine.py): limits hold, batches do not matter."""

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
from worker.solvers import engine

# An irregular point: runs hundreds of periods before it may end (tests/worker/test_engine.py).
IRREGULAR = dict(theta=1.0, xi=0.02, g1=0.5, g2=0.5, sigma=0.05, gamma_s=1.0, gamma_r=2.2)
PERIODIC = dict(theta=0.3, xi=0.05, g1=0.1, g2=0.1, sigma=0.05, gamma_s=1.0, gamma_r=2.05)


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


def test_short_batches_give_the_same_numbers(monkeypatch):
    # Slow periods shorten the batches between limit checks. An orbit is the same to the bit;
    # chaotic motion amplifies the round-off of restarting a batch, far below its error bar.
    ref = {k: simulate_point(CellParams(**p)) for k, p in (("irr", IRREGULAR), ("per", PERIODIC))}
    monkeypatch.setattr(engine, "BATCH_S", 0.0)  # every batch counts as slow: one period each
    short = {k: simulate_point(CellParams(**p)) for k, p in (("irr", IRREGULAR), ("per", PERIODIC))}
    a, b = ref["per"].as_dict(), short["per"].as_dict()
    a.pop("wall_s"), b.pop("wall_s")
    assert a["outcome"] == "periodic" and a == b
    irr, irr_short = ref["irr"], short["irr"]
    assert irr.outcome == irr_short.outcome == "irregular"
    assert irr.periods == irr_short.periods
    assert abs(irr.transmittance_db - irr_short.transmittance_db) < 1e-3 * irr.transmittance_db_se
