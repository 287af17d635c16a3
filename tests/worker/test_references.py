"""Every method against the closed forms (docs/model.md, "Checks with known answers").

Points are chosen where the answer depends on the physics: near the mass resonance, in the
isolation range and near the first pinned mode, both couplings, several damping ratios (a
near-static point, where Γ is 0.0009 dB whatever the model, would prove nothing). The
linear-tail proof is switched off so that each method integrates the impact-free response
itself instead of reporting the closed form. The extreme corners of the stress sweep (θ 1e-3 …
1e3, σ 1e-4 … 10, γ_r 0.01 … 50, ξ 0.5) are checked at default settings, as a study runs them.
This is the one module of closed-form checks; other tests use the closed forms only as values.
"""

import math

import numpy as np
import pytest
import scipy.linalg

from worker.model import (
    CellParams,
    assemble,
    linear_transmittance_db,
    pinned_max_re,
    pinned_transmittance_db,
)
from worker.simulate import SolverSettings, simulate_chunk, simulate_point

METHODS = ("event", "exponential", "euler")
# Γ tolerance (dB) at default resolution: event is exact between events, exponential exact in
# free flight (its error is the amplitude refinement), euler first order in Δτ.
LINEAR_TOL = {"event": 1e-6, "exponential": 1e-4, "euler": 5e-2}
PINNED_TOL = {"event": 1e-6, "exponential": 1e-4, "euler": 5e-2}
POINTS = [
    dict(gamma_r=0.9, coupling="paper", xi=0.05),
    dict(gamma_r=1.3, coupling="full", xi=0.02),
    dict(gamma_r=2.5, coupling="paper", xi=0.1, theta=1.0),
    dict(gamma_r=4.0, coupling="full", xi=0.05, sigma=0.1),
]


def cell(**kw) -> CellParams:
    return CellParams(**{"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, **kw})


def integrate(p: CellParams, method: str):
    return simulate_point(p, SolverSettings(method=method, linear_tail=False))


def test_the_points_are_sensitive_to_the_physics():
    for kw in POINTS:
        lin = linear_transmittance_db(cell(**kw, g1=1e6, g2=1e6))
        other_damping = linear_transmittance_db(cell(**{**kw, "xi": 2 * kw["xi"]}, g1=1, g2=1))
        assert abs(lin - other_damping) > 0.05
        pinned = pinned_transmittance_db(cell(**kw, g1=0.0, g2=0.0))
        assert abs(pinned - lin) > 0.5


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kw", POINTS, ids=lambda kw: f"{kw['coupling']}-{kw['gamma_r']}")
def test_huge_gaps_give_the_linear_frequency_response(method, kw):
    p = cell(**kw, g1=1e6, g2=1e6)
    r = integrate(p, method)
    assert r.outcome == "periodic" and r.response_period == 1 and r.contact_steps == 0
    assert r.transmittance_db == pytest.approx(linear_transmittance_db(p), abs=LINEAR_TOL[method])
    # and with the proof on, the closed form itself
    assert simulate_point(p, SolverSettings(method=method)).transmittance_db == (
        linear_transmittance_db(p)
    )


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kw", POINTS, ids=lambda kw: f"{kw['coupling']}-{kw['gamma_r']}")
def test_zero_gaps_give_the_pinned_linear_response(method, kw):
    p = cell(**kw, g1=0.0, g2=0.0)
    r = integrate(p, method)
    assert r.outcome == "periodic" and r.response_period == 1
    assert r.transmittance_db == pytest.approx(pinned_transmittance_db(p), abs=PINNED_TOL[method])


@pytest.mark.parametrize("kw", POINTS + [dict(gamma_r=0.85, sigma=1e-4, coupling="paper", xi=0.05)],
                         ids=lambda kw: f"{kw['coupling']}-{kw['gamma_r']}")  # fmt: skip
def test_zero_gaps_report_the_constrained_systems_exact_multiplier(kw):
    # independently of pinned_max_re's null-space reduction: the finite eigenvalues of the
    # constrained system as a matrix pencil in (u, u̇, μ), M ü + C u̇ + K u = X μ, Wᵀu = 0
    p = cell(**kw, g1=0.0, g2=0.0)
    sys_ = assemble(p)
    n = sys_.ndof
    A = np.zeros((2 * n + 1, 2 * n + 1))
    B = np.zeros_like(A)
    A[:n, n : 2 * n] = np.eye(n)
    A[n : 2 * n, :n] = -sys_.K
    A[n : 2 * n, n : 2 * n] = -sys_.C
    A[n : 2 * n, 2 * n] = sys_.X
    A[2 * n, :n] = sys_.W
    B[:n, :n] = np.eye(n)
    B[n : 2 * n, n : 2 * n] = sys_.M
    lam = scipy.linalg.eigvals(A, B)
    finite = lam[np.isfinite(lam) & (np.abs(lam) < 1e8)]
    assert len(finite) == 2 * (n - 1)  # the pinned cell has one degree of freedom fewer
    assert pinned_max_re(sys_) == pytest.approx(float(np.max(finite.real)), rel=1e-6)
    r = simulate_point(p)
    T = 2.0 * math.pi / p.gamma_r
    assert r.outcome == "periodic" and r.response_period == 1
    assert r.floquet_multiplier == pytest.approx(math.exp(T * np.max(finite.real)), rel=1e-6)
    assert r.transmittance_db == pytest.approx(pinned_transmittance_db(p), abs=1e-6)


# Extreme parameters (the stress sweep's corners): huge gaps (linear) and zero gaps (pinned), at
# default settings through simulate_chunk, with per-method Γ tolerances (dB).
EXTREME_BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1, gamma_r=0.85)
EXTREME_TOL = {"exponential": 1e-4, "event": 1e-6, "euler": 0.05}
EXTREME_TOL_PINNED = {"exponential": 1e-3, "event": 1e-5, "euler": 0.05}
EXTREME_LINEAR = [
    {"theta": 1e-3, "g1": 1e6, "g2": 1e6},
    {"theta": 1e3, "g1": 1e6, "g2": 1e6},
    {"sigma": 10.0, "g1": 1e6, "g2": 1e6, "coupling": "full"},
    {"gamma_r": 0.01, "g1": 1e6, "g2": 1e6},
    {"gamma_r": 50.0, "xi": 0.5, "g1": 1e6, "g2": 1e6, "coupling": "full"},
    {"xi": 0.5, "gamma_s": 10.0, "g1": 1e6, "g2": 1e6},
]
EXTREME_PINNED = [
    {"g1": 0.0, "g2": 0.0, "sigma": 1e-4},
    {"g1": 0.0, "g2": 0.0, "sigma": 10.0, "coupling": "full"},
    {"g1": 0.0, "g2": 0.0, "gamma_s": 0.1, "gamma_r": 2.0},
    {"g1": 0.0, "g2": 0.0, "xi": 0.5, "modes": 1, "coupling": "full"},
]


@pytest.mark.parametrize("method", METHODS)
def test_extreme_points_match_the_closed_forms(method):
    cases = [(kw, linear_transmittance_db, EXTREME_TOL) for kw in EXTREME_LINEAR]
    cases += [(kw, pinned_transmittance_db, EXTREME_TOL_PINNED) for kw in EXTREME_PINNED]
    pts = [{**EXTREME_BASE, **kw} for kw, _, _ in cases]
    for (kw, ref, tol), rec in zip(cases, simulate_chunk(pts, {"method": method}), strict=True):
        assert not rec["failed"], (kw, rec["reason"])
        assert rec["outcome"] in ("linear", "periodic") and rec["response_period"] == 1, kw
        expected = ref(CellParams(**{**EXTREME_BASE, **kw}))
        assert rec["transmittance_db"] == pytest.approx(expected, abs=tol[method]), kw


def _energy(state: np.ndarray, M: np.ndarray, K: np.ndarray) -> np.ndarray:
    n = M.shape[0]
    u, q = state[:, :n], state[:, n:]
    return 0.5 * np.einsum("ti,ij,tj->t", q, M, q) + 0.5 * np.einsum("ti,ij,tj->t", u, K, u)


def _energy_run(method: str, dt: float):
    """Full coupling, no damping, no forcing, the tip launched at the stops."""
    spp = 200
    p = cell(gamma_r=2 * math.pi / (dt * spp), xi=0.0, g1=0.1, g2=0.1, coupling="full")
    sys_ = assemble(p)
    x0 = np.zeros(2 * sys_.ndof)
    x0[sys_.ndof] = 0.5  # η̇_1: the tip moves at 1.0
    periods = max(2, round(40.0 / (dt * spp)))
    r = simulate_point(
        p,
        SolverSettings(method=method, steps_per_period=spp, coarse_steps=spp,
                       max_periods=periods, window=1, early_stop=False),
        history_periods=periods, initial_state=x0, forcing=False,
    )  # fmt: skip
    h = r.history
    E = np.concatenate([_energy(x0[None, :], sys_.M, sys_.K), _energy(h["state"], sys_.M, sys_.K)])
    contact = (h["impulse1"] > 0) | (h["impulse2"] > 0) | np.isin(h["kind"], (1, 2))
    return E[0], np.diff(E)[~contact], np.diff(E)[contact]


def test_energy_exponential_free_flight_is_exact_and_contact_rise_vanishes():
    rises = []
    for dt in (0.02, 0.01, 0.005):
        e0, free, contact = _energy_run("exponential", dt)
        assert len(contact) > 10  # the tip did reach the stops
        assert np.max(np.abs(free)) < 1e-11 * e0  # exact propagator: round-off only
        assert np.sum(contact) < 0  # plastic impacts dissipate
        rises.append(max(np.max(contact), 1e-300) / e0)
    assert rises[1] < 0.5 * rises[0] and rises[2] < 0.5 * rises[1]


def test_energy_event_is_constant_between_impacts_and_drops_at_each():
    e0, free, contact = _energy_run("event", 0.01)
    assert len(contact) > 5
    assert np.max(np.abs(free)) < 1e-12 * e0
    assert np.all(contact < 1e-14 * e0)
