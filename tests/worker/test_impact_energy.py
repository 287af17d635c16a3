"""The energy the impacts dissipate (docs/model.md §6): ``impact_energy`` per stop against the
event method's own impulses, time stepping converging to it, elastic and Newton impacts in
closed form, and ``impact_energy_share`` against an energy balance computed independently
from the orbit's history."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from worker.model import CellParams, assemble
from worker.model.chain import ChainParams
from worker.simulate import SolverSettings, simulate_chain_point, simulate_point
from worker.solvers import measure as ms
from worker.solvers.exponential import ExponentialRun
from worker.solvers.linear import linear_tail

# periodic with every method: one impact a period at each stop, stuck after each
CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=0.1, g2=0.1, modes=3)
FULL = dataclasses.replace(CELL, coupling="full")


@pytest.mark.parametrize("cell", [CELL, FULL], ids=["paper", "full"])
def test_a_plastic_impact_takes_half_the_square_of_its_approach_velocity_over_g(cell):
    r = simulate_point(cell, SolverSettings(method="event"), history_periods=1)
    assert r.outcome == "periodic" and r.response_period == 1
    h, sys_ = r.history, assemble(cell)
    for stop in (1, 2):
        at = h["kind"] == stop  # the impacts: the impulse P = −v⁻/G, so ½v⁻²/G = ½GP²
        assert at.sum() >= 1  # (full: at stop 1 one leaves at once, the next sticks)
        expected = 0.5 * sys_.G * np.sum(h[f"impulse{stop}"][at] ** 2)
        assert r.impact_energy[stop - 1] == pytest.approx(expected, rel=1e-12)
    if cell.coupling == "full":  # and it is the kinetic energy ½qᵀMq the impacts remove
        N, X = sys_.ndof, h["state"]
        ke = np.array([0.5 * x[N:] @ sys_.M @ x[N:] for x in X])
        k = np.flatnonzero(np.isin(h["kind"], (1, 2)))
        assert sum(r.impact_energy) == pytest.approx(np.sum(ke[k - 1] - ke[k]), rel=1e-12)
    assert r.impact_energy_se is None


@pytest.mark.parametrize("method", ["euler", "exponential"])
def test_time_stepping_converges_to_the_event_methods_energy_at_first_order(method):
    ref = np.array(simulate_point(FULL, SolverSettings(method="event")).impact_energy)

    def worst(base: int) -> float:
        # exponential's error changes sign with where the impact falls within a step: its
        # bound over eight step counts of an octave is what falls as Δτ
        counts = [base + k * base // 8 for k in range(8)] if method == "exponential" else [base]
        errs = []
        for spp in counts:
            r = simulate_point(FULL, SolverSettings(method=method, steps_per_period=spp))
            assert r.outcome == "periodic"
            errs.append(np.max(np.abs(np.subtract(r.impact_energy, ref)) / ref))
        return max(errs)

    coarse, fine = worst(2048), worst(8192)
    # four times the steps: a quarter of the error at first order (measured: 4.0 for euler,
    # 3.5 for exponential)
    assert 2.5 < coarse / fine < 6.0
    assert fine < (0.15 if method == "euler" else 3e-4)


def free_rows(periods: int, e: float, gamma_r: float = 1.0) -> tuple:
    """An unforced, undamped cell (full coupling) whose tip starts at 3 towards stop 1, run by
    ``exponential`` with restitution ``e`` at both stops for periods of 2π/γ_r: its period
    rows, history and system."""
    p = dataclasses.replace(FULL, xi=0.0, gamma_r=gamma_r, e1=e, e2=e)
    sys_ = assemble(p)
    run = ExponentialRun(sys_, SolverSettings(method="exponential", steps_per_period=1024),
                         linear_tail(sys_, False), False, 1e9)  # fmt: skip
    N = sys_.ndof
    x0 = np.zeros(2 * N)
    x0[N:] = np.linalg.lstsq(sys_.W[None, :], [3.0], rcond=None)[0]
    run.reset(x0)
    run.keep_history(periods * (1024 + 8) * 2)
    rows = np.zeros((periods, ms.ROW))
    run.advance(periods, False, 0, rows, np.zeros((periods, run.nx)))
    return rows, run.history(p, sys_.kappa), sys_, x0


def test_an_elastic_impact_takes_no_energy():
    rows, h, sys_, _ = free_rows(10, 1.0)
    impacts = (h["impulse1"] > 0).sum() + (h["impulse2"] > 0).sum()
    assert impacts > 200
    scale = 0.5 * 3.0**2 / sys_.G  # one impact's ½v⁻²/G
    assert np.max(np.abs(rows[:, [ms.M_EN1, ms.M_EN2]])) < 1e-12 * scale


def test_a_newton_impact_takes_one_minus_e_squared_of_it():
    e = 0.5
    # a short period: its impacts all rebound (the tip has not come to rest on a stop yet)
    rows, h, sys_, x0 = free_rows(1, e, gamma_r=2.0)
    N = sys_.ndof
    before = np.vstack([x0, h["state"][:-1]])  # each step's start
    for stop, sign in ((1, 1.0), (2, -1.0)):
        k = np.flatnonzero(h[f"impulse{stop}"] > 0)
        assert len(k) >= 2
        v = sign * (before[k, N:] @ sys_.W)  # approach velocities, towards the stop
        # Newton's impulse (1 + e) v⁻/G at once (no resting contact in this free run) …
        np.testing.assert_allclose(h[f"impulse{stop}"][k] * sys_.G, (1 + e) * v, rtol=1e-12)
        # … takes ½(1 − e²)v⁻²/G
        expected = np.sum(0.5 * (1 - e * e) * v * v / sys_.G)
        assert rows[0, ms.M_EN1 + stop - 1] == pytest.approx(expected, rel=1e-12)


def dissipation_by_quadrature(r, cell: CellParams) -> tuple[float, float, float]:
    """(W_F, ∫ qᵀCq, impacts' kinetic energy) over the orbit's period from its history alone:
    each piece between samples propagated exactly (scipy's expm of the free, or the stuck,
    dynamics) from the sample's state to 12 Gauss nodes; an impact is a sample pair at one τ."""
    from scipy.linalg import expm

    sys_ = assemble(cell)
    n, g = sys_.ndof, cell.gamma_r
    A = sys_.augmented_matrix()
    # stuck on a stop: the contact force keeps the tip's acceleration zero
    stuck = A.copy()
    stuck[n : 2 * n] = (np.eye(n) - np.outer(sys_.Minv @ sys_.X, sys_.W) / sys_.G) @ A[n : 2 * n]
    h = r.history
    tau = np.r_[0.0, h["tau"]]  # the orbit's start, then the samples
    X = np.vstack([r.final_state, h["state"]])
    kind = np.r_[0, h["kind"]]
    nodes, weights = np.polynomial.legendre.leggauss(12)
    work = visc = kinetic = 0.0
    for i in range(len(tau) - 1):
        if kind[i + 1] in (1, 2):
            q0, q1 = X[i, n:], X[i + 1, n:]
            kinetic += 0.5 * (q0 @ sys_.M @ q0 - q1 @ sys_.M @ q1)
        dt = tau[i + 1] - tau[i]
        if dt <= 0.0:
            continue
        z0 = np.r_[X[i], np.cos(g * tau[i]), np.sin(g * tau[i])]
        w, wd = sys_.W @ X[i, :n], sys_.W @ X[i, n:]
        acc = sys_.W @ (A @ z0)[n : 2 * n]  # the tip's acceleration if free
        on = (abs(w - cell.g1) < 1e-9 and acc > 0) or (abs(w + cell.g2) < 1e-9 and acc < 0)
        B = stuck if on and abs(wd) < 1e-9 and kind[i] not in (3, 4) else A
        assert np.max(np.abs((expm(B * dt) @ z0)[: 2 * n] - X[i + 1])) < 1e-10
        for t, wt in zip(0.5 * dt * (nodes + 1), 0.5 * dt * weights, strict=True):
            z = expm(B * t) @ z0
            q = z[n : 2 * n]
            visc += wt * q @ sys_.C @ q
            work += wt * q[-1] * (sys_.f_sin * z[2 * n + 1] + sys_.f_cos * z[2 * n])
    return work, visc, kinetic


@pytest.mark.parametrize("e", [0.0, 0.5])
def test_the_forcings_work_is_the_dashpots_and_the_impacts_energy(e):
    """Plastic impacts, and rebounds whose sequences accumulate (e = 0.5)."""
    cell = dataclasses.replace(FULL, e1=e, e2=e)
    r = simulate_point(cell, SolverSettings(method="event"), history_periods=1)
    assert r.outcome == "periodic" and r.response_period == 1
    work, visc, kinetic = dissipation_by_quadrature(r, cell)
    E = sum(r.impact_energy)
    assert kinetic == pytest.approx(E, rel=1e-12)
    # the balance over the orbit (measured: 2e-14), and W_F as the result forms it from the
    # period's first harmonic of s (share = E / W_F)
    assert abs(work - visc - E) < 1e-9 * work
    assert E / r.impact_energy_share == pytest.approx(work, rel=1e-9)
    assert 0.1 < r.impact_energy_share < 0.2


def test_the_share_only_where_the_energy_balances():
    full = simulate_point(FULL, SolverSettings(method="event"))
    assert full.outcome == "periodic" and 0.0 < full.impact_energy_share < 1.0
    paper = simulate_point(CELL, SolverSettings(method="event"))
    assert paper.outcome == "periodic" and paper.impact_energy_share is None
    assert paper.impact_energy[0] > 0 and paper.impact_energy[1] > 0
    # time stepping: the same share, to its step's error
    r = simulate_point(FULL, SolverSettings(method="exponential", steps_per_period=8192))
    assert r.impact_energy_share == pytest.approx(full.impact_energy_share, rel=1e-3)
    # no impacts: none of the damping's work (0), where paper coupling has no balance (None)
    for coupling, share in (("full", 0.0), ("paper", None)):
        lin = simulate_point(dataclasses.replace(FULL, g1=50.0, g2=50.0, coupling=coupling))
        assert lin.outcome == "linear" and lin.impact_energy == (0.0, 0.0)
        assert lin.impact_energy_share == share
    chain = simulate_chain_point(ChainParams(FULL, 2), SolverSettings(method="euler"))
    assert chain.impact_energy is None and chain.impact_energy_se is None
    assert chain.impact_energy_share is None


def test_an_irregular_point_has_error_bars():
    r = simulate_point(dataclasses.replace(CELL, modes=5), SolverSettings())
    assert r.outcome in ("irregular", "unsettled")
    assert all(e > 0 for e in r.impact_energy)
    assert all(0 < s < 0.5 * e for s, e in zip(r.impact_energy_se, r.impact_energy, strict=True))
    assert r.impact_energy_share is None  # paper coupling
    # undamped, full coupling: the impacts are all that dissipates (the windows' mean)
    r = simulate_point(dataclasses.replace(FULL, xi=0.0), SolverSettings())
    assert r.outcome in ("irregular", "unsettled")
    assert r.impact_energy_share == pytest.approx(1.0, abs=0.02)
