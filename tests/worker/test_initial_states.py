"""Initial states (worker/initial.py): rest, linear, random, the projection onto the stops, and
the final state a point hands on (docs/solvers.md, "Initial states and sweep lines")."""

import numpy as np
import pytest

from worker.model import CellParams, assemble, steady_state
from worker.simulate import (
    initial_state,
    parse_initial,
    project_admissible,
    simulate_chunk,
    simulate_point,
)
from worker.solvers.linear import linear_tail

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)
# an impacting period-1 orbit from rest (Γ 13.61 dB, docs/model.md §9)
IMPACTING = dict(BASE, gamma_r=0.85, g1=0.1, g2=0.1)


def cell(**kw) -> CellParams:
    return CellParams(**{**BASE, **kw})


def gap_violation(sys_, x: np.ndarray) -> float:
    """How far the tip is beyond a stop (<= 0: admissible)."""
    w = float(sys_.W @ x[: sys_.ndof])
    return max(w - sys_.params.g1, -sys_.params.g2 - w)


# --------------------------------------------------------------------------- rest and linear


def test_absent_initial_is_rest_bit_for_bit():
    a = simulate_chunk([IMPACTING])[0]
    b = simulate_chunk([dict(IMPACTING, initial={"kind": "rest", "seed": None, "index": 0})])[0]
    c = simulate_chunk([dict(IMPACTING, initial=None)])[0]
    for r in (b, c):
        assert {k: v for k, v in r.items() if k != "wall_s"} == {
            k: v for k, v in a.items() if k != "wall_s"
        }
    assert a["outcome"] == "periodic" and a["periods"] > 0
    assert np.array_equal(initial_state(cell(**_cell_keys(IMPACTING)), None), np.zeros(12))


def _cell_keys(pt: dict) -> dict:
    return {k: v for k, v in pt.items() if k not in BASE}


def test_linear_start_of_an_impact_free_point_ends_linear_at_once():
    # γ_r 2.5, gap 0.5: the linear tip amplitude is 0.119, far inside the clearance
    p = cell(gamma_r=2.5, g1=0.5, g2=0.5)
    ss = steady_state(assemble(p))
    assert abs(ss.W @ ss.U) < 0.2
    x0 = initial_state(p, {"kind": "linear"})
    assert np.array_equal(x0, linear_tail(assemble(p)).xp0)
    r = simulate_chunk([dict(BASE, gamma_r=2.5, g1=0.5, g2=0.5, initial={"kind": "linear"})])[0]
    assert r["outcome"] == "linear" and r["periods"] == 0 and r["steps"] == 0
    assert r["transmittance_db"] == ss.transmittance_db
    # from rest the same point needs a transient before the tail is proven
    rest = simulate_chunk([dict(BASE, gamma_r=2.5, g1=0.5, g2=0.5)])[0]
    assert rest["outcome"] == "linear" and rest["periods"] > 0


def test_linear_state_without_forcing_is_rest():
    p = cell(gamma_r=1.5)
    assert np.array_equal(initial_state(p, {"kind": "linear"}, forcing=False), np.zeros(12))


def test_bad_initial_entries_are_refused_and_reported():
    p = cell(gamma_r=1.0)
    for bad, word in (
        ({"kind": "chaos"}, "kind"),
        ({"kind": "random", "seed": -1}, "seed"),
        ({"kind": "random", "index": 1.5}, "index"),
        ({"kind": "linear", "sed": 1}, "unknown"),
        (3, "mapping"),
    ):
        with pytest.raises(ValueError, match=word):
            initial_state(p, bad)
    rec = simulate_chunk([dict(BASE, gamma_r=1.0, initial={"kind": "chaos"})])[0]
    assert rec["outcome"] == "failed" and "kind" in rec["reason"]
    assert rec["transmittance_linear_db"] is not None  # the cell is fine, its start is not
    assert parse_initial("linear") == ("linear", 0, 0)


def test_linear_start_at_an_undamped_resonance_is_refused():
    # ξ = ξ_b = 0 and γ_r on the mass's natural frequency 1/γ_s: no linear steady state
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, xi=0.0, modes=1)
    with pytest.raises(ValueError, match="undamped resonance"):
        initial_state(p, {"kind": "linear"})


# --------------------------------------------------------------------------- projection


def _min_norm_kkt(sys_, u: np.ndarray, target: float) -> np.ndarray:
    """Independent minimiser of |Δη|² with Wᵀ(u + Δu) = target and Δs = 0 (KKT system)."""
    n = sys_.ndof - 1
    phi = sys_.W[:n]
    kkt = np.zeros((n + 1, n + 1))
    kkt[:n, :n] = 2.0 * np.eye(n)
    kkt[:n, n] = phi
    kkt[n, :n] = phi
    rhs = np.zeros(n + 1)
    rhs[n] = target - float(sys_.W @ u)
    sol = np.linalg.solve(kkt, rhs)
    return np.append(sol[:n], 0.0)


@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_projection_is_the_smallest_change_onto_the_violated_stop(coupling):
    p = cell(gamma_r=1.0, g1=0.1, g2=0.3, coupling=coupling)
    sys_ = assemble(p)
    N = sys_.ndof
    rng = np.random.default_rng(7)
    for sign, target in ((1.0, 0.1), (-1.0, -0.3)):
        x = rng.standard_normal(2 * N)
        x[:N] *= 0.05
        x[0] = sign * 1.0  # mode 1 alone puts the tip 2.0 beyond either stop
        assert gap_violation(sys_, x) > 1.0
        y = project_admissible(sys_, x)
        # on the stop up to the round-off of Wᵀu (|W|·|u| ≈ 3 here)
        assert gap_violation(sys_, y) <= 1e-14
        assert float(sys_.W @ y[:N]) == pytest.approx(target, abs=1e-14)
        du = _min_norm_kkt(sys_, x[:N], target)
        np.testing.assert_allclose(y[:N] - x[:N], du, rtol=1e-12, atol=1e-15)
        assert y[N - 1] == x[N - 1]  # s is not part of the gap: untouched
        # any other admissible change along the stop is larger (a random feasible direction)
        z = rng.standard_normal(N)
        z[-1] = 0.0
        z -= sys_.W * (sys_.W @ z) / (sys_.W @ sys_.W)
        assert np.linalg.norm(du + 0.01 * z) > np.linalg.norm(du)
        # the velocity into the stop is removed, the velocity away from it kept
        wd = float(sys_.W @ y[N:])
        assert (wd <= 1e-12) if sign > 0 else (wd >= -1e-12)
        # projecting twice changes nothing
        assert np.array_equal(project_admissible(sys_, y), y)


def test_projection_removes_only_an_approaching_velocity():
    sys_ = assemble(cell(gamma_r=1.0, g1=0.1, g2=0.1))
    N = sys_.ndof
    W = sys_.W
    x = np.zeros(2 * N)
    x[:N] = W * 0.1 / (W @ W)  # the tip exactly on stop 1
    x[N:] = W * 0.7 / (W @ W)  # moving into it at ẇ = 0.7
    x[-1] = 0.3  # the mass moves too: kept
    y = project_admissible(sys_, x)
    assert float(W @ y[N:]) == pytest.approx(0.0, abs=1e-15)
    assert np.array_equal(y[:N], x[:N]) and y[-1] == 0.3
    away = x.copy()
    away[N:] = -x[N:]
    assert np.array_equal(project_admissible(sys_, away), away)


def test_projection_leaves_admissible_states_unchanged():
    sys_ = assemble(cell(gamma_r=1.0, g1=0.5, g2=0.5))
    N = sys_.ndof
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.standard_normal(2 * N) * 0.02
        assert gap_violation(sys_, x) < 0.0
        assert np.array_equal(project_admissible(sys_, x), x)


def test_projection_pins_the_tip_for_zero_gaps():
    sys_ = assemble(cell(gamma_r=1.0, g1=0.0, g2=0.0))
    N = sys_.ndof
    for sign in (1.0, -1.0):
        x = np.full(2 * N, sign * 0.2)
        y = project_admissible(sys_, x)
        assert abs(float(sys_.W @ y[:N])) <= 1e-15 and abs(float(sys_.W @ y[N:])) <= 1e-15


def test_projection_refuses_a_state_of_the_wrong_size():
    with pytest.raises(ValueError, match="12 finite numbers"):
        project_admissible(assemble(cell(gamma_r=1.0)), np.zeros(10))


# --------------------------------------------------------------------------- random


def test_random_states_are_reproducible_from_seed_and_index():
    p = cell(gamma_r=0.85, g1=0.1, g2=0.1)
    sys_ = assemble(p)
    a = initial_state(p, {"kind": "random", "seed": 5, "index": 2})
    b = initial_state(p, {"kind": "random", "seed": 5, "index": 2})
    c = initial_state(p, {"kind": "random", "seed": 5, "index": 3})
    d = initial_state(p, {"kind": "random", "seed": 6, "index": 2})
    assert np.array_equal(a, b)
    assert not np.allclose(a, c) and not np.allclose(a, d)
    assert np.array_equal(initial_state(p, {"kind": "random", "seed": None, "index": 1}),
                          initial_state(p, {"kind": "random", "seed": 0, "index": 1}))  # fmt: skip
    # around the linear state, at the size of the linear motion or the gaps, admissible
    lin = initial_state(p, {"kind": "linear"})
    N = sys_.ndof
    scale = max(np.max(np.abs(lin[:N])), np.max(np.abs(lin[N:])) / 0.85, 0.1)
    for k in range(10):
        x = initial_state(p, {"kind": "random", "seed": 1, "index": k})
        assert gap_violation(sys_, x) <= 1e-12 * 0.1
        # s and ṡ are never moved by the projection: S·z and S·γ_r·z with |z| < 6
        ds = np.abs(x[[N - 1, 2 * N - 1]] - lin[[N - 1, 2 * N - 1]])
        assert ds.max() > 0.0 and np.all(ds < 6.0 * scale * np.array([1.0, 0.85]))
    # a random start runs to the same impacting orbit as rest here (one attractor)
    rnd = simulate_chunk([dict(IMPACTING, initial={"kind": "random", "seed": 1, "index": 0})])
    rest = simulate_chunk([IMPACTING])
    assert rnd[0]["outcome"] == rest[0]["outcome"] == "periodic"
    assert rnd[0]["transmittance_db"] == pytest.approx(rest[0]["transmittance_db"], abs=1e-6)


# --------------------------------------------------------------------------- final state


def test_final_state_is_a_period_boundary_of_the_reported_response():
    p = cell(**_cell_keys(IMPACTING))
    r = simulate_point(p)
    assert r.outcome == "periodic" and r.final_state is not None
    assert "final_state" not in r.as_dict()
    # started on its own orbit, the point repeats it at once
    again = simulate_point(p, initial_state=r.final_state)
    assert again.outcome == "periodic"
    assert again.transmittance_db == pytest.approx(r.transmittance_db, abs=1e-8)
    assert again.periods < r.periods
    np.testing.assert_allclose(again.final_state, r.final_state, rtol=0, atol=1e-8)
    # linear: the closed-form state at phase 0
    q = cell(gamma_r=2.5, g1=0.5, g2=0.5)
    lin = simulate_point(q)
    assert lin.outcome == "linear"
    assert np.array_equal(lin.final_state, linear_tail(assemble(q)).xp0)
    # failed: none
    bad = simulate_point(CellParams(theta=500.0, sigma=0.05, gamma_s=1.0, gamma_r=1.0))
    assert bad.outcome == "failed" and bad.final_state is None
