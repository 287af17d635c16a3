"""Observables from the kernel's measurements (MODEL.md §6)."""

from __future__ import annotations

import math

import numpy as np


def transmittance_db(amplitude: float, base_scale: float) -> float:
    """Γ = 20 log10(A_s / θγ_s) (Eq. 32); ``base_scale`` is θγ_s."""
    return 20.0 * math.log10(amplitude / base_scale)


def theta_eff_harmonic(S: complex, Sb: complex, kappa: float, theta: float) -> float | None:
    """θ_eff = (κ - θ Re(Ŝ_b/Ŝ))/(1 + θ) from first harmonics at γ_r; None if Ŝ = 0."""
    if abs(S) == 0.0:
        return None
    return float((kappa - theta * (Sb / S).real) / (1.0 + theta))


def theta_eff_instantaneous(
    sdot: np.ndarray, sbdot: np.ndarray, kappa: float, theta: float
) -> np.ndarray:
    """Eq. 36's instantaneous ratio; NaN where |ṡ| < 10⁻³ max|ṡ| (singular there)."""
    thr = 1e-3 * np.max(np.abs(sdot)) if len(sdot) else 0.0
    ok = np.abs(sdot) >= thr
    out = np.full(sdot.shape, np.nan)
    out[ok] = (kappa - theta * sbdot[ok] / sdot[ok]) / (1.0 + theta)
    return out
