"""The public door of the worker: one point, or a chunk of points (one dask task).

``simulate_point`` validates, assembles the cell, prepares the method's kernel run
(``solvers.dispatch``) and hands it to the point engine (``solvers.engine``), which runs the
point to its proven end. ``simulate_chunk`` does that for many points and reports a point that
cannot be run as a failed record, never as an exception.
"""

from __future__ import annotations

import importlib
import math
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from worker.model import CellParams, assemble, steady_state
from worker.solvers.dispatch import KERNELS, RUNS
from worker.solvers.engine import DIVERGENCE_FACTOR, linear_reference_db, run_point
from worker.solvers.event.kernel import EVENT_FIELDS
from worker.solvers.linear import linear_tail
from worker.solvers.measure import HISTORY_FIELDS
from worker.solvers.settings import (
    DEFAULT_METHOD,
    LCP_SOLVERS,
    METHODS,
    OUTCOMES,
    SOLVER_VERSION,
    PointCancelled,
    PointLimits,
    PointResult,
    SolverSettings,
    int_in,
)

__all__ = [
    "DEFAULT_METHOD",
    "EVENT_FIELDS",
    "HISTORY_FIELDS",
    "LCP_SOLVERS",
    "METHODS",
    "OUTCOMES",
    "POINT_KEYS",
    "SOLVER_VERSION",
    "PointCancelled",
    "PointLimits",
    "PointResult",
    "SolverSettings",
    "failed_result",
    "kernels_cached",
    "linear_reference",
    "point_history",
    "simulate_chunk",
    "simulate_point",
    "warm_up",
]

POINT_KEYS = ("theta", "sigma", "gamma_s", "gamma_r", "xi", "g1", "g2", "modes", "coupling", "xi_b")

# How long a first compilation usually takes on a 2-core machine (measured; README).
COMPILE_SECONDS = {"event": "40–90", "exponential": "15–40", "euler": "10–30"}


def simulate_point(
    params: CellParams,
    settings: SolverSettings | None = None,
    *,
    history_periods: int = 0,
    initial_state: np.ndarray | None = None,
    forcing: bool = True,
    limits: PointLimits | None = None,
    cancelled: Callable[[], bool] | None = None,
    **options: Any,
) -> PointResult:
    """Simulate one point to its proven end and measure it.

    Parameters
    ----------
    params : CellParams
        The cell and excitation.
    settings : SolverSettings, optional
        Method and how a point ends (defaults: ``SolverSettings()``).
    history_periods : int
        Return the time history of this many periods of the reported response (the orbit,
        the closed-form steady state, or the last periods of an irregular run); never for
        whole studies.
    initial_state : ndarray, optional
        ``[u; q]`` at τ = 0 (default: rest).
    forcing : bool
        Switch the base excitation off (energy checks).
    limits : PointLimits, optional
        Wall-time and step budget of the point (default ``PointLimits()``); a point over its
        budget is ``failed`` with that reason.
    cancelled : callable, optional
        Polled between batches of periods; when it returns true the point raises
        :class:`PointCancelled`.
    **options
        Method options: ``event_tol``, ``max_events_per_period`` (``event``).

    Returns
    -------
    PointResult
        ``outcome`` says how the point ended; ``failed`` points carry a reason and ``None``
        values.

    Raises
    ------
    ValueError
        Invalid settings or state, or a method refusing the point (e.g. an unstable Euler
        step); ``simulate_chunk`` turns these into failed records.
    """
    settings = settings or SolverSettings()
    history_periods = int_in("history_periods", history_periods, 0, 100_000)
    RUNS[settings.method].check_options(**options)
    warm_up(settings.method)
    sys_ = assemble(params)
    nx = 2 * sys_.ndof
    x0 = np.zeros(nx)
    if initial_state is not None:
        x0 = np.asarray(initial_state, dtype=float)
        if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial_state must be {nx} finite numbers, got shape {x0.shape}")
    RUNS[settings.method].check_point(sys_, settings)
    tail = linear_tail(sys_, forcing)
    if tail.steady is None and settings.method == "event":
        # the forced free system is defective (a Jordan block): no eigen-decomposition, and
        # without impacts no steady state either
        return PointResult.failure(settings.method, (
            f"no steady state: undamped resonance (γ_r = {params.gamma_r:g} on a natural "
            "frequency with no damping); the event solver cannot propagate the secular growth"
        ))  # fmt: skip
    gaps = max(params.g1, params.g2)
    scale = max(tail.scale, float(np.max(np.abs(x0))), gaps if math.isfinite(gaps) else 0.0)

    def make_run():
        return RUNS[settings.method](sys_, settings, tail, forcing, DIVERGENCE_FACTOR * scale,
                                     **options)  # fmt: skip

    return run_point(make_run, sys_, tail, settings, x0, history_periods, limits, cancelled)


def simulate_chunk(
    points: Iterable[Mapping[str, Any]],
    solver: Mapping[str, Any] | None = None,
    limits: Mapping[str, Any] | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> list[dict[str, Any]]:
    """Run many points (one dask task). A point that fails is reported, never raised.

    Each point is a mapping of ``CellParams`` fields; ``solver`` holds ``SolverSettings``
    fields and ``limits`` ``PointLimits`` fields. Returns one ``PointResult.as_dict()`` per
    point, in order. When ``cancelled()`` turns true (checked between points and inside each
    point) the chunk stops and returns the records finished so far: fewer than the points.
    """
    settings = SolverSettings(**(solver or {}))
    budget = PointLimits(**(limits or {}))
    results: list[dict[str, Any]] = []
    for pt in points:
        if cancelled is not None and cancelled():
            break
        params: CellParams | None = None
        try:
            params = CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt})
            res = simulate_point(params, settings, limits=budget, cancelled=cancelled)
            results.append(res.as_dict())
        except PointCancelled:
            break
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            # a refused point of a valid cell still has its linear reference
            lin = linear_reference(params) if params is not None else None
            results.append(failed_result(settings, str(exc), lin))
    return results


def linear_reference(params: CellParams) -> float | None:
    """Γ_lin (dB): the closed-form transmittance of ``params``' cell with the stops removed
    (docs/model.md §7), or ``None`` where no closed form exists (undamped resonance)."""
    try:
        return linear_reference_db(steady_state(assemble(params)))
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return None


def point_history(
    point: Mapping[str, Any],
    solver: Mapping[str, Any],
    periods: int,
    limits: Mapping[str, Any] | None = None,
) -> PointResult:
    """One point of a study with ``periods`` periods of its time histories (one dask task:
    the service's ``/timeseries``). Raises ``ValueError`` for a point that cannot be run."""
    params = CellParams(**{k: point[k] for k in POINT_KEYS if k in point})
    return simulate_point(
        params, SolverSettings(**solver), history_periods=periods,
        limits=PointLimits(**(limits or {})),
    )  # fmt: skip


def failed_result(
    settings: SolverSettings, reason: str, linear_db: float | None = None
) -> dict[str, Any]:
    """The record of a point that could not be run (``linear_db``: its cell's Γ_lin, if any)."""
    spp = settings.steps_per_period or 0
    return PointResult.failure(settings.method, reason, linear_db, steps_per_period=spp).as_dict()


def _kernel(method: str):
    module, name = KERNELS[method].split(":")
    return getattr(importlib.import_module(module), name)


def kernels_cached(method: str) -> bool | None:
    """Whether the method's compiled kernel is in numba's on-disk cache (None: unknown)."""
    try:
        return bool(_kernel(method)._cache._cache_file._load_index())
    except Exception:  # numba internals: a missing attribute means we cannot tell
        return None


_warm: set[str] = set()  # methods whose kernels are compiled or loaded in this process


def warm_up(method: str | None = None, *, quiet: bool = False) -> None:
    """Compile (or load from numba's cache) a method's kernels once per process (default:
    every method), so no point's ``wall_s`` includes it. A first compilation on a machine says
    what it is doing and how long it usually takes; ``impactcell warmup`` does it ahead."""
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, modes=1)
    for m in METHODS if method is None else (method,):
        if m in _warm:
            continue
        _warm.add(m)
        cached = kernels_cached(m)
        if cached is False and not quiet:
            print(
                f"impactcell: compiling the numba kernels of method {m!r} (once per machine, "
                f"then cached; usually {COMPILE_SECONDS[m]} s) ...",
                file=sys.stderr, flush=True,
            )  # fmt: skip
        t0 = time.perf_counter()
        s = SolverSettings(method=m, steps_per_period=64, max_periods=3, window=1)
        # a point that impacts and a point that is linear at once: every kernel path compiles
        simulate_point(p, s, initial_state=np.r_[0.0, 0.0, 2.0, 0.0])
        if cached is False and not quiet:
            print(f"impactcell: {m!r} kernels ready in {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr, flush=True)  # fmt: skip
