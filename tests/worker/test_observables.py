"""Observable formulas (docs/model.md) on signals with known answers."""

import numpy as np
import pytest

from worker.observables import (
    theta_eff_harmonic,
    theta_eff_instantaneous,
    theta_eff_slope,
    transmittance_db,
)


def test_transmittance_is_amplitude_over_base_in_db():
    assert transmittance_db(0.3, 0.3) == pytest.approx(0.0)
    assert transmittance_db(0.03, 0.3) == pytest.approx(-20.0)


def test_harmonic_effective_mass_for_in_phase_and_out_of_phase_beams():
    # ṡ_b in phase with ṡ lowers θ_eff; out of phase raises it (Eq. 36 with κ).
    assert theta_eff_harmonic(1 + 0j, 0.5 + 0j, 1.0, 0.3) == pytest.approx((1 - 0.15) / 1.3)
    assert theta_eff_harmonic(1j, -2j, 1.3, 0.3) == pytest.approx((1.3 + 0.6) / 1.3)
    assert theta_eff_harmonic(0j, 1 + 0j, 1.0, 0.3) is None


def test_instantaneous_ratio_skips_the_singular_samples():
    t = np.linspace(0, 2 * np.pi, 401)
    sdot = np.cos(t)
    sbdot = -2.0 * np.cos(t)  # constant ratio -2 where defined
    inst = theta_eff_instantaneous(sdot, sbdot, 1.0, 0.3)
    ok = np.isfinite(inst)
    assert np.all(np.abs(sdot[~ok]) < 1e-3) and ok.sum() > 390
    np.testing.assert_allclose(inst[ok], (1 + 0.6) / 1.3)


def test_phase_portrait_slope_equals_the_harmonic_ratio_for_harmonic_motion():
    # ṡ = Re(iγ S e^{iγt}), ṡ_b = Re(iγ Sb e^{iγt}): ⟨ṡ_b ṡ⟩/⟨ṡ²⟩ = Re(Sb/S)
    t = np.linspace(0, 2 * np.pi, 100_001)[:-1]
    S, Sb, g = 0.7 - 0.2j, -0.4 + 0.9j, 1.0
    sd = np.real(1j * g * S * np.exp(1j * g * t))
    sbd = np.real(1j * g * Sb * np.exp(1j * g * t))
    slope = theta_eff_slope(np.mean(sd * sd), np.mean(sbd * sd), 1.0, 0.3)
    assert slope == pytest.approx(theta_eff_harmonic(S, Sb, 1.0, 0.3), abs=1e-12)


def test_phase_portrait_slope_is_bounded_where_the_plain_average_is_not():
    # ṡ through zero with ṡ_b not: Eq. 36's average over samples depends on where the samples
    # fall next to the zeros (by O(1), however fine the sampling); the slope does not
    means, slopes = [], []
    for offset in (0.02, 0.5):
        t = (np.arange(100_000) + offset) / 100_000 * 2 * np.pi
        sd = np.cos(t)
        sbd = np.cos(t) + 0.3 * np.sin(t)
        means.append(np.mean(sbd / sd))
        slopes.append(theta_eff_slope(np.mean(sd * sd), np.mean(sbd * sd), 1.0, 0.3))
    assert abs(means[1] - means[0]) > 1.0
    assert slopes[0] == pytest.approx(slopes[1], abs=1e-9)
    assert slopes[0] == pytest.approx((1.0 - 0.3) / 1.3, abs=1e-9)
    assert theta_eff_slope(0.0, 1.0, 1.0, 0.3) is None
