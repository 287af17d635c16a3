"""The paper's Sections 4.2 and 4.3 against our numbers (docs/paper-comparison.md).

Every value quoted as reproduced in the comparison is checked here against the paper's number,
at the cell of the shipped studies: θ = 1 (pinned by Figure 6's linear point), ξ = ξ_b = 0.015
(fitted to it), γ_s = 1, σ = 0.05, g̃ = 0.1, `paper` coupling, 5 modes. The values that are
not reproduced are checked too, so the document cannot silently go stale. The fast tests
simulate a few points; the slow ones run whole shipped studies.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from service.studies.runner import run_study
from service.studies.schema import load_study
from service.studies.shipped import shipped_studies
from worker.model import CellParams, assemble
from worker.model.references import linear_transmittance_db, steady_state
from worker.simulate import simulate_point
from worker.solvers.settings import PointResult, SolverSettings

#: Figure 6 (Section 4.3): γ_r → the paper's average θ_eff.
PAPER_FIG6 = {0.85: 0.5213, 2.35: 1.1072, 3.9: -1.9462, 4.15: -0.1826, 5.8: -0.1424}
#: The cell of paper-fig6-effective-mass.yaml and paper-fig5-theta1.yaml.
CELL = {"theta": 1.0, "sigma": 0.05, "gamma_s": 1.0, "xi": 0.015, "modes": 5, "coupling": "paper"}
GAPS = (0.1, 0.3, 0.5, 0.7, 1.0)


def point(gamma_r: float, gap: float = 0.1, **change: float) -> PointResult:
    """One point of the shipped cell, at the default solver settings."""
    params = CellParams(**{**CELL, **change}, gamma_r=gamma_r, g1=gap, g2=gap)
    return simulate_point(params, SolverSettings())


def linear_theta_eff(**change: float) -> float:
    """The closed-form (impact-free) θ_eff at γ_r 5.8, g̃ 0.1."""
    params = CellParams(**{**CELL, **change}, gamma_r=5.8, g1=0.1, g2=0.1)
    ss = steady_state(assemble(params))
    assert ss is not None
    return ss.theta_eff


@pytest.fixture(scope="module")
def fig6() -> dict[float, PointResult]:
    """The five Figure 6 points, taken from the shipped study itself."""
    study = load_study(shipped_studies()["paper-fig6-effective-mass"])
    pts = {round(p["gamma_r"], 10): p for p in study.iter_points()}
    out = {}
    for g in PAPER_FIG6:
        p = pts[g]  # the grid holds the paper's frequencies exactly
        assert {k: p[k] for k in CELL} == CELL and p["g1"] == p["g2"] == 0.1
        assert study.model.xi_b is None  # ξ_b = ξ
        out[g] = simulate_point(CellParams(**p), study.solver.settings())
    return out


# --------------------------------------------------------------------------- Figure 6


def test_the_linear_point_pins_theta_and_the_beam_damping() -> None:
    # γ_r 5.8 is impact-free; there θ_eff is a closed form. The paper's -0.1424 (four digits)
    # holds at θ = 1 and ξ_b within 0.0123 … 0.0162; 5 % off in θ is far outside 1 %.
    assert round(linear_theta_eff(), 4) == PAPER_FIG6[5.8]
    assert round(linear_theta_eff(xi=0.0120), 4) != PAPER_FIG6[5.8]
    assert round(linear_theta_eff(xi=0.0165), 4) != PAPER_FIG6[5.8]
    for theta in (0.95, 1.05):
        assert abs(linear_theta_eff(theta=theta) / PAPER_FIG6[5.8] - 1) > 0.1
    # The mass's own dashpot ξ does not enter ṡ_b/ṡ: only ξ_b is fitted.
    assert linear_theta_eff(xi=0.1, xi_b=0.015) == pytest.approx(linear_theta_eff(), abs=1e-12)


def test_theta_eff_at_0_85_and_5_8_within_1_percent(fig6: dict[float, PointResult]) -> None:
    for g in (0.85, 5.8):
        r = fig6[g]
        for value in (r.theta_eff, r.theta_eff_slope):
            assert value is not None
            assert value == pytest.approx(PAPER_FIG6[g], rel=0.01), (g, value)
    assert fig6[5.8].outcome == "linear"
    assert fig6[5.8].theta_eff == pytest.approx(PAPER_FIG6[5.8], abs=5e-5)  # all four digits
    assert fig6[0.85].outcome == "periodic" and fig6[0.85].impacts_per_period is not None
    assert sum(fig6[0.85].impacts_per_period) >= 2  # an impacting orbit, not the linear cell


def test_all_five_signs_of_theta_eff(fig6: dict[float, PointResult]) -> None:
    for g, paper in PAPER_FIG6.items():
        for value in (fig6[g].theta_eff, fig6[g].theta_eff_slope):
            assert value is not None and np.sign(value) == np.sign(paper), (g, value)
    # Panels ii: the slope of -θṡ_b against ṡ is positive at 0.85 and 2.35, negative at the
    # other three; at θ = 1 that is θ_eff above or below 1/(1 + θ) = 0.5.
    for g in PAPER_FIG6:
        slope = fig6[g].theta_eff_slope
        assert slope is not None and (slope > 0.5) == (g < 3)


def test_the_points_not_reproduced_stay_documented(fig6: dict[float, PointResult]) -> None:
    # docs/paper-comparison.md: 2.35 is close (the slope estimator within 5 %, the harmonic
    # one within 8 %); 3.9 and 4.15 are not reproduced (about 0.59× and 2.2× the paper's).
    r = fig6[2.35]
    assert r.theta_eff_slope == pytest.approx(PAPER_FIG6[2.35], rel=0.05)
    assert r.theta_eff == pytest.approx(PAPER_FIG6[2.35], rel=0.08)
    for g in (3.9, 4.15):
        value = fig6[g].theta_eff
        assert value is not None and abs(value / PAPER_FIG6[g] - 1) > 0.3, (g, value)


def test_below_theta_one_half_no_effective_mass_is_negative() -> None:
    # Why the θ 0.1-0.5 study never showed the paper's negative effective mass.
    for g in PAPER_FIG6:
        value = point(g, theta=0.5).theta_eff
        assert value is not None and value > 0.2, (g, value)


# --------------------------------------------------------------------------- Figure 5


def test_high_frequency_curves_coincide_with_the_impact_free_line() -> None:
    # Section 4.2: beyond the last impacts the gap no longer matters (Figure 5(b): γ_r 4,
    # g̃ 0.5 and 1 alike). At γ_r 5.9, g̃ 0.1 chaos beside the admissible impact-free response
    # dies out after ~415 periods, and may be claimed (with the may-be-transient note) before:
    # such claims wait for the transient guard (the shipped study's budget of 2,500 periods
    # puts its earliest claim later anyway)
    guard = SolverSettings(transient_guard=1000)
    for g_r, gaps in ((5.9, GAPS), (4.0, (0.5, 1.0))):
        lin = linear_transmittance_db(CellParams(**CELL, gamma_r=g_r, g1=1.0, g2=1.0))
        for gap in gaps:
            r = simulate_point(CellParams(**CELL, gamma_r=g_r, g1=gap, g2=gap), guard)
            assert r.outcome == "linear", (g_r, gap)
            assert r.transmittance_db == pytest.approx(lin, abs=1e-9)


def test_impacts_stop_at_a_lower_frequency_for_larger_gaps() -> None:
    # Last impacting γ_r of paper-fig5-theta1: 5.70, 5.38, 5.28, 5.16, 5.08 for g̃ 0.1 … 1.
    def impacting(g_r: float) -> list[bool]:
        return [point(g_r, gap).outcome != "linear" for gap in GAPS]

    assert impacting(5.5) == [True, False, False, False, False]
    assert impacting(5.3) == [True, True, False, False, False]


def test_small_gap_in_phase_large_gap_out_of_phase_at_2_5() -> None:
    # Figure 5(c): at γ_r 2.5 the tip (-s_b) moves with the mass for g̃ 0.1 and against it
    # for 0.7; at θ = 1, -Re(Ŝ_b/Ŝ) > 0 is θ_eff > 0.5.
    small, large = point(2.5, 0.1).theta_eff, point(2.5, 0.7).theta_eff
    assert small is not None and large is not None
    assert small > 0.5 + 0.3 and large < 0.5 - 0.3


def test_a_softer_beam_opens_a_second_pass_band_near_2_5() -> None:
    # paper-fig5-second-band: σ 0.02 puts the held-tip resonance at γ_r ≈ 2.5, inside the
    # paper's 2.2-3; with impacts Γ > 0 there, where the cell without stops attenuates.
    lin = linear_transmittance_db(CellParams(**{**CELL, "sigma": 0.02}, gamma_r=2.5, g1=1, g2=1))
    assert lin < -10
    for gap in (0.1, 0.3):
        r = point(2.5, gap, sigma=0.02)
        assert r.transmittance_db is not None and r.transmittance_db > 3.0, gap


# --------------------------------------------------------------------------- whole studies


def _run(name: str, root: Path) -> xr.Dataset:
    summary = run_study(load_study(shipped_studies()[name]), root, serial=True)
    assert summary.failed == 0
    return xr.load_dataset(summary.path).squeeze(drop=True)


def _last_impacting(ds: xr.Dataset) -> list[float]:
    x = ds.gamma_r.values
    return [float(x[np.flatnonzero(ds.outcome.sel(gap=g).values != 0).max()]) for g in GAPS]


def _first_quiet(ds: xr.Dataset) -> list[float]:
    """The first γ_r above the mass resonance (1.5) where a gap's response is impact-free."""
    x = ds.gamma_r.values
    out = []
    for g in GAPS:
        quiet = (ds.outcome.sel(gap=g).values == 0) & (x > 1.5)
        out.append(float(x[np.flatnonzero(quiet).min()]))
    return out


def _falling(values: Sequence[float] | np.ndarray) -> bool:
    """Strictly decreasing (over the gaps in increasing order)."""
    return bool(np.all(np.diff(np.asarray(values, dtype=float)) < 0))


def _pass_bands(x: np.ndarray, g: np.ndarray, lo: float) -> np.ndarray:
    """Frequencies above ``lo`` where Γ > 0."""
    return x[(x > lo) & (g > 0)]


@pytest.mark.slow
def test_fig6_study_reproduces_the_signs_and_two_values(tmp_path: Path) -> None:
    ds = _run("paper-fig6-effective-mass", tmp_path)
    for g, paper in PAPER_FIG6.items():
        value = float(ds.theta_eff.sel(gamma_r=g))
        assert np.sign(value) == np.sign(paper)
        if g in (0.85, 5.8):
            assert value == pytest.approx(paper, rel=0.01)
    # Negative effective mass over a band (γ_r ≈ 3.25 … 6), not at isolated points.
    neg = ds.gamma_r.values[ds.theta_eff.values < 0]
    assert neg.min() == pytest.approx(3.25, abs=0.06) and neg.max() == pytest.approx(6.0)


@pytest.mark.slow
def test_fig5_theta1_statements(tmp_path: Path) -> None:
    ds = _run("paper-fig5-theta1", tmp_path)
    x = ds.gamma_r.values
    last, first = _last_impacting(ds), _first_quiet(ds)
    assert _falling(last), last  # reproduced
    assert _falling(first), first
    above = x > max(last)
    curves = ds.transmittance_db.values[:, above]
    assert np.ptp(curves, axis=0).max() < 1e-9  # the curves coincide
    assert np.abs(curves - ds.transmittance_linear_db.values[:, above]).max() < 1e-9
    # Not reproduced with σ 0.05: no Γ > 0 band in 2.2-3, and the peak does not fall with the gap.
    band = (x >= 2.2) & (x <= 3.0)
    assert ds.transmittance_db.values[:, band].max() < 0
    peaks = ds.transmittance_db.max("gamma_r").values
    assert np.ptp(peaks) < 0.2 and peaks[-1] >= peaks[0]
    # The dip before the held-tip resonance (≈ 3.9) is deeper the smaller the gap: g̃ 0.1 by
    # more than 3 dB; g̃ 0.3's lowest point is an irregular one, whose value moves by tenths of
    # a dB with the round-off of the chaotic motion, so by more than 0.5 dB.
    dip = ds.transmittance_db.sel(gamma_r=slice(2.6, 3.85)).min("gamma_r").values
    assert dip[0] < dip[1] - 3 and dip[1] < dip[2:].min() - 0.5, dip


@pytest.mark.slow
def test_fig5_second_band_statements(tmp_path: Path) -> None:
    ds = _run("paper-fig5-second-band", tmp_path)
    x = ds.gamma_r.values
    last = _last_impacting(ds)
    assert _falling(last), last
    above = x > max(last)
    assert np.ptp(ds.transmittance_db.values[:, above], axis=0).max() < 1e-9
    peaks = ds.transmittance_db.max("gamma_r").values
    assert _falling(peaks), peaks  # the peak falls as the gap grows
    # A second Γ > 0 band inside the paper's 2.2-3 for g̃ ≤ 0.5, but narrower than 0.3.
    for gap in (0.1, 0.3, 0.5):
        band = _pass_bands(x, ds.transmittance_db.sel(gap=gap).values, 1.5)
        assert band.size and band.min() >= 2.2 and band.max() <= 3.0, (gap, band)
        assert band.max() - band.min() < 0.3
    # The anti-resonance before it is deeper for smaller gaps.
    dip = ds.transmittance_db.sel(gamma_r=slice(1.5, 2.45)).min("gamma_r").values
    assert _falling(-dip), dip
