"""The impact-free cell: its closed-form steady state, and proofs that no stop is reached again.

Between impacts the cell is linear, ``ẋ = A x + b (f_cos cos γτ + f_sin sin γτ)``. Every free
motion is the closed-form steady state ``x_p(τ) = Re(X̂ e^{iγτ})`` plus a homogeneous part, so
from a state ``x`` at forcing phase 0 the tip moves as

    w_tip(t) = Re(Ŵ e^{iγt}) + Re Σ_k c_k e^{λ_k t},   c = (W V)∘(V⁻¹ (x - x_p(0))),

a sum of exponentials. If every ``Re λ_k <= 0``, ``|w_tip(t)| <= |Ŵ| + Σ_k |c_k| e^{Re λ_k t}``
for all ``t >= 0``. The tail is proven impact-free (:meth:`LinearTail.proves`) when this bound
is below both clearances from some ``t*`` on and an exact root search of both gaps
(``event.roots.first_root``) shows no contact on ``[0, t*]``. With ``t* = 0`` the test is the
cheap per-period check of the kernels (``measure.period_end``). When the tail is proven and the
cell is damped, the point's steady state *is* the closed form (the ``linear`` outcome); with
``Re λ = 0`` (no damping) the free vibration never decays, which is a failure, not a result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from worker.memo import ArrayMemo
from worker.model import SteadyState, System, steady_state
from worker.solvers.event.regimes import cell_modes
from worker.solvers.event.roots import STACK, STACK_COLS, first_root

__all__ = ["GATE_RTOL", "LinearTail", "linear_tail", "tail_proof"]

# The bound must stay below the clearance by this relative margin (round-off in the bound).
GATE_RTOL = 1e-9
# Eigenvalues with Re λ within this fraction of |λ| of zero count as undamped.
UNDAMPED_RTOL = 1e-12


@dataclass(frozen=True)
class LinearTail:
    """What the linear tail test needs for one point (arrays ready for the kernels)."""

    steady: SteadyState | None  # None: no steady state (forcing at an undamped resonance)
    lam: np.ndarray  # kept eigenvalues of the free system (one of each conjugate pair)
    L: np.ndarray  # (m, 2N) complex: tip coefficient of each kept mode from x - x_p(0)
    xp0: np.ndarray  # (2N,) x_p at forcing phase 0 (zeros without a steady state)
    w_hat: complex  # Ŵ: the steady state's complex tip amplitude at phase 0
    amp: float  # |Ŵ|
    gamma_r: float
    gate: float  # the bound must be below this (the smaller clearance, less round-off)
    g1: float
    g2: float
    usable: bool  # the bound is valid (Re λ <= 0, a steady state exists, V well conditioned)
    damped: bool  # every mode decays (Re λ < 0): a proven tail is a steady state
    max_re: float  # largest Re λ of the free system
    scale: float  # size of the steady state's state vector (or of the static response)

    def proves(self, x: np.ndarray, horizon: float) -> bool:
        """Whether the free motion from ``x`` (forcing phase 0) provably never reaches a stop:
        the bound is below the gate from some ``t* <= horizon`` on, and an exact search of
        both gaps finds no contact on ``[0, t*]`` (compiled: :func:`tail_proof`)."""
        if not self.usable:
            return False
        return tail_proof(self.L, self.xp0, self.lam, np.asarray(x, dtype=np.float64), self.amp,
                          self.gate, self.w_hat, self.gamma_r, self.g1, self.g2,
                          float(horizon))  # fmt: skip


@njit(cache=True, nogil=True)
def tail_proof(L, xp0, lam, x, amp, gate, w_hat, gamma_r, g1, g2, horizon):
    """The linear tail proof of :meth:`LinearTail.proves` (a usable tail): with
    ``c = L (x - x_p(0))``, the tip's bound ``|Ŵ| + Σ|c_k| e^{Re λ_k t}`` decreases in t; where it
    passes the gate (to horizon/1024, on two grids of 33 times) is t*, and both gaps are
    searched for a root on [0, t*]."""
    m = L.shape[0]
    nx = x.shape[0]
    nk = m + 1
    coef = np.empty(nk, dtype=np.complex128)
    lamc = np.empty(nk, dtype=np.complex128)
    mag = np.empty(m)
    decay = np.empty(m)
    total = amp
    still = amp  # the part that never decays
    for k in range(m):
        z = 0j
        for j in range(nx):
            z += L[k, j] * (x[j] - xp0[j])
        coef[k] = z
        lamc[k] = lam[k]
        mag[k] = abs(z)
        decay[k] = min(lam[k].real, 0.0)
        total += mag[k]
        if decay[k] == 0.0:
            still += mag[k]
    if total < gate:
        return True
    if still >= gate:
        return False
    end = amp
    for k in range(m):
        end += mag[k] * math.exp(decay[k] * horizon)
    if end >= gate:
        return False
    lo = 0.0
    hi = horizon
    for _ in range(2):
        step = (hi - lo) / 32.0
        first = 32
        for i in range(33):
            t = lo + step * i
            b = amp
            for k in range(m):
                b += mag[k] * math.exp(decay[k] * t)
            if b < gate:
                first = i
                break
        lo, hi = lo + step * max(first - 1, 0), lo + step * first
    coef[m] = w_hat
    lamc[m] = 1j * gamma_r
    stack = np.zeros((STACK, STACK_COLS))
    w4 = np.zeros(nk)
    tol_t = 1e-9 * hi
    # stop 1: g1 - w > 0; stop 2: g2 + w > 0, with w = Re Σ coef e^{λt}
    neg = np.empty(nk, dtype=np.complex128)
    for k in range(nk):
        neg[k] = -coef[k]
    if first_root(neg, lamc, nk, g1, 0.0, hi, tol_t, stack, w4) >= 0.0:
        return False
    return first_root(coef, lamc, nk, g2, 0.0, hi, tol_t, stack, w4) < 0.0


_FREE = ArrayMemo()  # the free system's modes, per cell (γ_r does not enter them)


def _free_modes(A: np.ndarray, W: np.ndarray, N: int) -> tuple:
    """Eigenvalues of ``A`` in reduced form (``regimes.cell_modes``: one of each conjugate pair,
    weight 2), the tip rows ``L``, the largest ``Re λ``, whether the tail bound is valid
    (``Re λ <= 0``, V well conditioned) and whether every mode decays."""
    lam, V, Vi, keep, weight, _, cv, cvi = cell_modes(A)
    lam_abs = float(np.max(np.abs(lam)))
    max_re = float(np.max(lam.real))
    valid = max_re <= UNDAMPED_RTOL * max(lam_abs, 1.0)
    damped = max_re < -UNDAMPED_RTOL * max(lam_abs, 1.0)
    cond = cv * float(np.max(cvi))  # the 1-norm condition number of V
    cond_ok = math.isfinite(cond) and cond < 1e12
    # Re(c e^{λt} + c̄ e^{λ̄t}) = Re(2c e^{λt}): the weight folds a pair into one term
    WV = (W @ V[:N, :])[keep]
    L = np.ascontiguousarray((weight * WV)[:, None] * Vi[keep, :])
    return np.ascontiguousarray(lam[keep]), L, max_re, bool(valid and cond_ok), bool(damped)


def linear_tail(sys_: System, forcing: bool = True) -> LinearTail:
    """Closed-form steady state and the tail-proof data of ``sys_`` (forcing on or off)."""
    p = sys_.params
    N = sys_.ndof
    A = sys_.state_matrix()
    lam, L, max_re, valid, damped = _FREE.get((A, sys_.W), lambda: _free_modes(A, sys_.W, N))
    steady = steady_state(sys_, forcing=forcing)
    if steady is None:
        xp0 = np.zeros(2 * N)
        w_hat = 0j
        static = np.linalg.solve(sys_.K, np.eye(N)[-1]) * math.hypot(sys_.f_sin, sys_.f_cos)
        scale = float(np.max(np.abs(static)))
    else:
        xp0 = steady.state_at_phase_zero()
        w_hat = complex(sys_.W @ steady.U)
        scale = float(np.max(np.abs(np.concatenate([steady.U, 1j * p.gamma_r * steady.U]))))
    return LinearTail(
        steady=steady,
        lam=lam.copy(),  # copies: the cached arrays are shared by the cell's points
        L=L.copy(),
        xp0=np.ascontiguousarray(xp0),
        w_hat=w_hat,
        amp=abs(w_hat),
        gamma_r=p.gamma_r,
        gate=min(p.g1, p.g2) * (1.0 - GATE_RTOL),
        g1=float(p.g1),
        g2=float(p.g2),
        usable=bool(valid and steady is not None),
        damped=damped,
        max_re=max_re,
        scale=max(scale, 1e-300),
    )
