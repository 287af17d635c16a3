"""worker.physical: SI inputs → the model's non-dimensional parameters (docs/model.md §8)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from worker.checks import check_field
from worker.model import betas as cantilever_betas
from worker.physical import BASE_AMPLITUDE_M, TABLE1_FREQUENCIES_HZ, PhysicalCell

# Positive, finite, physically plausible magnitudes for property tests.
_pos = st.floats(min_value=1e-4, max_value=1e4, allow_nan=False, allow_infinity=False)


def _cell(**overrides: Any) -> PhysicalCell:
    """A valid generic cell (not Table 1) with selected fields overridden."""
    fields: dict[str, Any] = {
        "length_m": 0.2,
        "width_m": 0.02,
        "thickness_m": 0.003,
        "density_kg_m3": 1000.0,
        "youngs_modulus_pa": 1.0e9,
        "outer_mass_kg": 0.05,
        "spring_n_m": 500.0,
        "gap_m": 2.0e-3,
        "damping_ratio": 0.02,
        "base_amplitude_m": 5.0e-4,
    }
    fields.update(overrides)
    return PhysicalCell(**fields)


@pytest.fixture
def table1() -> PhysicalCell:
    return PhysicalCell.table1(damping_ratio=0.01, base_amplitude_m=1.0e-3)


# --------------------------------------------------------------------------------------
# Table 1 numbers (docs/model.md §8)


def test_table1_inputs(table1: PhysicalCell) -> None:
    assert table1.length_m == 0.15
    assert table1.width_m == 0.01
    assert table1.thickness_m == 0.0025
    assert table1.density_kg_m3 == 1250.0
    assert table1.youngs_modulus_pa == 4.583e7
    assert table1.spring_n_m == 350.0
    assert table1.gaps_m == (1.0e-3, 1.0e-3)
    assert table1.damping_ratio == 0.01
    assert table1.base_amplitude_m == 1.0e-3
    assert table1.base_acceleration_m_s2 is None


def test_table1_derived_quantities(table1: PhysicalCell) -> None:
    ei = table1.EI  # a local name: ruff's SIM300 mistakes the upper-case EI for a constant
    assert ei == pytest.approx(5.9674e-4, rel=1e-4)
    assert table1.rho_A_L == pytest.approx(4.6875e-3, rel=1e-9)  # exact in the inputs
    assert table1.outer_mass_kg == pytest.approx(16.67e-3, rel=1e-12)
    assert table1.omega_m == pytest.approx(144.90, abs=0.005)
    assert table1.f_m_hz == pytest.approx(23.06, abs=0.005)
    assert table1.theta == pytest.approx(0.28119, abs=5e-6)
    assert table1.sigma == pytest.approx(1.7966e-3, abs=5e-8)


def test_table1_beam_modes_to_printed_digits(table1: PhysicalCell) -> None:
    modes = table1.beam_mode_frequencies_hz(5)
    assert modes.shape == (5,)
    # Each printed value is the rounding of ours to the digits shown.
    assert round(float(modes[0]), 3) == 3.437
    assert round(float(modes[1]), 2) == 21.54
    assert round(float(modes[2]), 2) == 60.31
    assert round(float(modes[3]), 1) == 118.2
    assert round(float(modes[4]), 1) == 195.4


def test_table1_modes_consistent_with_sigma(table1: PhysicalCell) -> None:
    # docs/model.md §2: ω̃_i = β_i² √σ in units of ω_b = ω_m.
    betas = cantilever_betas(5)
    expected = betas**2 * math.sqrt(table1.sigma) * table1.f_m_hz
    np.testing.assert_allclose(table1.beam_mode_frequencies_hz(5), expected, rtol=1e-12)


def test_table1_requires_excitation_and_damping() -> None:
    with pytest.raises(ValueError, match="base_amplitude_m"):
        PhysicalCell.table1(damping_ratio=0.0)
    with pytest.raises(TypeError):
        PhysicalCell.table1(base_amplitude_m=1e-3)  # type: ignore[call-arg]
    with pytest.raises(TypeError):
        PhysicalCell.table1(0.0, 1e-3)  # type: ignore[misc]


def test_table1_with_acceleration() -> None:
    cell = PhysicalCell.table1(damping_ratio=0.0, base_acceleration_m_s2=2.0)
    assert cell.base_amplitude_m is None
    assert cell.base_acceleration_m_s2 == 2.0
    assert cell.theta == pytest.approx(0.28119, abs=5e-6)


def test_table1_frequency_plan() -> None:
    expected = (
        [12.0, 14.0, 16.0, 18.0, 20.0, 22.0]
        + [23.0, 24.0, 25.0, 26.0, 27.0, 28.0, 29.0, 30.0]
        + [32.0, 34.0, 36.0, 38.0, 40.0, 42.0]
    )
    assert isinstance(TABLE1_FREQUENCIES_HZ, tuple)
    assert len(TABLE1_FREQUENCIES_HZ) == 20
    assert list(TABLE1_FREQUENCIES_HZ) == expected
    assert all(type(f) is float for f in TABLE1_FREQUENCIES_HZ)
    assert all(a < b for a, b in itertools.pairwise(TABLE1_FREQUENCIES_HZ))


def test_table1_to_model(table1: PhysicalCell) -> None:
    params = table1.to_model(23.0)
    assert set(params) == {"theta", "sigma", "gamma_s", "gamma_r", "xi", "g1", "g2"}
    assert params["gamma_s"] == 1.0
    assert params["theta"] == table1.theta
    assert params["sigma"] == table1.sigma
    assert params["xi"] == 0.01
    assert params["gamma_r"] == pytest.approx(2 * math.pi * 23.0 / 144.8993, rel=1e-6)
    # g = U_g = 1 mm, so g̃ = g θ / U_g = θ.
    assert params["g1"] == pytest.approx(0.2811938, rel=1e-6)
    assert params["g2"] == params["g1"]


# --------------------------------------------------------------------------------------
# Clamped–free eigenvalues


def test_betas_known_values() -> None:
    np.testing.assert_allclose(
        cantilever_betas(5),
        [1.875104068711961, 4.694091132974175, 7.854757438237613, 10.99554073487547,
         14.13716839104647],
        rtol=1e-13,
    )  # fmt: skip


@pytest.mark.parametrize("n", [1, 2, 30, 400])
def test_betas_solve_the_characteristic_equation(n: int) -> None:
    betas = cantilever_betas(n)
    assert betas.shape == (n,)
    assert np.all(np.isfinite(betas))
    assert np.all(np.diff(betas) > 0)
    # Residual of cos β + sech β = 0; sech written with exp(-β) so large β cannot overflow.
    sech = 2 * np.exp(-betas) / (1 + np.exp(-2 * betas))
    residual = np.cos(betas) + sech
    assert np.all(np.abs(residual) < 1e-13 * np.maximum(1.0, betas))
    # Each root is the i-th one: it lies near its asymptote (i - 1/2)π, within 0.31 rad
    # (the worst case, i = 1: 1.8751 - π/2 ≈ 0.3043).
    asymptote = (np.arange(1, n + 1) - 0.5) * np.pi
    assert np.all(np.abs(betas - asymptote) < 0.31)
    if n >= 30:
        assert betas[29] == pytest.approx(29.5 * np.pi, rel=1e-15)


@pytest.mark.parametrize("n", [0, -1, 2.0, True, "3"])
def test_betas_reject_bad_n(n: Any) -> None:
    with pytest.raises(ValueError, match="n must be an integer >= 1"):
        cantilever_betas(n)


def test_mode_frequencies_reject_bad_n(table1: PhysicalCell) -> None:
    with pytest.raises(ValueError, match="n must be an integer >= 1, got 0"):
        table1.beam_mode_frequencies_hz(0)


# --------------------------------------------------------------------------------------
# Derived quantities, generic cell


def test_section_properties() -> None:
    cell = _cell(width_m=0.02, thickness_m=0.003)
    assert cell.area_m2 == pytest.approx(6.0e-5, rel=1e-12)
    assert cell.second_moment_m4 == pytest.approx(0.02 * 0.003**3 / 12, rel=1e-12)
    ei = cell.EI
    assert ei == pytest.approx(1.0e9 * 4.5e-11, rel=1e-12)
    assert cell.rho_A_L == pytest.approx(1000.0 * 6.0e-5 * 0.2, rel=1e-12)
    assert cell.omega_m == pytest.approx(100.0, rel=1e-12)  # √(500 / 0.05)
    assert cell.f_m_hz == pytest.approx(100.0 / (2 * math.pi), rel=1e-12)
    assert cell.theta == pytest.approx(0.012 / 0.05, rel=1e-12)
    assert cell.sigma == pytest.approx(0.045 / (0.06 * 0.2**4 * 100.0**2), rel=1e-12)


def test_from_added_mass() -> None:
    cell = PhysicalCell.from_added_mass(
        body_mass_kg=0.03,
        added_mass_kg=0.02,
        length_m=0.2,
        width_m=0.02,
        thickness_m=0.003,
        density_kg_m3=1000.0,
        youngs_modulus_pa=1.0e9,
        spring_n_m=500.0,
        gap_m=2.0e-3,
        base_amplitude_m=5.0e-4,
    )
    assert cell.outer_mass_kg == pytest.approx(0.05, rel=1e-15)
    assert cell.omega_m == pytest.approx(100.0, rel=1e-12)
    assert cell.damping_ratio == 0.0  # the documented default


def test_from_added_mass_errors() -> None:
    common: dict[str, Any] = {
        "length_m": 0.2,
        "width_m": 0.02,
        "thickness_m": 0.003,
        "density_kg_m3": 1000.0,
        "youngs_modulus_pa": 1.0e9,
        "spring_n_m": 500.0,
        "gap_m": 2.0e-3,
        "base_amplitude_m": 5.0e-4,
    }
    with pytest.raises(ValueError, match=r"added_mass_kg must be >= 0, got -0\.001"):
        PhysicalCell.from_added_mass(body_mass_kg=0.03, added_mass_kg=-0.001, **common)
    with pytest.raises(ValueError, match=r"body_mass_kg must be > 0, got 0\.0"):
        PhysicalCell.from_added_mass(body_mass_kg=0.0, added_mass_kg=0.01, **common)
    with pytest.raises(ValueError, match="outer_mass_kg must not be given"):
        PhysicalCell.from_added_mass(
            body_mass_kg=0.03, added_mass_kg=0.01, outer_mass_kg=0.04, **common
        )
    # Zero added mass is a bare body.
    bare = PhysicalCell.from_added_mass(body_mass_kg=0.03, added_mass_kg=0.0, **common)
    assert bare.outer_mass_kg == 0.03


def test_numbers_are_normalised_to_float() -> None:
    cell = _cell(length_m=np.float64(0.2), spring_n_m=500, gap_m=np.float32(0.002))
    assert type(cell.length_m) is float
    assert type(cell.spring_n_m) is float
    assert type(cell.gap_m) is float
    assert cell == _cell(gap_m=float(np.float32(0.002)))


def test_cell_is_frozen_and_keyword_only() -> None:
    cell = _cell()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cell.length_m = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        PhysicalCell(0.2, 0.02, 0.003, 1000.0, 1e9, 0.05, 500.0, 2e-3)  # type: ignore[misc]


# --------------------------------------------------------------------------------------
# Frequency conversion


def test_hz_to_gamma_r_by_hand() -> None:
    cell = _cell()  # ω_m = 100 rad/s
    assert cell.hz_to_gamma_r(50.0 / math.pi) == pytest.approx(1.0, rel=1e-14)
    assert cell.gamma_r_to_hz(2.0) == pytest.approx(100.0 / math.pi, rel=1e-14)
    # f_m maps to γ_r = 1 (resonance of the outer mass with γ_s = 1).
    assert cell.hz_to_gamma_r(cell.f_m_hz) == pytest.approx(1.0, rel=1e-14)


@given(frequency_hz=st.floats(min_value=1e-3, max_value=1e5))
def test_frequency_round_trip(frequency_hz: float) -> None:
    cell = PhysicalCell.table1(damping_ratio=0.0, base_amplitude_m=1e-3)
    gamma_r = cell.hz_to_gamma_r(frequency_hz)
    assert cell.gamma_r_to_hz(gamma_r) == pytest.approx(frequency_hz, rel=1e-14)
    assert cell.to_model(frequency_hz)["gamma_r"] == gamma_r


@given(gamma_r=st.floats(min_value=1e-4, max_value=1e3))
def test_gamma_round_trip(gamma_r: float) -> None:
    cell = _cell()
    assert cell.hz_to_gamma_r(cell.gamma_r_to_hz(gamma_r)) == pytest.approx(gamma_r, rel=1e-14)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, -math.inf])
def test_frequency_conversions_reject_bad_values(bad: float) -> None:
    cell = _cell()
    with pytest.raises(ValueError, match="frequency_hz"):
        cell.hz_to_gamma_r(bad)
    with pytest.raises(ValueError, match="gamma_r"):
        cell.gamma_r_to_hz(bad)
    with pytest.raises(ValueError, match="frequency_hz"):
        cell.to_model(bad)
    with pytest.raises(ValueError, match="frequency_hz"):
        cell.base_amplitude_at(bad)


# --------------------------------------------------------------------------------------
# Gap scaling and base excitation


def test_gap_scaling_by_hand() -> None:
    # θ = 0.012 / 0.05 = 0.24; g = 2 mm, U_g = 0.5 mm → B = U_g/θ = 2.0833 mm,
    # g̃ = g θ / U_g = 2 · 0.24 / 0.5 = 0.96.
    cell = _cell()
    assert cell.length_scale_m(10.0) == pytest.approx(5.0e-4 / 0.24, rel=1e-12)
    params = cell.to_model(10.0)
    assert params["g1"] == pytest.approx(0.96, rel=1e-12)
    assert params["g2"] == pytest.approx(0.96, rel=1e-12)
    # With a displacement amplitude the gaps do not depend on frequency.
    assert cell.to_model(1000.0)["g1"] == pytest.approx(0.96, rel=1e-12)


def test_acceleration_amplitude_by_hand() -> None:
    # a = 4π² m/s² at f = 1 Hz (Ω = 2π) is U_g = 1 m; at 2 Hz it is 0.25 m.
    cell = _cell(base_amplitude_m=None, base_acceleration_m_s2=4 * math.pi**2)
    assert cell.base_amplitude_at(1.0) == pytest.approx(1.0, rel=1e-14)
    assert cell.base_amplitude_at(2.0) == pytest.approx(0.25, rel=1e-14)
    # At fixed acceleration U_g ∝ 1/Ω², so g̃ = gθ/U_g ∝ Ω²: doubling f quadruples g̃.
    ratio = cell.to_model(2.0)["g1"] / cell.to_model(1.0)["g1"]
    assert ratio == pytest.approx(4.0, rel=1e-12)


# Within the cell's ranges: U_g = a/Ω² stays in [1e-12, 100] m.
@given(frequency_hz=st.floats(min_value=1.0, max_value=500.0),
       accel=st.floats(min_value=1e-3, max_value=1e3))  # fmt: skip
def test_acceleration_input_equals_equivalent_amplitude(frequency_hz: float, accel: float) -> None:
    by_accel = _cell(base_amplitude_m=None, base_acceleration_m_s2=accel, gap1_m=1e-3)
    amplitude = accel / (2 * math.pi * frequency_hz) ** 2
    by_amp = _cell(base_amplitude_m=amplitude, gap1_m=1e-3)
    a = by_accel.to_model(frequency_hz)
    b = by_amp.to_model(frequency_hz)
    assert a.keys() == b.keys()
    for key in a:
        assert a[key] == pytest.approx(b[key], rel=1e-12), key


# Zero or a physical size: subnormal gaps only test floating-point underflow.
_gap = st.just(0.0) | st.floats(min_value=1e-9, max_value=1.0)


# Amplitudes and gaps, scaled, stay within the cell's ranges ([1e-12, 100] m, [0, 1e3] m).
@given(gap=_gap, amplitude=st.floats(min_value=1e-6, max_value=1.0),
       scale=st.floats(min_value=1e-2, max_value=1e2))  # fmt: skip
def test_gap_tilde_is_linear_in_gap_and_inverse_in_amplitude(
    gap: float, amplitude: float, scale: float
) -> None:
    cell = _cell(gap_m=gap, base_amplitude_m=amplitude)
    g = cell.to_model(20.0)["g1"]
    assert g == pytest.approx(gap * cell.theta / amplitude, rel=1e-12, abs=0.0)
    scaled = _cell(gap_m=gap * scale, base_amplitude_m=amplitude * scale)
    assert scaled.to_model(20.0)["g1"] == pytest.approx(g, rel=1e-12, abs=1e-300)


def test_asymmetric_gaps() -> None:
    cell = _cell(gap_m=2e-3, gap1_m=1e-3, gap2_m=3e-3)
    assert cell.gaps_m == (1e-3, 3e-3)
    params = cell.to_model(15.0)
    assert params["g1"] == pytest.approx(1e-3 * 0.24 / 5e-4, rel=1e-12)
    assert params["g2"] == pytest.approx(3e-3 * 0.24 / 5e-4, rel=1e-12)
    # One side given: the other falls back to gap_m.
    only1 = _cell(gap_m=2e-3, gap1_m=0.0)
    assert only1.gaps_m == (0.0, 2e-3)
    only2 = _cell(gap_m=2e-3, gap2_m=5e-3)
    assert only2.gaps_m == (2e-3, 5e-3)
    # Unset sides follow gap_m through dataclasses.replace.
    assert dataclasses.replace(only2, gap_m=4e-3).gaps_m == (4e-3, 5e-3)
    # Both sides given: gap_m is not needed; one side alone is not enough.
    assert _cell(gap_m=None, gap1_m=1e-3, gap2_m=3e-3).gaps_m == (1e-3, 3e-3)
    with pytest.raises(ValueError, match=r"^gap_m must be given, or both gap1_m and gap2_m"):
        _cell(gap_m=None, gap1_m=1e-3)


def test_zero_gap_is_allowed() -> None:
    params = _cell(gap_m=0.0).to_model(10.0)
    assert params["g1"] == 0.0
    assert params["g2"] == 0.0


def test_damping_passes_through() -> None:
    assert _cell(damping_ratio=0.0).to_model(5.0)["xi"] == 0.0
    assert _cell(damping_ratio=0.3).to_model(5.0)["xi"] == 0.3


# --------------------------------------------------------------------------------------
# Validation: every error path names the field, the value and what is allowed

_POSITIVE_FIELDS = [
    "length_m",
    "width_m",
    "thickness_m",
    "density_kg_m3",
    "youngs_modulus_pa",
    "outer_mass_kg",
    "spring_n_m",
    "base_amplitude_m",
]


@pytest.mark.parametrize("field", _POSITIVE_FIELDS)
@pytest.mark.parametrize("bad", [0.0, -0.1])
def test_positive_fields_reject_nonpositive(field: str, bad: float) -> None:
    with pytest.raises(ValueError, match=rf"^{field} must be > 0, got {bad!r}; allowed range \["):
        _cell(**{field: bad})


def test_positive_field_example_message() -> None:
    with pytest.raises(ValueError) as info:
        _cell(length_m=-0.1)
    assert str(info.value) == "length_m must be > 0, got -0.1; allowed range [1e-09, 1000]"


def test_base_acceleration_rejects_nonpositive() -> None:
    with pytest.raises(ValueError, match=r"^base_acceleration_m_s2 must be > 0, got -1\.0; "):
        _cell(base_amplitude_m=None, base_acceleration_m_s2=-1.0)
    with pytest.raises(ValueError, match=r"^base_acceleration_m_s2 must be > 0, got 0\.0; "):
        _cell(base_amplitude_m=None, base_acceleration_m_s2=0.0)


@pytest.mark.parametrize(
    "field",
    [*_POSITIVE_FIELDS, "damping_ratio", "gap_m", "gap1_m", "gap2_m"],
)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_fields_reject_nonfinite(field: str, bad: float) -> None:
    with pytest.raises(ValueError, match=rf"^{field} must be finite, got {bad!r}; allowed range"):
        _cell(**{field: bad})


@pytest.mark.parametrize("field", ["damping_ratio", "gap_m", "gap1_m", "gap2_m"])
def test_nonnegative_fields_reject_negative(field: str) -> None:
    text = rf"^{field} must be >= 0, got -0\.001; allowed range \[0, "
    with pytest.raises(ValueError, match=text):
        _cell(**{field: -0.001})


@pytest.mark.parametrize("bad", ["0.1", None, True, 1j, [0.1]])
def test_fields_reject_non_numbers(bad: Any) -> None:
    with pytest.raises(ValueError, match=r"^width_m must be a real number, got "):
        _cell(width_m=bad)


def test_base_excitation_exactly_one() -> None:
    with pytest.raises(ValueError, match="exactly one of base_amplitude_m and base_acceleration"):
        _cell(base_amplitude_m=None)
    with pytest.raises(
        ValueError, match=r"got base_amplitude_m=0\.0005, base_acceleration_m_s2=9\.81"
    ):
        _cell(base_acceleration_m_s2=9.81)


def test_per_frequency_amplitudes_follow_the_fields_rule() -> None:
    # A study's per-frequency amplitudes are checked by this rule and then set point by point
    # as base_amplitude_m: one rule, so a value the list accepts the cell accepts too.
    meta = {f.name: dict(f.metadata) for f in dataclasses.fields(PhysicalCell)}
    assert {k: v for k, v in meta["base_amplitude_m"].items() if k != "optional"} == (
        BASE_AMPLITUDE_M
    )
    for value in (1e-12, 1e-3, 100.0):
        assert _cell(base_amplitude_m=value).base_amplitude_m == check_field(
            "u", value, BASE_AMPLITUDE_M
        )
    for value in (0.0, 1e-13, 101.0):
        with pytest.raises(ValueError, match="^u must be"):
            check_field("u", value, BASE_AMPLITUDE_M)
        with pytest.raises(ValueError, match="^base_amplitude_m must be"):
            _cell(base_amplitude_m=value)


def test_length_scale_is_u_g_over_theta_per_amplitude() -> None:
    # B = U_g/(θγ_s) with γ_s = 1: amplitudes in metres are amplitude × B (docs/model.md §8).
    for u in (2.5e-4, 1e-3):
        cell = PhysicalCell.table1(damping_ratio=0.03, base_amplitude_m=u)
        theta = 1250.0 * 0.01 * 0.0025 * 0.15 / 0.01667
        assert cell.length_scale_m(23.0) == pytest.approx(u / theta, rel=1e-12)
        assert cell.to_model(23.0)["g1"] == pytest.approx(1e-3 / cell.length_scale_m(23.0))
