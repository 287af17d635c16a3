"""Drivers around the kernels: validate, prepare matrices, run, read the result record."""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import scipy.linalg

from worker import kernels as K
from worker.model import CellParams, System, assemble
from worker.observables import theta_eff_harmonic, theta_eff_instantaneous, transmittance_db

SOLVER_VERSION = "1"
METHODS = ("exponential", "euler", "event")
LCP_SOLVERS = ("closed", "lemke")
DEFAULT_EXP_STEPS = 2048
DEFAULT_COARSE_STEPS = 64
DEFAULT_EULER_STEPS = 1024
MAX_STEPS_PER_PERIOD = 10_000_000


def _int_in(name: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in {lo}…{hi}, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name} must be an integer in {lo}…{hi}, got {value}")
    return int(value)


@dataclass(frozen=True)
class SolverSettings:
    """How a point is integrated and measured.

    Parameters
    ----------
    method : {"exponential", "euler", "event"}
        Exact propagator with impulses (default), the paper's semi-implicit Euler scheme, or
        the event-driven reference solver (``worker/event.py``; ``steps_per_period`` is then
        its sub-grid of event brackets, default 64).
    steps_per_period : int or None
        Time steps per excitation period; for ``exponential`` the resolution used near the
        stops (free flight takes whole coarse steps, exactly). ``None`` picks a default:
        2048 for ``exponential``; for ``euler`` 1024 or enough steps for Δτ·ω̃_max <= 1
        (with heavily damped stiff modes: half the largest stable step).
    coarse_steps : int
        Free-flight steps per period of ``exponential`` (a divisor of ``steps_per_period`` is
        used).
    max_periods : int
        Period budget; a point not periodic by then is ``irregular``.
    periodicity_tol : float
        Relative tolerance of the stroboscopic periodicity test (including the estimated
        remaining transient).
    window : int
        Measurement window (periods) of an irregular response.
    near_margin : float
        ``exponential`` refines a coarse step when the tip may come within this fraction of
        a stop's gap of that stop.
    adaptive : bool
        ``exponential`` only: take whole coarse steps far from the stops (results are the same
        up to round-off; switch off to compare).
    early_stop : bool
        Stop once periodic (measure p more periods); off runs the whole budget.
    lcp : {"closed", "lemke"}
        ``euler`` only: the two-stop contact LCP of each step in closed form (default) or by
        the compiled Lemke solver of ``worker/lcp.py``, as the paper does (same solution; a
        cost comparison).
    """

    method: str = "exponential"
    steps_per_period: int | None = None
    coarse_steps: int = DEFAULT_COARSE_STEPS
    max_periods: int = 1000
    periodicity_tol: float = 1e-8
    window: int = 20
    near_margin: float = 0.1
    adaptive: bool = True
    early_stop: bool = True
    lcp: str = "closed"

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.steps_per_period is not None:
            object.__setattr__(
                self,
                "steps_per_period",
                _int_in("steps_per_period", self.steps_per_period, 4, MAX_STEPS_PER_PERIOD),
            )
        object.__setattr__(
            self, "coarse_steps", _int_in("coarse_steps", self.coarse_steps, 4, 1 << 20)
        )
        object.__setattr__(
            self, "max_periods", _int_in("max_periods", self.max_periods, 2, 10_000_000)
        )
        object.__setattr__(self, "window", _int_in("window", self.window, 1, 10_000_000))
        if self.window >= self.max_periods:
            raise ValueError(
                f"window must be < max_periods ({self.max_periods}), got {self.window}"
            )
        tol = self.periodicity_tol
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0.0 < tol < 1.0:
            raise ValueError(f"periodicity_tol must be in (0, 1), got {tol!r}")
        if self.lcp not in LCP_SOLVERS:
            raise ValueError(f"lcp must be one of {', '.join(LCP_SOLVERS)}, got {self.lcp!r}")
        m = self.near_margin
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not 0.0 <= m < 1.0:
            raise ValueError(f"near_margin must be in [0, 1), got {m!r}")


@dataclass
class PointResult:
    """What one point reports (MODEL.md §6). Values are ``None`` when the point failed."""

    transmittance_db: float | None
    amplitude: float | None
    theta_eff: float | None
    theta_eff_mean: float | None
    response_period: int
    impacts_per_period: tuple[float, float] | None
    peak_impulse: float | None
    converged: bool
    periods: int
    steps: int
    contact_steps: int
    coarse_steps: int
    steady_period: int
    wall_s: float
    failed: bool
    reason: str
    method: str
    steps_per_period: int
    history: dict[str, np.ndarray] | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict (no history)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "history"}
        if self.impacts_per_period is not None:
            out["impacts_per_period"] = list(self.impacts_per_period)
        return out


@dataclass(frozen=True)
class _Prepared:
    method: int
    n_coarse: int
    n_sub: int
    arrays: tuple


def _euler_check(sys_: System, dt: float) -> None:
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
    if _euler_radius(sys_, dt) > 1.0 + 1e-9:
        raise ValueError(
            f"steps_per_period gives Δτ = {dt:.6g}, unstable for the euler scheme with this "
            f"damping; the largest stable step is Δτ ≈ {_largest_stable_step(sys_, dt):.6g}"
        )


def _largest_stable_step(sys_: System, dt: float) -> float:
    """Bisection on (0, dt] for the largest step with spectral radius <= 1 (dt is unstable)."""
    lo, hi = 0.0, dt
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _euler_radius(sys_, mid) > 1.0 + 1e-9:
            hi = mid
        else:
            lo = mid
    return lo


def _euler_radius(sys_: System, dt: float) -> float:
    n = sys_.ndof
    MK = sys_.Minv @ sys_.K
    MC = sys_.Minv @ sys_.C
    eye = np.eye(n)
    Q = eye - dt * MC
    A = np.block([[eye - dt * dt * MK, dt * Q], [-dt * MK, Q]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def euler_default_steps(sys_: System) -> int:
    """Default Euler resolution: 1024 per period, or enough for Δτ·ω̃_max <= 1.

    Where explicit damping of stiff modes makes that step unstable, half the largest stable
    step (the same factor 2 of margin), so the default is never refused.
    """
    T = 2.0 * math.pi / sys_.params.gamma_r
    n = max(DEFAULT_EULER_STEPS, math.ceil(T * sys_.omega_max()))
    if _euler_radius(sys_, T / n) > 1.0 + 1e-9:
        n = math.ceil(2.0 * T / _largest_stable_step(sys_, T / n))
    return n


def _augmented(sys_: System) -> np.ndarray:
    """``ż = A_aug z`` with ``z = [u; q; cos γτ; sin γτ]``: harmonic forcing carried exactly."""
    n = sys_.ndof
    g = sys_.params.gamma_r
    A = np.zeros((2 * n + 2, 2 * n + 2))
    A[: 2 * n, : 2 * n] = sys_.state_matrix()
    fs = sys_.Minv[:, -1]  # M⁻¹ e_s
    A[n : 2 * n, 2 * n] = fs * sys_.f_cos
    A[n : 2 * n, 2 * n + 1] = fs * sys_.f_sin
    A[2 * n, 2 * n + 1] = -g
    A[2 * n + 1, 2 * n] = g
    return A


def _fourier_rows(sys_: System, A_aug: np.ndarray, dt: float) -> np.ndarray:
    """Rows ψ with ψ·z(0) = ∫₀^dt [s; s_b](t) e^{-iγt} dt exactly, for free flight from z(0)."""
    nz = A_aug.shape[0]
    # ∫₀^dt e^{(A - iγ)t} dt is the top-right block of exp([[A - iγ, I], [0, 0]] dt).
    B = np.zeros((2 * nz, 2 * nz), dtype=complex)
    B[:nz, :nz] = A_aug - 1j * sys_.params.gamma_r * np.eye(nz)
    B[:nz, nz:] = np.eye(nz)
    integral = scipy.linalg.expm(B * dt)[:nz, nz:]
    n = sys_.ndof - 1
    R = np.zeros((2, nz))
    R[0, n] = 1.0  # s
    R[1, :n] = sys_.d  # s_b
    return np.ascontiguousarray(R @ integral)


def _step_maps(sys_: System, A_aug: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """Exact one-step map (Φ, E) and the exact Fourier integral rows ψ over a step of ``dt``."""
    nx = A_aug.shape[0] - 2
    P = scipy.linalg.expm(A_aug * dt)
    Phi = np.ascontiguousarray(P[:nx, :nx])
    E = np.ascontiguousarray(P[:nx, nx:])
    return Phi, E, _fourier_rows(sys_, A_aug, dt)


def _prepare(sys_: System, settings: SolverSettings) -> _Prepared:
    nx = 2 * sys_.ndof
    empty2 = np.zeros((1, 1))
    T = 2.0 * math.pi / sys_.params.gamma_r
    if settings.method == "euler":
        spp = settings.steps_per_period or euler_default_steps(sys_)
        if spp > MAX_STEPS_PER_PERIOD:
            # only a default can get here (an explicit value is validated): refuse, don't hang
            raise ValueError(
                f"the euler scheme needs steps_per_period >= {spp} here (Δτ·ω̃_max <= 1, "
                f"ω̃_max = {sys_.omega_max():.6g}), more than the limit {MAX_STEPS_PER_PERIOD}; "
                f"use method exponential or event"
            )
        _euler_check(sys_, T / spp)
        Minv = sys_.Minv
        arrays = (
            empty2,
            np.zeros((1, 2)),
            empty2,
            np.zeros((1, 2)),
            np.zeros(nx),
            np.zeros((2, nx + 2), dtype=complex),
            np.zeros((2, nx + 2), dtype=complex),
            np.zeros(2, dtype=complex),
            np.ascontiguousarray(Minv @ sys_.C),
            np.ascontiguousarray(Minv @ sys_.K),
            np.ascontiguousarray(Minv[:, -1]),
            np.ascontiguousarray(Minv @ sys_.X),
        )
        return _Prepared(K.METHOD_EULER, spp, 1, arrays)

    spp = settings.steps_per_period or DEFAULT_EXP_STEPS
    n_coarse = min(settings.coarse_steps, spp)
    while spp % n_coarse:
        n_coarse -= 1
    n_sub = spp // n_coarse
    A_aug = _augmented(sys_)
    dtc = T / n_coarse
    Phi_c, E_c, psi_c = _step_maps(sys_, A_aug, dtc)
    Phi_f, E_f, psi_f = _step_maps(sys_, A_aug, dtc / n_sub)
    # Moreau: the impulse acts at the start of a fine step, so it moves the end state by Φ_f b
    # and the step's Fourier integral by ψ_f b.
    b = np.zeros(nx)
    b[sys_.ndof :] = sys_.Minv @ sys_.X
    b_f = Phi_f @ b
    psib_f = psi_f[:, :nx] @ b
    arrays = (
        Phi_c,
        E_c,
        Phi_f,
        E_f,
        np.ascontiguousarray(b_f),
        psi_c,
        psi_f,
        np.ascontiguousarray(psib_f),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros(1),
        np.ascontiguousarray(sys_.Minv @ sys_.X),
    )
    return _Prepared(K.METHOD_EXPONENTIAL, n_coarse, n_sub, arrays)


_warm: set[str] = set()  # methods whose kernels are compiled in this process


def warm_up(method: str | None = None) -> None:
    """Compile (or load from numba's cache) a method's kernels once (default: every method),
    so ``wall_s`` never includes it. Only the method asked for is compiled: a fresh machine
    does not pay for kernels it does not use."""
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, modes=1)
    for m in METHODS if method is None else (method,):
        if m in _warm:
            continue
        _warm.add(m)
        simulate_point(p, SolverSettings(method=m, steps_per_period=64, max_periods=3, window=1))


def simulate_point(
    params: CellParams,
    settings: SolverSettings | None = None,
    *,
    history_periods: int = 0,
    initial_state: np.ndarray | None = None,
    forcing: bool = True,
) -> PointResult:
    """Simulate one point from rest to steady state and measure it.

    Parameters
    ----------
    params : CellParams
        The cell and excitation.
    settings : SolverSettings, optional
        Method and measurement settings (defaults: ``SolverSettings()``).
    history_periods : int
        Keep the time history of the last this-many periods (never for whole studies).
    initial_state : ndarray, optional
        ``[u; q]`` at τ = 0 (default: rest).
    forcing : bool
        Switch the base excitation off (energy checks).

    Returns
    -------
    PointResult
        ``failed`` with a reason (and ``None`` values) when the state stopped being finite.
    """
    settings = settings or SolverSettings()
    warm_up(settings.method)
    if settings.method == "event":
        from worker.event import simulate_event

        return simulate_event(
            params, settings, history_periods=history_periods, initial_state=initial_state,
            forcing=forcing,
        )  # fmt: skip
    sys_ = assemble(params)
    prep = _prepare(sys_, settings)
    nx = 2 * sys_.ndof
    x = np.zeros(nx)
    if initial_state is not None:
        x0 = np.asarray(initial_state, dtype=float)
        if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial_state must be {nx} finite numbers, got shape {x0.shape}")
        x[:] = x0
    history_periods = _int_in("history_periods", history_periods, 0, 100_000)
    spp = prep.n_coarse * prep.n_sub
    cap = history_periods * spp
    hist = np.zeros((cap, K.H_COLS))
    xh = np.zeros((cap, nx))
    out = np.zeros(K.OUT_SIZE)
    xn = np.zeros(nx)
    ring = np.zeros((K.RING, nx))
    p = params
    t0 = time.perf_counter()
    K.simulate_kernel(
        prep.method, x, prep.n_coarse, prep.n_sub, p.gamma_r, 1.0 if forcing else 0.0,
        *prep.arrays,
        sys_.f_sin, sys_.f_cos, sys_.W, sys_.d, sys_.G, p.g1, p.g2, sys_.kappa, p.theta,
        settings.max_periods, settings.periodicity_tol, settings.window, settings.near_margin,
        settings.adaptive, settings.early_stop, 1e-3,
        hist, xh, out, xn, ring, settings.method == "euler" and settings.lcp == "lemke",
    )  # fmt: skip
    wall = time.perf_counter() - t0
    return _result(out, params, settings, sys_, wall, spp, hist, xh, history_periods)


def _result(out, params, settings, sys_, wall, spp, hist, xh, history_periods) -> PointResult:
    periods = int(out[K.O_PERIODS])
    common = dict(
        periods=periods,
        steps=int(out[K.O_STEPS]),
        contact_steps=int(out[K.O_CONTACT_STEPS]),
        coarse_steps=int(out[K.O_COARSE_SKIPPED]),
        steady_period=int(out[K.O_STEADY_PERIOD]),
        wall_s=wall,
        method=settings.method,
        steps_per_period=spp,
    )
    history = _unroll(hist, xh, out, params, sys_) if history_periods else None
    values = [out[k] for k in (K.O_S_MAX, K.O_S_MIN, K.O_S_RE, K.O_S_IM, K.O_SB_RE, K.O_SB_IM)]
    reason = ""
    if out[K.O_FAILED] == 1.0:
        reason = f"state stopped being finite in period {int(out[K.O_FAIL_PERIOD])}"
    elif not all(math.isfinite(v) for v in values):
        reason = "measurement not finite"
    amp = 0.5 * (out[K.O_S_MAX] - out[K.O_S_MIN])
    if not reason and amp <= 0.0:
        reason = "no motion of the outer mass in the measurement window"
    if reason:
        return PointResult(
            transmittance_db=None, amplitude=None, theta_eff=None, theta_eff_mean=None,
            response_period=0, impacts_per_period=None, peak_impulse=None, converged=False,
            failed=True, reason=reason, history=history, **common,
        )  # fmt: skip
    S = complex(out[K.O_S_RE], out[K.O_S_IM])
    Sb = complex(out[K.O_SB_RE], out[K.O_SB_IM])
    theta_eff = theta_eff_harmonic(S, Sb, sys_.kappa, params.theta)
    tm = out[K.O_THETA_MEAN_T]
    theta_mean = out[K.O_THETA_MEAN_SUM] / tm if tm > 0 else None
    mp = max(out[K.O_MEASURED_PERIODS], 1.0)
    return PointResult(
        transmittance_db=transmittance_db(amp, params.base_scale),
        amplitude=float(amp),
        theta_eff=theta_eff,
        theta_eff_mean=None if theta_mean is None else float(theta_mean),
        response_period=int(out[K.O_RESPONSE_PERIOD]),
        impacts_per_period=(float(out[K.O_IMPACTS1] / mp), float(out[K.O_IMPACTS2] / mp)),
        peak_impulse=float(out[K.O_PEAK_IMPULSE]),
        converged=bool(out[K.O_CONVERGED]),
        failed=False,
        reason="irregular" if not out[K.O_CONVERGED] else "",
        history=history,
        **common,
    )


def _unroll(hist, xh, out, params, sys_) -> dict[str, np.ndarray]:
    count = int(out[K.O_HIST_COUNT])
    cap = hist.shape[0]
    order = np.r_[count % cap : cap, 0 : count % cap] if count > cap else np.arange(count)
    h = hist[order]
    sdot = h[:, K.H_SDOT]
    sbdot = h[:, K.H_SBDOT]
    # NaN marks where Eq. 36 is singular (ṡ ≈ 0); histories only, never a point result.
    inst = theta_eff_instantaneous(sdot, sbdot, sys_.kappa, params.theta)
    return {
        "tau": h[:, K.H_TAU],
        "s": h[:, K.H_S],
        "w_tip": h[:, K.H_WTIP],
        "s_b": h[:, K.H_SB],
        "s_dot": sdot,
        "s_b_dot": sbdot,
        "theta_eff": inst,
        "impulse1": h[:, K.H_L1],
        "impulse2": h[:, K.H_L2],
        "state": xh[order],
    }


POINT_KEYS = ("theta", "sigma", "gamma_s", "gamma_r", "xi", "g1", "g2", "modes", "coupling", "xi_b")


def simulate_chunk(
    points: Iterable[Mapping[str, Any]], solver: Mapping[str, Any] | None = None
) -> list[dict[str, Any]]:
    """Run many points (one dask task). A point that fails is reported, never raised.

    Each point is a mapping of ``CellParams`` fields; ``solver`` holds ``SolverSettings`` fields.
    Returns one ``PointResult.as_dict()`` per point, in order.
    """
    settings = SolverSettings(**(solver or {}))
    results = []
    for pt in points:
        try:
            params = CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt})
            results.append(simulate_point(params, settings).as_dict())
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            results.append(failed_result(settings, str(exc)))
    return results


def failed_result(settings: SolverSettings, reason: str) -> dict[str, Any]:
    """The record of a point that could not be run."""
    r = PointResult(
        transmittance_db=None, amplitude=None, theta_eff=None, theta_eff_mean=None,
        response_period=0, impacts_per_period=None, peak_impulse=None, converged=False,
        periods=0, steps=0, contact_steps=0, coarse_steps=0, steady_period=-1, wall_s=0.0,
        failed=True, reason=reason, method=settings.method,
        steps_per_period=settings.steps_per_period or 0,
    )  # fmt: skip
    return r.as_dict()


__all__ = [
    "SOLVER_VERSION",
    "PointResult",
    "SolverSettings",
    "euler_default_steps",
    "failed_result",
    "simulate_chunk",
    "simulate_point",
    "warm_up",
]
