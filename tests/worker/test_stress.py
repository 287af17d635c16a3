"""Extreme parameters for every method: finite or failed with a reason, and right where a
closed form is known (docs/accuracy.md; the full sweep is audits/stress.py)."""

import math

import pytest

from worker.model import CellParams, assemble, pinned_transmittance_db
from worker.simulate import SolverSettings, simulate_chunk, simulate_point
from worker.solvers.euler import check_stable
from worker.solvers.euler import default_steps as euler_default_steps
from worker.solvers.settings import MAX_STEPS_PER_PERIOD

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1, gamma_r=0.85)
METHODS = ("exponential", "event", "euler")


def assert_clean(rec: dict) -> None:
    """No NaN/inf anywhere; finite values, or failed with a reason."""
    for k, v in rec.items():
        vals = v if isinstance(v, (list, tuple)) else [v]
        assert all(not (isinstance(x, float) and not math.isfinite(x)) for x in vals), k
    if rec["failed"]:
        assert rec["reason"] and rec["transmittance_db"] is None
    else:
        for k in ("transmittance_db", "amplitude", "theta_eff"):
            assert isinstance(rec[k], float) and math.isfinite(rec[k]), k
        assert rec["periods"] <= 2000  # the budget plus the side runs that confirm an orbit
        assert rec["outcome"] in ("linear", "periodic", "irregular", "unsettled")


EXTREMES = {
    "theta=1e-3": {"theta": 1e-3},
    "sigma=1e-4": {"sigma": 1e-4},
    "sigma=10": {"sigma": 10.0},
    "gamma_r=50": {"gamma_r": 50.0},
    "xi=0": {"xi": 0.0},
    "xi=0.5": {"xi": 0.5},
    "gaps=1e-9": {"g1": 1e-9, "g2": 1e-9},
    "gaps=1e-3/1": {"g1": 1e-3, "g2": 1.0},
    "gaps=0/0.1": {"g1": 0.0, "g2": 0.1},
    "modes=1": {"modes": 1},
}


@pytest.mark.parametrize("method", METHODS)
def test_extreme_points_are_finite_or_failed_with_a_reason(method):
    pts = [{**BASE, **kw} for kw in EXTREMES.values()]
    for label, rec in zip(EXTREMES, simulate_chunk(pts, {"method": method}), strict=True):
        assert rec["method"] == method, label
        assert_clean(rec)
        assert not rec["failed"], (label, rec["reason"])


@pytest.mark.parametrize("method", ["exponential", "event"])
def test_thirty_modes_pinned_and_impacting(method):
    p = CellParams(**{**BASE, "modes": 30, "g1": 0.0, "g2": 0.0})
    r = simulate_point(p, SolverSettings(method=method))
    assert r.transmittance_db == pytest.approx(pinned_transmittance_db(p), abs=1e-3)
    rec30, rec5 = simulate_chunk([{**BASE, "modes": 30}, BASE], {"method": method})
    assert_clean(rec30)
    assert rec30["outcome"] == rec5["outcome"] == "periodic"
    # modal convergence at this impacting point: Γ(30) within 1e-3 dB of Γ(5) (measured 4.7e-4)
    assert rec30["transmittance_db"] == pytest.approx(rec5["transmittance_db"], abs=1e-3)


def test_paper_coupling_at_theta_1e3_diverges_and_every_method_says_so_quickly():
    # The published (non-Lagrangian) coupling gains energy at every impact when θ is large:
    # all three methods find the same growth, and none may hang on the overflow.
    pt = {**BASE, "theta": 1e3}
    for method in METHODS:
        rec = simulate_chunk([pt], {"method": method})[0]
        assert_clean(rec)
        assert rec["failed"] and "diverged" in rec["reason"]
        # caught within a few periods, not at the end of the budget (measured: 7)
        assert rec["periods"] <= 20
    # the consistent coupling at the same θ is bounded
    rec = simulate_chunk([{**pt, "coupling": "full"}], {"method": "event"})[0]
    assert_clean(rec)
    assert not rec["failed"]


def test_euler_refusal_is_a_value_error_naming_steps_per_period():
    p = CellParams(**BASE)
    with pytest.raises(ValueError, match=r"steps_per_period .* largest stable step is Δτ"):
        simulate_point(p, SolverSettings(method="euler", steps_per_period=150))
    rec = simulate_chunk([BASE], {"method": "euler", "steps_per_period": 150})[0]
    assert_clean(rec)
    assert rec["failed"] and "steps_per_period" in rec["reason"]
    assert "largest stable step" in rec["reason"]


@pytest.mark.parametrize(
    "kw",
    [{"modes": 30}, {"xi": 0.5, "sigma": 1.0, "modes": 8}, {"xi": 0.5, "modes": 30}],
)
def test_euler_default_steps_are_never_refused(kw):
    # Explicit damping of stiff modes can make Δτ·ω̃_max = 1 unstable: the default steps halve
    # below the damping-aware limit.
    sys_ = assemble(CellParams(**{**BASE, **kw}))
    n = euler_default_steps(sys_)
    check_stable(sys_, 2 * math.pi / sys_.params.gamma_r / n)


def test_euler_default_beyond_the_step_limit_is_refused_not_run():
    pt = {**BASE, "modes": 30, "sigma": 10.0, "gamma_r": 0.01, "g1": 0.0, "g2": 0.0}
    assert euler_default_steps(assemble(CellParams(**pt))) > MAX_STEPS_PER_PERIOD
    rec = simulate_chunk([pt], {"method": "euler"})[0]
    # refused before a single step is taken
    assert rec["periods"] == 0 and rec["steps"] == 0
    assert rec["failed"] and "steps_per_period" in rec["reason"]
    assert_clean(rec)


@pytest.mark.parametrize("method", METHODS)
def test_period_budget_ends_a_long_run(method):
    # γ_r 5 is irregular: a 60-period budget is too short for its statistics
    rec = simulate_chunk(
        [{**BASE, "gamma_r": 5.0}], {"method": method, "max_periods": 60, "window": 10}
    )[0]
    assert_clean(rec)
    assert rec["outcome"] == "unsettled" and rec["response_period"] == 0
    assert rec["periods"] >= 60 and "budget of 60 periods ran out" in rec["reason"]
