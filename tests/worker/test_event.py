"""The event-driven reference solver (``method: "event"``) against known answers (MODEL.md §8)."""

import math
import time

import numpy as np
import pytest

from worker.event import prepare_event, simulate_event, stuck_matrices
from worker.model import CellParams, assemble, linear_transmittance_db, pinned_transmittance_db
from worker.simulate import PointResult, SolverSettings, simulate_chunk, simulate_point

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)
EVENT = SolverSettings(method="event")


def cell(**kw) -> CellParams:
    return CellParams(**{**BASE, **kw})


@pytest.mark.parametrize("coupling", ["paper", "full"])
@pytest.mark.parametrize("gamma_r", [0.3, 1.0, 4.5])
def test_huge_gaps_give_the_linear_frequency_response(coupling, gamma_r):
    p = cell(gamma_r=gamma_r, g1=1e6, g2=1e6, coupling=coupling)
    r = simulate_point(p, EVENT)
    assert r.converged and r.response_period == 1 and not r.failed and r.method == "event"
    assert r.contact_steps == 0 and r.impacts_per_period == (0.0, 0.0)
    assert r.transmittance_db == pytest.approx(linear_transmittance_db(p), abs=1e-6)


@pytest.mark.parametrize("coupling", ["paper", "full"])
@pytest.mark.parametrize("gamma_r", [0.5, 1.7, 3.3])
def test_zero_gaps_give_the_pinned_linear_response(coupling, gamma_r):
    p = cell(gamma_r=gamma_r, g1=0.0, g2=0.0, coupling=coupling)
    r = simulate_point(p, EVENT)
    assert r.converged and not r.failed
    assert r.transmittance_db == pytest.approx(pinned_transmittance_db(p), abs=1e-5)


def test_stuck_regime_is_the_constrained_system():
    """The reduced stuck dynamics equal the free dynamics plus the contact force along M⁻¹X."""
    rng = np.random.default_rng(1)
    for coupling in ("paper", "full"):
        s = assemble(cell(gamma_r=1.3, coupling=coupling))
        N = s.ndof
        A, _, Qout, mu = stuck_matrices(s, -0.1)
        y = rng.standard_normal(2 * N + 1)
        y[-1] = 1.0
        z = Qout @ y
        u, q = z[:N], z[N : 2 * N]
        h = -s.C @ q - s.K @ u
        h[-1] += z[2 * N] * s.f_cos + z[2 * N + 1] * s.f_sin
        force = -(s.W @ s.Minv @ h) / s.G  # keeps Wᵀq̇ = 0
        assert mu @ y == pytest.approx(force, rel=1e-12)
        assert s.W @ u == pytest.approx(-0.1, rel=1e-14)
        zdot = Qout @ (A @ y)
        qdot = s.Minv @ (h + s.X * force)
        np.testing.assert_allclose(zdot[:N], q, atol=1e-12)
        np.testing.assert_allclose(zdot[N : 2 * N], qdot, atol=1e-11)


# Periodic impacting points (period 1, 1, 1 paper; 1, 1, 4 full).
IMPACTING = [(g, c) for c in ("paper", "full") for g in (0.85, 2.0, 2.5)]


@pytest.fixture(scope="module")
def event_results():
    return {(g, c): simulate_point(cell(gamma_r=g, coupling=c), EVENT) for g, c in IMPACTING}


@pytest.mark.parametrize(("gamma_r", "coupling"), IMPACTING)
def test_fine_step_schemes_converge_to_the_event_solution(event_results, gamma_r, coupling):
    ev = event_results[(gamma_r, coupling)]
    assert ev.converged and not ev.failed and sum(ev.impacts_per_period) > 0
    p = cell(gamma_r=gamma_r, coupling=coupling)
    ex = simulate_point(p, SolverSettings(steps_per_period=16384))
    eu = simulate_point(p, SolverSettings(method="euler", steps_per_period=65536))
    for ref, tol in ((ex, 1e-4), (eu, 1e-3)):
        assert ref.response_period == ev.response_period
        assert ref.impacts_per_period == ev.impacts_per_period
        assert ref.transmittance_db == pytest.approx(ev.transmittance_db, abs=tol)
        assert ref.theta_eff == pytest.approx(ev.theta_eff, abs=tol)


@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_sub_grid_sets_the_cost_not_the_answer(coupling):
    p = cell(gamma_r=0.85, coupling=coupling)
    a = simulate_point(p, SolverSettings(method="event", steps_per_period=16, near_margin=0.0))
    b = simulate_point(p, SolverSettings(method="event", steps_per_period=256))
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
    assert a.theta_eff == pytest.approx(b.theta_eff, abs=1e-9)
    assert a.impacts_per_period == b.impacts_per_period


def test_impact_times_close_the_gap_to_round_off():
    r = simulate_event(cell(gamma_r=2.0), EVENT, history_periods=2)
    ev = r.history["events"]
    impacts = ev[ev[:, 1] == 1.0]
    assert len(impacts) >= 4 and np.all(impacts[:, 4] > 0)
    assert np.max(np.abs(impacts[:, 3])) <= 1e-12  # gap / clearance at the located time
    releases = ev[ev[:, 1] == 2.0]
    assert len(releases) >= 4 and np.max(np.abs(releases[:, 3])) <= 1e-10  # force / its scale
    h = r.history
    assert np.max(h["w_tip"]) <= 0.1 * (1 + 1e-12) and np.min(h["w_tip"]) >= -0.1 * (1 + 1e-12)


def _energy(state: np.ndarray, M: np.ndarray, K: np.ndarray) -> np.ndarray:
    n = M.shape[0]
    u, q = state[:, :n], state[:, n:]
    return 0.5 * np.einsum("ti,ij,tj->t", q, M, q) + 0.5 * np.einsum("ti,ij,tj->t", u, K, u)


def test_energy_is_constant_between_impacts_and_drops_at_each():
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.234, xi=0.0, g1=0.1, g2=0.1,
                   coupling="full")  # fmt: skip
    sys_ = assemble(p)
    x0 = np.zeros(2 * sys_.ndof)
    x0[sys_.ndof] = 0.5  # η̇_1: the tip moves at 1.0 and reaches the stops
    r = simulate_event(
        p, SolverSettings(method="event", max_periods=8, window=1, early_stop=False),
        history_periods=8, initial_state=x0, forcing=False,
    )  # fmt: skip
    assert not r.failed
    h = r.history
    E = np.concatenate([_energy(x0[None, :], sys_.M, sys_.K), _energy(h["state"], sys_.M, sys_.K)])
    dE = np.diff(E)
    impact = np.isin(h["kind"], (1, 2))
    assert impact.sum() >= 5 and np.isin(h["kind"], (3, 4)).sum() >= 2  # impacts and releases
    assert np.max(np.abs(dE[~impact])) < 1e-12 * E[0]  # free flight and stick: round-off only
    ev = h["events"]
    big = ev[ev[:, 1] == 1.0][:, 4] > 1e-9
    assert np.all(dE[impact][big] < -1e-14 * E[0])  # every plastic impact dissipates


def _linear_orbit(p: CellParams) -> tuple[np.ndarray, float]:
    """State at τ = 0 of the impact-free periodic orbit, and its tip amplitude."""
    s = assemble(p)
    g = p.gamma_r
    H = s.K - g * g * s.M + 1j * g * s.C
    u_hat = np.linalg.solve(H, np.eye(s.ndof)[-1] * (s.f_cos - 1j * s.f_sin))
    return np.concatenate([u_hat.real, -g * u_hat.imag]), float(abs(s.W @ u_hat))


def test_grazing_contact_is_found_between_sub_grid_samples():
    # On the linear orbit with the gap 1e-8 (relative) inside the tip amplitude, the tip grazes
    # the stop once per swing; 8 samples per period never see the gap close.
    lin = cell(gamma_r=1.5, g1=1e6, g2=1e6)
    x0, amp = _linear_orbit(lin)
    g = amp * (1.0 - 1e-8)
    p = cell(gamma_r=1.5, g1=g, g2=g)
    first = []
    for kw in ({"steps_per_period": 8, "near_margin": 0.0}, {"steps_per_period": 512}):
        settings = SolverSettings(method="event", max_periods=3, window=1, early_stop=False, **kw)
        r = simulate_event(p, settings, history_periods=3, initial_state=x0)
        ev = r.history["events"]
        assert not r.failed and len(ev) > 0 and ev[0, 1] == 1.0
        assert ev[0, 0] < 2 * math.pi / 1.5  # in the first period
        assert 0.0 <= ev[0, 4] < 1e-3  # a grazing (light) impact
        first.append(ev[0])
    assert first[0][0] == pytest.approx(first[1][0], abs=1e-9)
    # From rest, near-grazing gaps settle on an impacting orbit: the runs complete, and the
    # sub-grid changes nothing.
    a, b = (
        simulate_point(p, SolverSettings(method="event", **kw))
        for kw in ({"steps_per_period": 8, "near_margin": 0.0}, {"steps_per_period": 512})
    )
    for res in (a, b):
        assert res.converged and not res.failed and res.contact_steps > 0
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
    assert a.impacts_per_period == b.impacts_per_period


def test_chattering_is_ended_by_the_event_budget():
    p = cell(gamma_r=1.2, g1=0.01, g2=0.01)
    t0 = time.perf_counter()
    r = simulate_event(p, SolverSettings(method="event", max_periods=40, window=5),
                       max_events_per_period=3)  # fmt: skip
    assert time.perf_counter() - t0 < 10.0
    assert r.failed and "event budget exceeded" in r.reason and r.transmittance_db is None
    # with the default budget the same point runs to the end
    r = simulate_point(p, SolverSettings(method="event", max_periods=40, window=5))
    assert not r.failed or "event budget" in r.reason


def test_result_has_the_same_shape_as_other_methods():
    p = cell(gamma_r=0.85)
    a = simulate_point(p, EVENT, history_periods=1)
    b = simulate_point(p, SolverSettings(), history_periods=1)
    assert isinstance(a, PointResult)
    assert a.as_dict().keys() == b.as_dict().keys()
    assert set(b.history) <= set(a.history)
    assert np.all(np.diff(a.history["tau"]) >= 0)
    out = simulate_chunk([dict(BASE, gamma_r=1.0, g1=1e6, g2=1e6)], {"method": "event"})
    assert out[0]["method"] == "event" and not out[0]["failed"]
    assert math.isfinite(out[0]["transmittance_db"])


def test_irregular_points_are_measured_on_the_window():
    r = simulate_point(
        cell(gamma_r=5.0), SolverSettings(method="event", max_periods=120, window=10)
    )
    assert not r.converged and r.response_period == 0 and r.reason == "irregular"
    assert r.periods == 120 and math.isfinite(r.transmittance_db)


def test_regimes_are_well_conditioned_for_the_benchmark_cell():
    for g in (0.2, 1.0, 6.0):
        assert prepare_event(assemble(cell(gamma_r=g)), 128).cond < 1e6


def test_bad_event_tolerance_is_refused():
    with pytest.raises(ValueError, match="event_tol"):
        simulate_event(cell(gamma_r=1.0), EVENT, event_tol=0.0)
