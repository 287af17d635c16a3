"""The event-driven solver: regimes, located events, grazing, chattering, far stops."""

import math

import numpy as np
import pytest

from worker.model import CellParams, assemble, steady_state
from worker.simulate import SolverSettings, simulate_point
from worker.solvers.event.regimes import prepare_event, stuck_matrices

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)
EVENT = SolverSettings(method="event")


def cell(**kw) -> CellParams:
    return CellParams(**{**BASE, **kw})


@pytest.mark.parametrize("w_star", [-0.1, 0.0, 0.37, 1e12])
def test_stuck_regime_is_the_constrained_system(w_star):
    """The reduced stuck dynamics equal the free dynamics plus the contact force along M⁻¹X."""
    rng = np.random.default_rng(1)
    for coupling in ("paper", "full"):
        s = assemble(cell(gamma_r=1.3, coupling=coupling))
        N = s.ndof
        A, _, Qout, mu = stuck_matrices(s)
        y = rng.standard_normal(2 * N + 1)
        y[-1] = w_star  # the stop's position is the last state
        z = Qout @ y
        u, q = z[:N], z[N : 2 * N]
        h = -s.C @ q - s.K @ u
        h[-1] += z[2 * N] * s.f_cos + z[2 * N + 1] * s.f_sin
        force = -(s.W @ s.Minv @ h) / s.G  # keeps Wᵀq̇ = 0
        assert mu @ y == pytest.approx(force, rel=1e-10, abs=1e-12 * abs(w_star))
        assert s.W @ u == pytest.approx(w_star, rel=1e-13, abs=1e-13)
        zdot = Qout @ (A @ y)
        qdot = s.Minv @ (h + s.X * force)
        scale = 1.0 + abs(w_star)
        np.testing.assert_allclose(zdot[:N], q, atol=1e-12 * scale)
        np.testing.assert_allclose(zdot[N : 2 * N], qdot, atol=1e-11 * scale)


@pytest.mark.parametrize("modes", [1, 5, 30])
@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_regime_modes_built_from_the_cells_own_reconstruct_each_regime(modes, coupling):
    # The regimes' eigen-decompositions are assembled from the cell's own (γ_r-free) modes
    # and the forcing oscillator's in closed form: in reduced form (one of each conjugate
    # pair, weight folded into V) they must give back the identity and the regime matrix.
    for g in (0.3, 1.7, 6.0):
        s = assemble(cell(gamma_r=g, g1=0.1, g2=0.1, coupling=coupling, modes=modes))
        ea = prepare_event(s, 64)
        A1 = stuck_matrices(s)[0]
        for r, A in ((0, s.augmented_matrix()), (1, A1)):
            nz, m = A.shape[0], ea.nk[r]
            V, Vi, lam = ea.V[r, :nz, :m], ea.Vi[r, :m, :nz], ea.lam[r, :m]
            scale = np.max(np.abs(A))
            np.testing.assert_allclose((V @ Vi).real, np.eye(nz), atol=1e-9)
            np.testing.assert_allclose(((V * lam) @ Vi).real, A, atol=1e-9 * scale)
            # the forcing mode is set from the exact phase: its coefficient of (c, s) = (1, 0)
            f = ea.fidx[r]
            assert f >= 0 and lam[f] == pytest.approx(1j * g)
            np.testing.assert_allclose(ea.fcs[r], Vi[f, nz - (2 if r == 0 else 3) :][:2])


def test_regimes_stay_well_conditioned_whatever_the_clearance():
    for g in (0.2, 1.0, 6.0):
        for gap in (0.1, 1e6, 1e12):
            assert prepare_event(assemble(cell(gamma_r=g, g1=gap, g2=gap)), 128).cond < 1e6


def test_a_stop_the_motion_cannot_reach_is_no_constraint():
    # stop 1 at 1e12, stop 2 at 0.1: the same answer as a stop 1 at 1e6
    far = simulate_point(cell(gamma_r=1.3, g1=1e12, g2=0.1))
    near = simulate_point(cell(gamma_r=1.3, g1=1e6, g2=0.1))
    assert far.outcome == near.outcome == "periodic"
    assert far.transmittance_db == pytest.approx(near.transmittance_db, abs=1e-10)
    assert far.impacts_per_period[0] == 0 and far.impacts_per_period[1] > 0
    both = simulate_point(cell(gamma_r=1.3, g1=1e12, g2=1e12))
    assert both.outcome == "linear"


@pytest.mark.parametrize(
    "coupling, gamma_r, gap",
    [("paper", 0.85, 0.1), ("full", 0.85, 0.1), ("paper", 0.446, 0.1), ("full", 0.6, 0.3)],
)
def test_sub_grid_sets_the_cost_not_the_answer(coupling, gamma_r, gap):
    # Every measured integral is exact over its segment (primitives.py), so the phase-portrait
    # slope too is the same on any sub-grid. (With 4-point Gauss rules per interval it moved by
    # up to 5e-4 between 16 and 256 intervals at γ_r 0.45-0.6, where the beam's fifth mode
    # turns up to 1.5 times in one interval.)
    p = cell(gamma_r=gamma_r, coupling=coupling, g1=gap, g2=gap)
    a = simulate_point(p, SolverSettings(steps_per_period=16, near_margin=0.0))
    b = simulate_point(p, SolverSettings(steps_per_period=256))
    assert a.outcome == b.outcome == "periodic"
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
    assert a.theta_eff == pytest.approx(b.theta_eff, abs=1e-9)
    assert a.theta_eff_slope == pytest.approx(b.theta_eff_slope, abs=1e-9)
    assert a.impacts_per_period == b.impacts_per_period


def test_impact_times_close_the_gap_to_round_off():
    r = simulate_point(cell(gamma_r=2.0), EVENT, history_periods=2)
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
    r = simulate_point(
        p, SolverSettings(max_periods=8, window=1, early_stop=False),
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


def test_grazing_contact_is_found_between_sub_grid_samples():
    # On the linear orbit with the gap 1e-8 (relative) inside the tip amplitude, the tip grazes
    # the stop once per swing; 8 samples per period never see the gap close.
    lin = cell(gamma_r=1.5, g1=1e6, g2=1e6)
    ss = steady_state(assemble(lin))
    x0, amp = ss.state_at_phase_zero(), ss.tip_amplitude
    g = amp * (1.0 - 1e-8)
    p = cell(gamma_r=1.5, g1=g, g2=g)
    first = []
    for kw in ({"steps_per_period": 8, "near_margin": 0.0}, {"steps_per_period": 512}):
        settings = SolverSettings(max_periods=3, window=1, early_stop=False, **kw)
        r = simulate_point(p, settings, history_periods=3, initial_state=x0)
        ev = r.history["events"]
        assert not r.failed and len(ev) > 0 and ev[0, 1] == 1.0
        assert ev[0, 0] < 2 * math.pi / 1.5  # in the first period
        assert 0.0 <= ev[0, 4] < 1e-3  # a grazing (light) impact
        first.append(ev[0])
    assert first[0][0] == pytest.approx(first[1][0], abs=1e-9)
    # From rest, near-grazing gaps settle on an impacting orbit, and the sub-grid changes
    # nothing.
    a, b = (
        simulate_point(p, SolverSettings(**kw))
        for kw in ({"steps_per_period": 8, "near_margin": 0.0}, {"steps_per_period": 512})
    )
    for res in (a, b):
        assert res.outcome == "periodic" and res.contact_steps > 0
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
    assert a.impacts_per_period == b.impacts_per_period


def test_chattering_is_ended_by_the_event_budget():
    p = cell(gamma_r=1.2, g1=0.01, g2=0.01)
    r = simulate_point(p, SolverSettings(max_periods=40, window=5, max_events_per_period=3))
    assert r.failed and "event budget exceeded" in r.reason and r.transmittance_db is None
    assert r.periods == 1  # stopped in the period where the budget ran out, not at the end
    # with the default budget the same point runs to a result
    r = simulate_point(p, SolverSettings(max_periods=40, window=5))
    assert not r.failed and r.contact_steps > 3 * r.periods


def test_the_event_budget_is_a_solver_setting():
    p = cell(gamma_r=1.2, g1=0.01, g2=0.01)
    small = simulate_point(p, SolverSettings(max_periods=40, window=5, max_events_per_period=3))
    assert small.failed and "more than 3 events in period 1" in small.reason
    assert "max_events_per_period raises the budget" in small.reason  # what to do about it
    # the default budget given explicitly is the default
    big = simulate_point(p, SolverSettings(max_periods=40, window=5, max_events_per_period=1000))
    default = simulate_point(p, SolverSettings(max_periods=40, window=5))
    assert not big.failed
    assert big.as_dict() | {"wall_s": 0} == default.as_dict() | {"wall_s": 0}


def test_bad_event_options_are_refused_with_the_field():
    with pytest.raises(ValueError, match="event_tol must be in"):
        simulate_point(cell(gamma_r=1.0), EVENT, event_tol=0.0)
    with pytest.raises(ValueError, match="max_events_per_period must be an integer"):
        simulate_point(cell(gamma_r=1.0), SolverSettings(max_events_per_period=0))
    # one place for the budget: the setting, not also a method option
    with pytest.raises(ValueError, match="method event takes no option max_events_per_period"):
        simulate_point(cell(gamma_r=1.0), EVENT, max_events_per_period=1000)
