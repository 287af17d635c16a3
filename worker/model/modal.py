"""Clamped–free modal data (docs/model.md §2): the roots β_i, tip values, means and shapes.

Closed forms only, no quadrature; exact for every supported mode (the shapes are evaluated
without the cancellation that ruins the textbook form once βx ≳ 35).
"""

from __future__ import annotations

import math
import numbers
from functools import cache

import numpy as np
from numpy.typing import NDArray

__all__ = ["betas", "mode_means", "mode_shape", "tip_values"]


def _sech(beta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return ``1 / cosh(beta)`` for ``beta >= 0`` without overflow.

    ``cosh`` overflows past ``beta ≈ 710``; written with ``exp(-beta)`` the value simply
    underflows to zero, which is the correct limit.
    """
    e = np.exp(-beta)
    return 2.0 * e / (1.0 + e * e)


def betas(n: int) -> NDArray[np.float64]:
    """Return the first ``n`` clamped–free eigenvalues ``β_i`` (roots of ``cos β cosh β = -1``).

    Parameters
    ----------
    n : int
        Number of roots, ``n >= 1``.

    Returns
    -------
    numpy.ndarray
        Shape ``(n,)``, increasing: 1.8751, 4.6941, 7.8548, 10.9955, 14.1372, ...

    Raises
    ------
    ValueError
        If ``n`` is not an integer ``>= 1``.

    Notes
    -----
    The equation is solved in the equivalent form ``cos β + sech β = 0``. The product form
    ``cos β cosh β + 1`` is useless beyond the first few roots: ``cosh β`` grows like ``e^β``
    so the residual is dominated by rounding in ``cos β``. In the ``sech`` form the function
    has slope ``≈ ∓1`` near each root, and Newton's method started at ``(i - 1/2)π`` (the
    asymptotic root) converges quadratically to the i-th root for every ``i``.
    """
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    return _betas_array(int(n)).copy()


@cache
def _betas_array(n: int) -> NDArray[np.float64]:
    # the roots are universal: solved once per process, not ~0.1 ms at every point
    beta = (np.arange(1, n + 1, dtype=np.float64) - 0.5) * np.pi
    for _ in range(50):
        sech = _sech(beta)
        value = np.cos(beta) + sech
        # d/dβ sech β = -sech β · tanh β
        slope = -np.sin(beta) - sech * np.tanh(beta)
        step = value / slope
        beta = beta - step
        if np.all(np.abs(step) <= 4.0 * np.finfo(np.float64).eps * beta):
            break
    beta.setflags(write=False)
    return beta


@cache
def _betas_tuple(n: int) -> tuple[float, ...]:
    return tuple(float(b) for b in _betas_array(n))


def _sigma_i(b: float) -> float:
    # (sinh β - sin β)/(cosh β + cos β), divided through by cosh β so large β stays finite.
    ch = math.cosh(b)
    return (math.tanh(b) - math.sin(b) / ch) / (1.0 + math.cos(b) / ch)


def _one_minus_sigma_i(b: float) -> float:
    # 1 - σ_i without cancellation: (e^-β + cos β + sin β)/(cosh β + cos β).
    return (math.exp(-b) + math.cos(b) + math.sin(b)) / (math.cosh(b) + math.cos(b))


def tip_values(n: int) -> np.ndarray:
    """φ_i(1) = 2(-1)^(i+1)."""
    return np.array([2.0 * (-1.0) ** i for i in range(n)])


def mode_means(n: int) -> np.ndarray:
    """d_i = ∫₀¹ φ_i dx = 2σ_i/β_i."""
    return np.array([2.0 * _sigma_i(b) / b for b in _betas_tuple(n)])


def mode_shape(i: int, x: np.ndarray | float, derivative: int = 0) -> np.ndarray:
    """Cancellation-free φ_i(x) (``derivative`` 0) or φ_i''(x) (``derivative`` 2).

    φ = (cosh βx - σ sinh βx) - cos βx + σ sin βx. The first bracket equals
    ½(1-σ)e^{βx} + ½(1+σ)e^{-βx}; with 1-σ computed without cancellation it is exact for
    every mode, where the textbook form loses all digits once βx ≳ 35.
    """
    if isinstance(i, bool) or not isinstance(i, numbers.Integral) or i < 1:
        raise ValueError(f"i must be an integer >= 1, got {i!r}")
    if derivative not in (0, 2):
        raise ValueError(f"derivative must be 0 or 2, got {derivative}")
    b = _betas_tuple(i)[i - 1]
    s = _sigma_i(b)
    oms = _one_minus_sigma_i(b)
    x = np.asarray(x, dtype=float)
    hyper = 0.5 * oms * np.exp(b * x) + 0.5 * (1.0 + s) * np.exp(-b * x)
    if derivative == 0:
        return hyper - np.cos(b * x) + s * np.sin(b * x)
    return b * b * (hyper + np.cos(b * x) - s * np.sin(b * x))
