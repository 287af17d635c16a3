"""Observables of a point (docs/model.md §6): transmittance and the effective-mass estimators.

The effective mass θ_eff is the first-harmonic ratio (Eq. 35 at the driving frequency: force
over acceleration at γ_r, the frequency-domain definition of a mass-in-mass cell's effective
mass). Beside it, ``theta_eff_slope`` is the phase-portrait ratio θ_ps: the least-squares slope
of the velocity phase portrait ``ṡ_b ≈ r ṡ``, ``r = ⟨ṡ_b ṡ⟩/⟨ṡ²⟩``, put in the same formula. It
weighs every harmonic by its share of ``⟨ṡ²⟩``, so it equals θ_eff only where the motion is
harmonic (linear points); at impacting points, where impacts put velocity into the harmonics,
it is not an effective mass at γ_r and may differ from θ_eff in sign (docs/model.md §6).

Why there is no time average of Eq. 36: the instantaneous ratio ``ṡ_b/ṡ`` is singular wherever
``ṡ`` crosses zero (twice a period, and at every impact in the paper coupling, where ``ṡ``
jumps through zero), so its plain average over time diverges and any finite value depends on
the sampling.
"""

from __future__ import annotations

import math

import numpy as np


def transmittance_db(amplitude: float, base_scale: float) -> float:
    """Γ = 20 log10(A_s / θγ_s) (Eq. 32); ``base_scale`` is θγ_s."""
    return 20.0 * math.log10(amplitude / base_scale)


def theta_eff_harmonic(S: complex, Sb: complex, kappa: float, theta: float) -> float | None:
    """The effective mass θ_eff = (κ - θ Re(Ŝ_b/Ŝ))/(1 + θ) from the first harmonics at γ_r
    (Eq. 35); None if Ŝ = 0."""
    if abs(S) == 0.0:
        return None
    return float((kappa - theta * (Sb / S).real) / (1.0 + theta))


def theta_eff_slope(vv: float, vb: float, kappa: float, theta: float) -> float | None:
    """The phase-portrait ratio θ_ps = (κ - θ⟨ṡ_b ṡ⟩/⟨ṡ²⟩)/(1 + θ), all harmonics weighted by
    their velocity power (θ_eff only for harmonic motion); None if ṡ ≡ 0."""
    if not vv > 0.0:
        return None
    return float((kappa - theta * vb / vv) / (1.0 + theta))


def theta_eff_instantaneous(
    sdot: np.ndarray, sbdot: np.ndarray, kappa: float, theta: float
) -> np.ndarray:
    """Eq. 36's instantaneous ratio, for time histories only; NaN where |ṡ| < 10⁻³ max|ṡ|."""
    thr = 1e-3 * np.max(np.abs(sdot)) if len(sdot) else 0.0
    ok = np.abs(sdot) >= thr
    out = np.full(sdot.shape, np.nan)
    out[ok] = (kappa - theta * sbdot[ok] / sdot[ok]) / (1.0 + theta)
    return out
