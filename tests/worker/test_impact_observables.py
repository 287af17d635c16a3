"""What the impacts are (docs/model.md §6): the fraction of the period the tip spends on each
stop and the mean approach velocity of its impacts, against the event method's own events,
across methods, and where they are not defined."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from worker.model import CellParams
from worker.model.chain import ChainParams
from worker.simulate import SolverSettings, simulate_chain_point, simulate_chunk, simulate_point
from worker.solvers.engine.point import _approach_se

# periodic with every method: one impact a period at each stop, stuck after each
CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=0.1, g2=0.1, modes=3)


def test_the_time_on_each_stop_is_the_orbits_stuck_time():
    r = simulate_point(CELL, SolverSettings(method="event"), history_periods=1)
    assert r.outcome == "periodic" and r.response_period == 1
    h = r.history
    kind, tau = h["kind"], h["tau"]
    T = 2 * np.pi / CELL.gamma_r
    for stop in (1, 2):  # an impact that sticks (kind 1, 2) to its release (kind 3, 4)
        on, off = tau[kind == stop], tau[kind == 2 + stop]
        assert len(on) == len(off) == 1
        stuck = (off[0] - on[0]) % T
        assert r.contact_fraction[stop - 1] == pytest.approx(stuck / T, abs=1e-9)
    assert 0.15 < r.contact_fraction[0] < 0.3 and r.contact_fraction_se is None


@pytest.mark.parametrize("method", ["euler", "exponential"])
def test_time_stepping_converges_to_the_event_methods_values(method):
    ref = simulate_point(CELL, SolverSettings(method="event"))
    errs = []
    for spp in (2048, 8192):
        r = simulate_point(CELL, SolverSettings(method=method, steps_per_period=spp))
        assert r.outcome == "periodic"
        ct = np.abs(np.subtract(r.contact_fraction, ref.contact_fraction))
        v = np.abs(np.subtract(r.impact_velocity, ref.impact_velocity) / ref.impact_velocity)
        errs.append((ct.max(), v.max()))
    (ct0, v0), (ct1, v1) = errs
    assert ct1 < 2e-4 and v1 < 1e-2  # a step is T/8192 = 1.2e-4 of the period
    assert ct1 < ct0 and v1 <= v0 * 1.01  # and shrinking with the step


def test_a_linear_point_never_touches_a_stop():
    r = simulate_point(dataclasses.replace(CELL, g1=50.0, g2=50.0), SolverSettings())
    assert r.outcome == "linear"
    assert r.contact_fraction == (0.0, 0.0) and r.impact_velocity is None


def test_an_irregular_point_has_error_bars_and_a_failed_one_nothing():
    # the default cell at γ_r 1.3: a response of window statistics with every method
    r = simulate_point(dataclasses.replace(CELL, modes=5), SolverSettings())
    assert r.outcome in ("irregular", "unsettled")
    assert all(0.0 < c < 1.0 for c in r.contact_fraction)
    assert all(0.0 < s < 0.05 for s in r.contact_fraction_se)
    assert all(v is not None and v > 0 for v in r.impact_velocity)
    point = {k: getattr(CELL, k) for k in ("theta", "sigma", "gamma_s", "gamma_r", "modes")}
    (d,) = simulate_chunk([point], {"method": "euler", "steps_per_period": 8})  # unstable
    assert d["failed"] and d["contact_fraction"] is None and d["impact_velocity"] is None


def test_chains_do_not_report_them_yet():
    r = simulate_chain_point(ChainParams(CELL, 2), SolverSettings(method="euler"))
    assert r.contact_fraction is None and r.impact_velocity is None


def test_irregular_impact_observables_are_window_means_with_error_bars():
    """At an irregular point the impacts per period, time on the stops, approach velocity and
    impact energy are means over the stationary span's windows, each with a standard error
    that is positive and small against the mean."""
    r = simulate_point(dataclasses.replace(CELL, modes=5), SolverSettings())
    assert r.outcome in ("irregular", "unsettled")
    for mean, se in ((r.impacts_per_period, r.impacts_per_period_se),
                     (r.contact_fraction, r.contact_fraction_se),
                     (r.impact_velocity, r.impact_velocity_se),
                     (r.impact_energy, r.impact_energy_se)):  # fmt: skip
        for m, s in zip(mean, se, strict=True):
            assert m > 0 and 0 < s < 0.2 * m
    periodic = simulate_point(CELL, SolverSettings())
    assert periodic.outcome == "periodic"
    assert periodic.impacts_per_period_se is None and periodic.impact_velocity_se is None


def test_the_approach_velocitys_error_bar_is_the_ratio_estimators():
    """Σv/Σn over windows: no spread when every window has the same mean velocity; else the
    ratio estimator's standard error, here by hand; none for a stop with impacts in only one
    window."""
    n = np.array([[2.0, 1.0], [4.0, 0.0], [2.0, 0.0]])
    same = _approach_se(0.5 * n, n)
    assert same[0] == 0.0 and same[1] is None
    v = np.array([[1.0, 0.3], [2.4, 0.0], [0.6, 0.0]])
    r = 4.0 / 8.0  # Σv / Σn at stop 1
    resid = v[:, 0] - r * n[:, 0]  # 0, 0.4, -0.4
    expected = np.sqrt(resid @ resid / (3 * 2)) / (8.0 / 3)
    assert _approach_se(v, n)[0] == pytest.approx(expected, rel=1e-15)
