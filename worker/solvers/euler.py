"""``method: euler``: the paper's semi-implicit Euler scheme with impulses (Eqs. 13, 31).

Per step: the free velocity ``q_f = q + Δτ M⁻¹(-C q - K u + e_s f)``, the predicted gaps, the
two-stop LCP (closed form, or Lemke's algorithm at every step with ``lcp="lemke"``, as
published), then ``q ← q_f + M⁻¹X(-Λ1 + Λ2)`` and ``u ← u + q Δτ``. First harmonics and the
phase-portrait integrals are the rectangle rule on the scheme's own samples.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.model import System
from worker.solvers import measure as ms
from worker.solvers.lcp import LEMKE_OK, lemke_nb, lemke_workspace, two_stop_impulses
from worker.solvers.settings import MAX_STEPS_PER_PERIOD, SolverSettings
from worker.solvers.stepping import (
    SteppingRun,
    contact_step,
    extrema,
    record_step,
    tally_impulses,
)

DEFAULT_STEPS = 1024


@njit(**ms.KERNEL_JIT)
def euler_kernel(x, kst, ring, n_periods, measure, checks, rows, samples, hist, xh, spp,
                 gamma_r, f_scale, MinvC, MinvK, Minv_es, MinvX, f_sin, f_cos, W, d, G, g1, g2,
                 e1, e2, use_lemke, lcp_M, lcp_q, lcp_T, lcp_basis, lcp_cand, lcp_B, lcp_xb, lcp_z,
                 lin_L, lin_xp, lin_amp, lin_gate, div_limit, tol, xn):  # fmt: skip
    """Advance up to ``n_periods`` periods; returns (periods done, END code, period found).

    With ``e1 = e2 = 0`` the paper's position-level contact: the impulses close each predicted
    gap. Otherwise Newton's law at the velocity level (Moreau–Jean): a stop whose predicted gap
    closes takes the impulse that leaves the tip's velocity away from it at least ``e`` times
    its approach velocity at the step's start (docs/model.md §5)."""
    nx = x.shape[0]
    N = nx // 2
    n = N - 1
    T = 2.0 * math.pi / gamma_r
    dt = T / spp
    elastic = e1 > 0.0 or e2 > 0.0
    gdt = G if elastic else G * dt  # the contact gain: on velocities, or on positions
    if use_lemke:
        lcp_M[0, 0] = gdt
        lcp_M[0, 1] = -gdt
        lcp_M[1, 0] = -gdt
        lcp_M[1, 1] = gdt
    for k in range(n_periods):
        ms.begin_row(rows, k)
        period = kst[ms.K_PERIOD]
        contact = int(kst[ms.K_CONTACT])
        smin = np.inf
        smax = -np.inf
        h0 = h1 = h2 = h3 = vv = vb = 0.0
        imp1 = imp2 = peak = nsteps = ncontact = 0.0
        ct1 = ct2 = vimp1 = vimp2 = en1 = en2 = 0.0
        last = -1.0
        for js in range(spp):
            cph = math.cos(gamma_r * js * dt)
            sph = math.sin(gamma_r * js * dt)
            s0 = x[n]
            v0 = x[N + n]
            fval = f_scale * (f_sin * sph + f_cos * cph)
            for i in range(N):
                acc = Minv_es[i] * fval
                for j in range(N):
                    acc -= MinvC[i, j] * x[N + j] + MinvK[i, j] * x[j]
                xn[N + i] = x[N + i] + dt * acc
            wpred = 0.0
            for i in range(N):
                wpred += W[i] * (x[i] + dt * xn[N + i])
            c1 = g1 - wpred
            c2 = g2 + wpred
            if elastic:
                wv0 = ms.dot(W, x[N:], N)  # the tip's velocity before: the approach
                wvf = ms.dot(W, xn[N:], N)  # and after the free step
                c1 = -(wvf + e1 * max(wv0, 0.0)) if c1 <= 0.0 else 0.0
                c2 = (wvf - e2 * max(-wv0, 0.0)) if c2 <= 0.0 else 0.0
            if use_lemke:
                lcp_q[0] = c1
                lcp_q[1] = c2
                status = lemke_nb(lcp_M, lcp_q, lcp_T, lcp_basis, lcp_cand, lcp_B, lcp_xb,
                                  lcp_z, 50)  # fmt: skip
                if status != LEMKE_OK:  # no solution: the state becomes non-finite, the
                    lcp_z[0] = np.nan  # point fails with that reason
                l1 = lcp_z[0]
                l2 = lcp_z[1]
            else:
                l1, l2 = two_stop_impulses(gdt, c1, c2)
            P = l2 - l1
            vm = 0.0
            if l1 > 0.0 or l2 > 0.0:
                vm = ms.dot(W, xn[N:], N)  # the free velocity Wᵀq_f: the impulse's v⁻
            for i in range(N):
                xn[N + i] += MinvX[i] * P
                xn[i] = x[i] + dt * xn[N + i]
            if measure:
                # the rectangle rule over whole periods: the DFT of the scheme's own samples
                sbv = ms.dot(d, x, n)
                h0 += dt * x[n] * cph
                h1 -= dt * x[n] * sph
                h2 += dt * sbv * cph
                h3 -= dt * sbv * sph
            if l1 > 0.0 or l2 > 0.0:
                ct1, ct2, vimp1, vimp2, en1, en2 = tally_impulses(
                    l1, l2, contact, ms.dot(W, x[N:], N), vm, vm + G * P, G, dt, ct1, ct2, vimp1,
                    vimp2, en1, en2,
                )  # fmt: skip
            for i in range(nx):
                x[i] = xn[i]
            v1 = x[N + n]
            if measure:
                vv += dt * v1 * v1
                vb += dt * ms.dot(d, x[N:], n) * v1
            smin, smax = extrema(s0, v0, x[n], v1, dt, smin, smax)
            nsteps += 1.0
            if l1 > 0.0 or l2 > 0.0:
                ncontact += 1.0
            if l1 > 0.0 or l2 > 0.0 or contact != 0:
                contact, imp1, imp2, peak, last = contact_step(
                    l1, l2, js / spp, contact, imp1, imp2, peak, last, W, x, N, g1, g2
                )
            if hist.shape[0] > 0:
                record_step(hist, xh, kst, period * T + (js + 1) * dt, x, nx, W, d, N, n, l1, l2)
        ms.close_row(rows, k, smin, smax, (h0, h1, h2, h3), vv, vb, imp1, imp2, peak, last,
                     nsteps, ncontact, 0.0, contact)  # fmt: skip
        ms.close_impacts(rows, k, ct1, ct2, vimp1, vimp2, en1, en2)
        kst[ms.K_CONTACT] = contact  # read at the next period's start, this batch or the next
        kst[ms.K_PERIOD] += 1.0
        code, p = ms.period_end(x, nx, rows, samples, k, ring, kst, lin_L, lin_xp, lin_amp,
                                lin_gate, checks, div_limit, tol)  # fmt: skip
        if code != ms.END_NONE:
            return k + 1, code, p
    return n_periods, ms.END_NONE, 0


def _radius(sys_: System, dt: float) -> float:
    """Spectral radius of the scheme's free-flight step matrix."""
    n = sys_.ndof
    MK = sys_.Minv @ sys_.K
    MC = sys_.Minv @ sys_.C
    eye = np.eye(n)
    Q = eye - dt * MC
    A = np.block([[eye - dt * dt * MK, dt * Q], [-dt * MK, Q]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def largest_stable_step(sys_: System, dt: float) -> float:
    """Bisection on (0, dt] for the largest step with spectral radius <= 1 (dt is unstable)."""
    lo, hi = 0.0, dt
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _radius(sys_, mid) > 1.0 + 1e-9:
            hi = mid
        else:
            lo = mid
    return lo


def check_stable(sys_: System, dt: float) -> None:
    """Refuse Euler steps beyond the stability limit, naming the largest stable step."""
    wmax = sys_.omega_max()
    limit = 2.0 / wmax
    period = 2.0 * math.pi / sys_.params.gamma_r
    if dt * wmax >= 2.0:
        raise ValueError(
            f"steps_per_period gives Δτ = {dt:.6g} with Δτ·ω̃_max = {dt * wmax:.4g} >= 2: the "
            f"euler scheme is unstable; the largest stable step is Δτ < {limit:.6g} "
            f"(ω̃_max = {wmax:.6g}), i.e. steps_per_period > {period / limit:.1f}"
        )
    # Damping is explicit in the scheme: heavily damped high modes can be unstable below 2/ω.
    if _radius(sys_, dt) > 1.0 + 1e-9:
        raise ValueError(
            f"steps_per_period gives Δτ = {dt:.6g}, unstable for the euler scheme with this "
            f"damping; the largest stable step is Δτ ≈ {largest_stable_step(sys_, dt):.6g}"
        )


def default_steps(sys_: System) -> int:
    """Default Euler resolution: 1024 per period, or enough for Δτ·ω̃_max <= 1.

    Where explicit damping of stiff modes makes that step unstable, half the largest stable
    step (the same factor 2 of margin), so the default is never refused for stability.
    """
    T = 2.0 * math.pi / sys_.params.gamma_r
    n = max(DEFAULT_STEPS, math.ceil(T * sys_.omega_max()))
    if _radius(sys_, T / n) > 1.0 + 1e-9:
        n = math.ceil(2.0 * T / largest_stable_step(sys_, T / n))
    return n


class EulerRun(SteppingRun):
    """A point integrated by the paper's scheme."""

    name = "euler"
    kernel = staticmethod(euler_kernel)

    @classmethod
    def check_point(cls, sys_: System, settings: SolverSettings) -> int:
        """The steps per period this point runs at; refused beyond the stability limit or
        beyond ``MAX_STEPS_PER_PERIOD``."""
        spp = settings.steps_per_period or default_steps(sys_)
        if spp > MAX_STEPS_PER_PERIOD:
            # only a default can get here (an explicit value is validated): refuse, don't hang
            raise ValueError(
                f"the euler scheme needs steps_per_period >= {spp} here (Δτ·ω̃_max <= 1, "
                f"ω̃_max = {sys_.omega_max():.6g}), more than the limit {MAX_STEPS_PER_PERIOD}; "
                f"use method exponential or event"
            )
        check_stable(sys_, 2.0 * math.pi / sys_.params.gamma_r / spp)
        return spp

    def __init__(self, sys_: System, settings: SolverSettings, *args) -> None:
        super().__init__(sys_, settings, *args)
        p = sys_.params
        spp = self.check_point(sys_, settings)
        self.spp = spp
        Minv = sys_.Minv
        c = np.ascontiguousarray
        self.arrays = (
            spp, p.gamma_r, self.f_scale, c(Minv @ sys_.C), c(Minv @ sys_.K), c(Minv[:, -1]),
            c(Minv @ sys_.X), sys_.f_sin, sys_.f_cos, sys_.W, sys_.d, sys_.G, p.g1, p.g2, p.e1,
            p.e2, settings.lcp == "lemke", np.zeros((2, 2)), np.zeros(2), *lemke_workspace(2),
        )  # fmt: skip
        self.xn = np.zeros(self.nx)
