"""Helpers the two time-stepping kernels (``euler``, ``exponential``) share, and their run.

A period's measurements are accumulated in local variables by the helpers below (the range of
``s``, contact episodes, first harmonics, the phase-portrait integrals) and written to the
period's row once, by ``measure.close_row`` (why once: its docstring; measured here, 3× slower
steps with stores in the loop).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit

from worker.solvers import measure as ms
from worker.solvers.base import KernelRun


@njit(cache=True, nogil=True, inline="always")
def extrema(s0, v0, s1, v1, dt, smin, smax):
    """The period's range of s widened by one step [s0, v0] → [s1, v1] of length dt (refined
    by the cubic Hermite interpolant where ṡ changes sign)."""
    lo = s1
    hi = s1
    if v0 * v1 <= 0.0:
        lo, _, hi, _ = ms.cubic_minmax(s0, v0, s1, v1, dt)
    return min(smin, lo), max(smax, hi)


@njit(cache=True, nogil=True, inline="always")
def contact_step(l1, l2, phase, contact, imp1, imp2, peak, last, W, x, N, g1, g2):
    """Contact episodes after a step with impulses (l1, l2): one begins with an impulse at a
    stop not already in contact; it ends once the gap has opened by ``OPEN_FRAC`` of itself
    (so a scheme's chatter at a release is not counted as new impacts)."""
    if l1 > 0.0 or l2 > 0.0:
        if l1 > 0.0 and contact != 1:
            imp1 += 1.0
            last = phase
        if l2 > 0.0 and contact != 2:
            imp2 += 1.0
            last = phase
        peak = max(peak, l1, l2)
        contact = 1 if l1 > 0.0 else 2
    elif contact != 0:
        w = ms.dot(W, x, N)
        if (contact == 1 and g1 - w > ms.OPEN_FRAC * g1) or (
            contact == 2 and g2 + w > ms.OPEN_FRAC * g2
        ):
            contact = 0
    return contact, imp1, imp2, peak, last


@njit(cache=True, nogil=True, inline="always")
def tally_impulses(l1, l2, contact, wv, vm, vp, G, dt, ct1, ct2, vimp1, vimp2, en1, en2):
    """A step's impulses in the period's impact tallies (``measure.close_impacts``): a step
    whose impulse holds the tip on a stop is ``dt`` on it; an impulse that begins a contact
    episode (at a stop the tip is not on already: ``contact``, before :func:`contact_step`)
    adds the tip's approach velocity ``wv`` (towards stop 1 positive, Wᵀq at the step's
    start); and every impulse takes the energy ``½(v⁻² − v⁺²)/G`` from the tip's velocity
    ``vm`` just before it to ``vp`` just after (docs/model.md §6), booked at the stop whose
    impulse is the larger."""
    if l1 > 0.0:
        ct1 += dt
        if contact != 1:
            vimp1 += wv
    if l2 > 0.0:
        ct2 += dt
        if contact != 2:
            vimp2 -= wv
    # factored: where the tip rests on a stop v⁻ ≈ v⁺, and v⁻² − v⁺² would cancel
    de = 0.5 * (vm - vp) * (vm + vp) / G
    if l1 >= l2:
        en1 += de
    else:
        en2 += de
    return ct1, ct2, vimp1, vimp2, en1, en2


@njit(cache=True, nogil=True, inline="always")
def harmonics(psi, psib, P, x, cf, sf, rot_c, rot_s, nx):
    """e^{-iγτ₀}·∫ [s; s_b] e^{-iγt} dt over one exact step from [x; cf; sf] (impulse P at its
    start), as (s re, s im, s_b re, s_b im); (rot_c, rot_s) = (cos, -sin) of the phase γτ₀."""
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    out3 = 0.0
    for r in range(2):
        zr = psib[r].real * P
        zi = psib[r].imag * P
        for j in range(nx):
            zr += psi[r, j].real * x[j]
            zi += psi[r, j].imag * x[j]
        zr += psi[r, nx].real * cf + psi[r, nx + 1].real * sf
        zi += psi[r, nx].imag * cf + psi[r, nx + 1].imag * sf
        if r == 0:
            out0 = zr * rot_c - zi * rot_s
            out1 = zr * rot_s + zi * rot_c
        else:
            out2 = zr * rot_c - zi * rot_s
            out3 = zr * rot_s + zi * rot_c
    return out0, out1, out2, out3


@njit(cache=True, nogil=True, inline="always")
def portrait(gl, glb, P, x, cf, sf, dt, nx):
    """(∫ ṡ², ∫ ṡ_b ṡ) over one exact step by 4-point Gauss–Legendre: ``gl[j]`` are the rows
    giving (ṡ, ṡ_b) at node j from [x; cf; sf], ``glb[j]`` their impulse columns."""
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
    return dt * vv, dt * vb


@njit(cache=True, nogil=True)
def record_step(hist, xh, kst, tau, x, nx, W, d, N, n, l1, l2):
    """One history sample after a step."""
    ms.record(hist, xh, kst, tau, x[n], ms.dot(W, x, N), ms.dot(d, x, n), x[N + n],
              ms.dot(d, x[N:], n), l1, l2, 0.0, x, nx)  # fmt: skip


def gauss_rows(P_of_t, dt: float, N: int, d: np.ndarray) -> np.ndarray:
    """(4, 2, nz) rows of (ṡ, ṡ_b) at the Gauss nodes of a step of ``dt``; ``P_of_t(t)`` is the
    exact propagator of the augmented state over t."""
    n = N - 1
    out = []
    for t in ms.GL_NODES * dt:
        P = P_of_t(t)
        out.append([P[N + n, :], d @ P[N : N + n, :]])
    return np.ascontiguousarray(np.array(out))


class SteppingRun(KernelRun):
    """The run of a time-stepping kernel. Subclasses set ``kernel`` (a compiled kernel, as a
    staticmethod) and, in ``__init__``, ``arrays`` (what it takes after the run's shared
    arrays) and ``xn`` (a scratch state)."""

    kernel: Callable[..., tuple[int, int, int]]
    arrays: tuple
    xn: np.ndarray

    def _advance(self, n, measure, checks, rows, samples):
        return self.kernel(
            self.x, self.kst, self.ring, n, measure, checks, rows, samples, self.hist, self.xh,
            *self.arrays, self.lin_L, self.lin_xp, self.lin_amp, self.lin_gate, self.div_limit,
            self.tol, self.xn,
        )  # fmt: skip
