"""The simulator against references with known answers (MODEL.md §8)."""

import math

import numpy as np
import pytest

from worker.model import CellParams, assemble, linear_transmittance_db, pinned_transmittance_db
from worker.simulate import SolverSettings, simulate_chunk, simulate_point

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)


def cell(**kw) -> CellParams:
    return CellParams(**{**BASE, **kw})


@pytest.mark.parametrize("coupling", ["paper", "full"])
@pytest.mark.parametrize("gamma_r", [0.3, 1.0, 2.5, 4.5])
def test_huge_gaps_give_the_linear_frequency_response(coupling, gamma_r):
    p = cell(gamma_r=gamma_r, g1=1e6, g2=1e6, coupling=coupling)
    r = simulate_point(p)
    assert r.converged and r.response_period == 1 and not r.failed
    assert r.contact_steps == 0 and r.impacts_per_period == (0.0, 0.0)
    assert r.transmittance_db == pytest.approx(linear_transmittance_db(p), abs=1e-4)


@pytest.mark.parametrize("coupling", ["paper", "full"])
@pytest.mark.parametrize("gamma_r", [0.5, 1.7, 3.3])
def test_zero_gaps_give_the_pinned_linear_response(coupling, gamma_r):
    p = cell(gamma_r=gamma_r, g1=0.0, g2=0.0, coupling=coupling)
    r = simulate_point(p)
    assert r.converged
    assert r.transmittance_db == pytest.approx(pinned_transmittance_db(p), abs=1e-3)
    # pinned is not free: the two references differ markedly here
    assert abs(pinned_transmittance_db(p) - linear_transmittance_db(p)) > 0.1


def test_linear_limit_with_euler_converges_to_the_same_answer():
    p = cell(gamma_r=1.2, g1=1e6, g2=1e6)
    r = simulate_point(p, SolverSettings(method="euler", steps_per_period=8192))
    assert r.transmittance_db == pytest.approx(linear_transmittance_db(p), abs=2e-3)


def test_amplitude_is_refined_between_samples():
    # 16 steps per period: the largest sample misses the peak by up to 20log10(cos(π/16)).
    p = cell(gamma_r=0.7, g1=1e6, g2=1e6)
    r = simulate_point(p, SolverSettings(steps_per_period=16, coarse_steps=16), history_periods=1)
    exact = linear_transmittance_db(p)
    sampled = 20 * math.log10(0.5 * np.ptp(r.history["s"]) / p.base_scale)
    assert abs(r.transmittance_db - exact) < 2e-3
    assert abs(sampled - exact) > 5 * abs(r.transmittance_db - exact)


IMPACTING = [(0.85, "paper"), (1.5, "paper"), (0.85, "full")]


@pytest.fixture(scope="module")
def fine_reference():
    """Exponential at 65536 steps per period: the fine-step limit for the points above."""
    out = {}
    for g, c in IMPACTING:
        r = simulate_point(cell(gamma_r=g, coupling=c), SolverSettings(steps_per_period=65536))
        assert r.converged and r.response_period >= 1 and sum(r.impacts_per_period) > 0
        out[(g, c)] = r
    return out


def test_euler_converges_with_order_one(fine_reference):
    ref = fine_reference[(0.85, "paper")].transmittance_db
    steps = np.array([2048, 4096, 8192, 16384])
    err = []
    for n in steps:
        r = simulate_point(cell(gamma_r=0.85), SolverSettings(method="euler", steps_per_period=n))
        assert r.converged and r.response_period == fine_reference[(0.85, "paper")].response_period
        err.append(abs(r.transmittance_db - ref))
    order = -np.polyfit(np.log(1.0 / steps), np.log(err), 1)[0] * -1
    assert order == pytest.approx(1.0, abs=0.2)


@pytest.mark.parametrize(("gamma_r", "coupling"), IMPACTING)
def test_euler_and_exponential_agree_at_fine_steps(fine_reference, gamma_r, coupling):
    ref = fine_reference[(gamma_r, coupling)]
    r = simulate_point(
        cell(gamma_r=gamma_r, coupling=coupling),
        SolverSettings(method="euler", steps_per_period=65536),
    )
    assert r.response_period == ref.response_period
    assert r.transmittance_db == pytest.approx(ref.transmittance_db, abs=1e-3)
    assert r.theta_eff == pytest.approx(ref.theta_eff, abs=1e-3)


@pytest.mark.parametrize(("gamma_r", "coupling"), IMPACTING)
def test_default_exponential_is_within_1e_3_db_of_the_fine_limit(fine_reference, gamma_r, coupling):
    ref = fine_reference[(gamma_r, coupling)]
    r = simulate_point(cell(gamma_r=gamma_r, coupling=coupling))
    assert r.transmittance_db == pytest.approx(ref.transmittance_db, abs=1e-3)
    assert r.coarse_steps > 0  # free flight took whole coarse steps


def test_subharmonic_response_is_detected_with_its_period():
    r = simulate_point(cell(gamma_r=0.7, coupling="full"))
    assert r.converged and r.response_period == 2
    # whole impacts over the two measured periods
    assert (2 * np.array(r.impacts_per_period) % 1 == 0).all()


def test_adaptive_coarse_steps_change_nothing_but_cost():
    p = cell(gamma_r=1.5)
    a = simulate_point(p, SolverSettings(steps_per_period=1024))
    b = simulate_point(p, SolverSettings(steps_per_period=1024, adaptive=False))
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
    assert a.steps < b.steps


def _energy(state: np.ndarray, M: np.ndarray, K: np.ndarray) -> np.ndarray:
    n = M.shape[0]
    u, q = state[:, :n], state[:, n:]
    return 0.5 * np.einsum("ti,ij,tj->t", q, M, q) + 0.5 * np.einsum("ti,ij,tj->t", u, K, u)


def _energy_run(dt: float):
    spp = 200
    p = CellParams(
        theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=2 * math.pi / (dt * spp), xi=0.0,
        g1=0.1, g2=0.1, coupling="full",
    )  # fmt: skip
    sys_ = assemble(p)
    x0 = np.zeros(2 * sys_.ndof)
    x0[sys_.ndof] = 0.5  # η̇_1: the tip moves at 1.0 and reaches the stops
    periods = max(2, round(40.0 / (dt * spp)))
    r = simulate_point(
        p,
        SolverSettings(steps_per_period=spp, coarse_steps=spp, max_periods=periods,
                       window=1, early_stop=False),
        history_periods=periods, initial_state=x0, forcing=False,
    )  # fmt: skip
    h = r.history
    E = np.concatenate(
        [[_energy(x0[None, :], sys_.M, sys_.K)[0]], _energy(h["state"], sys_.M, sys_.K)]
    )
    contact = (h["impulse1"] > 0) | (h["impulse2"] > 0)
    dE = np.diff(E)
    return E[0], dE[~contact], dE[contact]


def test_energy_is_conserved_in_free_flight_and_contact_rise_vanishes():
    rises = []
    for dt in (0.02, 0.01, 0.005):
        e0, free, contact = _energy_run(dt)
        assert len(contact) > 10  # the tip did reach the stops
        assert np.max(np.abs(free)) < 1e-11 * e0  # exact propagator: round-off only
        assert np.sum(contact) < 0  # plastic impacts dissipate
        rises.append(max(np.max(contact), 1e-300) / e0)
    assert rises[1] < 0.5 * rises[0] and rises[2] < 0.5 * rises[1]


def test_irregular_points_are_classified_and_measured_on_the_window():
    r = simulate_point(cell(gamma_r=5.0), SolverSettings(max_periods=120, window=10))
    assert not r.converged and r.response_period == 0 and r.reason == "irregular"
    assert r.periods == 120 and math.isfinite(r.transmittance_db)


def test_early_stop_saves_periods():
    p = cell(gamma_r=0.85)
    a = simulate_point(p)
    b = simulate_point(p, SolverSettings(early_stop=False, max_periods=400, window=1))
    assert a.converged and a.periods < 200 < b.periods
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-6)


def test_non_finite_state_marks_the_point_failed_without_nan():
    sys_ = assemble(cell(gamma_r=1.0))
    x0 = np.full(2 * sys_.ndof, 1e308)
    r = simulate_point(cell(gamma_r=1.0, g1=1e6, g2=1e6), initial_state=x0)
    assert r.failed and "finite" in r.reason
    assert r.transmittance_db is None and r.theta_eff is None
    d = r.as_dict()
    assert all(not (isinstance(v, float) and not math.isfinite(v)) for v in d.values())


def test_euler_beyond_its_stability_limit_is_refused_with_the_largest_step():
    p = cell(gamma_r=0.3)
    T = 2 * math.pi / 0.3
    wmax = assemble(p).omega_max()
    n_unstable = math.floor(T * wmax / 2) - 1  # Δτ·ω̃_max > 2
    with pytest.raises(ValueError, match=r"largest stable step is Δτ < 0\.0447"):
        simulate_point(p, SolverSettings(method="euler", steps_per_period=n_unstable))
    # Explicit damping of the stiff modes makes the real limit tighter than 2/ω̃_max.
    with pytest.raises(
        ValueError, match=r"with this damping; the largest stable step is Δτ ≈ 0\.0425"
    ):
        simulate_point(p, SolverSettings(method="euler", steps_per_period=n_unstable + 3))
    r = simulate_point(p, SolverSettings(method="euler", steps_per_period=math.ceil(T / 0.042)))
    assert not r.failed and math.isfinite(r.transmittance_db)


def test_history_has_every_channel_and_bounded_length():
    r = simulate_point(cell(gamma_r=0.85), history_periods=2)
    h = r.history
    keys = {"tau", "s", "w_tip", "s_b", "s_dot", "s_b_dot", "theta_eff", "impulse1", "impulse2"}
    assert keys <= set(h)
    n = len(h["tau"])
    assert 0 < n <= 2 * 2048 and all(len(h[k]) == n for k in keys)
    assert np.all(np.diff(h["tau"]) > 0)
    assert np.max(h["w_tip"]) <= 0.1 + 1e-9 and np.min(h["w_tip"]) >= -0.1 - 1e-9
    assert np.any(h["impulse1"] > 0) and np.any(h["impulse2"] > 0)
    assert simulate_point(cell(gamma_r=0.85)).history is None


def test_asymmetric_gaps_hit_only_the_near_stop():
    r = simulate_point(cell(gamma_r=0.85, g1=0.1, g2=1e6), history_periods=1)
    assert r.impacts_per_period[0] >= 1 and r.impacts_per_period[1] == 0
    assert np.min(r.history["w_tip"]) < -0.1  # it swings past where stop 2 would be


def test_chunk_reports_bad_points_instead_of_raising():
    pts = [dict(BASE, gamma_r=1.0, g1=1e6, g2=1e6), dict(BASE, gamma_r=-1.0, g1=0.1, g2=0.1)]
    out = simulate_chunk(pts, {"steps_per_period": 256})
    assert len(out) == 2
    assert not out[0]["failed"] and out[0]["transmittance_db"] is not None
    assert out[1]["failed"] and "gamma_r must be > 0, got -1.0" in out[1]["reason"]
    assert out[1]["transmittance_db"] is None


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"method": "rk4"}, "method must be one of exponential, euler, event, got 'rk4'"),
        ({"steps_per_period": 2}, "steps_per_period must be an integer in 4"),
        ({"max_periods": 10, "window": 10}, "window must be < max_periods"),
        ({"periodicity_tol": 0.0}, "periodicity_tol must be in"),
    ],
)
def test_bad_solver_settings(kw, message):
    with pytest.raises(ValueError, match=message):
        SolverSettings(**kw)
