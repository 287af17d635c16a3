"""Observable formulas (MODEL.md §6) on signals with known answers."""

import numpy as np
import pytest

from worker.observables import theta_eff_harmonic, theta_eff_instantaneous, transmittance_db


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
