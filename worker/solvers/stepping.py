"""Helpers the two time-stepping kernels (``euler``, ``exponential``) share, and their run.

Each step ends with :func:`step_end`: the range of ``s`` (refined between step ends by the
cubic Hermite interpolant where ``ṡ`` changes sign), contact episodes, the history sample.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from worker.solvers import measure as ms


@njit(cache=True, nogil=True)
def step_end(rows, k, kst, hist, xh, s0, v0, s1, v1, dt, l1, l2, phase, tau, x, nx, W, d, N, n,
             g1, g2):  # fmt: skip
    """Measure one finished step [s0, v0] → [s1, v1] of length dt."""
    lo = s1
    hi = s1
    if v0 * v1 <= 0.0:
        lo, _, hi, _ = ms.cubic_minmax(s0, v0, s1, v1, dt)
    ms.add_extrema(rows, k, lo, hi)
    if l1 > 0.0 or l2 > 0.0:
        ms.add_impulses(rows, kst, k, l1, l2, phase)
        rows[k, ms.M_CONTACT] += 1.0
    elif kst[ms.K_CONTACT] != 0.0:
        ms.release_if_open(kst, ms.dot(W, x, N), g1, g2)
    rows[k, ms.M_STEPS] += 1.0
    if hist.shape[0] > 0:
        ms.record(hist, xh, kst, tau, s1, ms.dot(W, x, N), ms.dot(d, x, n), v1,
                  ms.dot(d, x[N:], n), l1, l2, 0.0, x, nx)  # fmt: skip


@njit(cache=True, nogil=True)
def harmonics(rows, k, psi, psib, P, x, cf, sf, rot_c, rot_s, nx):
    """Add e^{-iγτ₀}·∫ [s; s_b] e^{-iγt} dt over one exact step from [x; cf; sf] (impulse P at
    its start); (rot_c, rot_s) = (cos, -sin) of the step's phase γτ₀."""
    for r in range(2):
        zr = psib[r].real * P
        zi = psib[r].imag * P
        for j in range(nx):
            zr += psi[r, j].real * x[j]
            zi += psi[r, j].imag * x[j]
        zr += psi[r, nx].real * cf + psi[r, nx + 1].real * sf
        zi += psi[r, nx].imag * cf + psi[r, nx + 1].imag * sf
        rows[k, ms.M_S_RE + 2 * r] += zr * rot_c - zi * rot_s
        rows[k, ms.M_S_IM + 2 * r] += zr * rot_s + zi * rot_c


@njit(cache=True, nogil=True)
def portrait(rows, k, gl, glb, P, x, cf, sf, dt, nx):
    """Add ∫ ṡ² and ∫ ṡ_b ṡ over one exact step by 4-point Gauss–Legendre: ``gl[j]`` are the
    rows giving (ṡ, ṡ_b) at node j from [x; cf; sf], ``glb[j]`` their impulse columns."""
    vv = 0.0
    vb = 0.0
    for j in range(4):
        v = glb[j, 0] * P + gl[j, 0, nx] * cf + gl[j, 0, nx + 1] * sf
        b = glb[j, 1] * P + gl[j, 1, nx] * cf + gl[j, 1, nx + 1] * sf
        for i in range(nx):
            v += gl[j, 0, i] * x[i]
            b += gl[j, 1, i] * x[i]
        wj = ms.GL_WEIGHTS[j]
        vv += wj * v * v
        vb += wj * b * v
    rows[k, ms.M_VV] += dt * vv
    rows[k, ms.M_VB] += dt * vb


def gauss_rows(P_of_t, dt: float, N: int, d: np.ndarray) -> np.ndarray:
    """(4, 2, nz) rows of (ṡ, ṡ_b) at the Gauss nodes of a step of ``dt``; ``P_of_t(t)`` is the
    exact propagator of the augmented state over t."""
    n = N - 1
    out = []
    for t in ms.GL_NODES * dt:
        P = P_of_t(t)
        out.append([P[N + n, :], d @ P[N : N + n, :]])
    return np.ascontiguousarray(np.array(out))
