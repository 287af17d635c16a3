"""The linear reference in every point result: Γ_lin (the same cell without stops, closed form)
and the impact effect Γ − Γ_lin (docs/solvers.md, "The linear reference")."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from worker.model import CellParams
from worker.simulate import SolverSettings, linear_reference, simulate_chunk, simulate_point

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)


def cell(**kw: float | int | str) -> CellParams:
    return CellParams(**{**BASE, **kw})  # type: ignore[arg-type]


def paper_transmissibility_db(gamma_r: float, gamma_s: float, xi: float) -> float:
    """Base-excitation transmissibility |1 + 2iξr| / |1 − r² + 2iξr|, r = γ_rγ_s: Γ_lin of the
    paper coupling, where the outer mass ignores the beam (docs/model.md §7), written here
    without the project's assembly."""
    r = gamma_r * gamma_s
    return 20.0 * math.log10(abs(1 + 2j * xi * r) / abs(1 - r * r + 2j * xi * r))


def full_one_mode_db(p: CellParams) -> float:
    """Γ_lin of the ``full`` coupling with one mode, assembled by hand from docs/model.md §2, §4:
    β₁ the first root of cos β cosh β = −1, d₁ = 2σ₁/β₁, M = [[1, −d₁], [−d₁, 1/θ + 1]],
    K = diag(σβ₁⁴, 1/(θγ_s²)), C = diag(2ξ_b ω̃₁, 2ξ/(θγ_s)) (Rayleigh with n = 1)."""
    beta = 1.8751040687119611
    s1 = (math.sinh(beta) - math.sin(beta)) / (math.cosh(beta) + math.cos(beta))
    d1 = 2.0 * s1 / beta
    th, gs, g, xi = p.theta, p.gamma_s, p.gamma_r, p.xi
    w1 = beta**2 * math.sqrt(p.sigma)
    M = np.array([[1.0, -d1], [-d1, 1.0 / th + 1.0]])
    K = np.diag([p.sigma * beta**4, 1.0 / (th * gs**2)])
    C = np.diag([2.0 * xi * w1, 2.0 * xi / (th * gs)])
    H = K - g * g * M + 1j * g * C
    U = np.linalg.solve(H, np.array([0.0, 1.0])) * complex(2.0 * xi * g, -1.0 / gs)
    return 20.0 * math.log10(abs(U[1]) / (th * gs))


@pytest.mark.parametrize("gamma_r", [0.3, 3.9, 5.8])
def test_linear_points_have_no_impact_effect_and_the_closed_form(gamma_r: float) -> None:
    r = simulate_point(cell(gamma_r=gamma_r, g1=0.1, g2=0.1))
    assert r.outcome == "linear"
    assert r.impact_effect_db == 0.0  # exactly: Γ is the closed form itself
    assert r.transmittance_linear_db == r.transmittance_db
    ref = paper_transmissibility_db(gamma_r, 1.0, 0.05)
    assert r.transmittance_linear_db == pytest.approx(ref, abs=1e-9)


@pytest.mark.parametrize("gamma_r", [0.4, 2.0, 4.0])
def test_full_coupling_reference_against_a_hand_assembly(gamma_r: float) -> None:
    p = cell(gamma_r=gamma_r, coupling="full", modes=1, g1=50.0, g2=50.0)
    r = simulate_point(p)
    assert r.outcome == "linear" and r.impact_effect_db == 0.0
    # the full coupling is not the paper's transmissibility: the beam loads the mass
    assert abs(r.transmittance_linear_db - paper_transmissibility_db(gamma_r, 1.0, 0.05)) > 0.01
    assert r.transmittance_linear_db == pytest.approx(full_one_mode_db(p), abs=1e-9)


@pytest.mark.parametrize(
    ("gamma_r", "coupling"), [(0.85, "paper"), (1.0, "paper"), (2.35, "paper"), (1.2, "full")]
)
def test_impacting_points_reference_equals_the_cell_without_stops(
    gamma_r: float, coupling: str
) -> None:
    r = simulate_point(cell(gamma_r=gamma_r, coupling=coupling, g1=0.1, g2=0.1))
    assert r.outcome in ("periodic", "irregular") and r.impacts_per_period != (0.0, 0.0)
    free = simulate_point(cell(gamma_r=gamma_r, coupling=coupling, g1=1e6, g2=1e6))
    assert free.outcome == "linear"
    assert r.transmittance_linear_db == pytest.approx(free.transmittance_db, abs=1e-9)
    assert r.impact_effect_db == pytest.approx(r.transmittance_db - free.transmittance_db, abs=1e-9)
    assert abs(r.impact_effect_db) > 0.1  # the stops change this point: a real effect
    assert linear_reference(cell(gamma_r=gamma_r, coupling=coupling)) == pytest.approx(
        free.transmittance_db, abs=1e-9
    )


def test_failed_point_keeps_the_reference_and_has_no_effect() -> None:
    p = cell(gamma_r=0.85, theta=500.0)
    r = simulate_point(p)
    assert r.outcome == "failed" and r.transmittance_db is None and r.impact_effect_db is None
    # the closed form of the cell is still a fact about it (the impacts diverged, not the cell)
    assert r.transmittance_linear_db == pytest.approx(
        paper_transmissibility_db(0.85, 1.0, 0.05), abs=1e-9
    )
    text = json.dumps(r.as_dict(), allow_nan=False)  # never NaN written as a number
    assert '"impact_effect_db": null' in text


def test_refused_point_of_a_valid_cell_keeps_the_reference() -> None:
    pt = dict(BASE, gamma_r=1.0, sigma=100.0, g1=0.1, g2=0.1)
    (rec,) = simulate_chunk([pt], {"method": "euler", "steps_per_period": 8})
    assert rec["failed"] and "unstable" in rec["reason"]
    assert rec["impact_effect_db"] is None
    assert rec["transmittance_linear_db"] == pytest.approx(
        paper_transmissibility_db(1.0, 1.0, 0.05), abs=1e-9
    )
    (bad,) = simulate_chunk([dict(pt, theta=-1.0)])  # no cell at all: nothing to refer to
    assert bad["failed"] and bad["transmittance_linear_db"] is None


@pytest.mark.parametrize("method", ["event", "exponential"])
def test_undamped_resonance_has_no_reference(method: str) -> None:
    s = SolverSettings(method=method, max_periods=200)
    r = simulate_point(cell(gamma_r=1.0, xi=0.0, g1=1e6, g2=1e6), s)
    assert r.outcome == "failed" and "undamped resonance" in r.reason
    assert r.transmittance_linear_db is None and r.impact_effect_db is None
    assert linear_reference(cell(gamma_r=1.0, xi=0.0)) is None
