"""The public door of the worker: one point, a chunk of points, or a sweep line (one dask task).

``simulate_point`` validates, assembles the cell, prepares the method's kernel run
(``solvers.dispatch``) and hands it to the point engine (``solvers.engine``), which runs the
point to its proven end. ``simulate_chunk`` does that for many independent points and reports a
point that cannot be run as a failed record, never as an exception. ``simulate_line`` runs the
points of one sweep line in order, each starting from its predecessor's final state
(docs/solvers.md, "Initial states and sweep lines").
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import math
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from worker.compile_progress import compile_progress
from worker.initial import INITIAL_KINDS, initial_state, parse_initial, project_admissible
from worker.model import CellParams, assemble, steady_state
from worker.model.chain import ChainParams, assemble_chain, chain_linear_transmittance_db
from worker.numba_cache import exclusive, mark_done, marked_done, on_disk
from worker.observables import transmittance_db
from worker.solvers.chain_euler import ChainEulerRun, ChainSteppingRun, chain_tail, engine_view
from worker.solvers.chain_exponential import ChainExponentialRun
from worker.solvers.dispatch import KERNELS, RUNS
from worker.solvers.engine import compile_helpers, linear_reference_db, run_point
from worker.solvers.engine import config as engine_config
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
    "CHAIN_METHODS",
    "CHAIN_POINT_KEYS",
    "DEFAULT_METHOD",
    "EVENT_FIELDS",
    "HISTORY_FIELDS",
    "INITIAL_KINDS",
    "LCP_SOLVERS",
    "METHODS",
    "OUTCOMES",
    "POINT_KEYS",
    "SOLVER_VERSION",
    "PointCancelled",
    "PointLimits",
    "PointResult",
    "SolverSettings",
    "cache_ready",
    "failed_result",
    "fill_cache",
    "initial_state",
    "kernels_cached",
    "linear_reference",
    "parse_initial",
    "point_history",
    "project_admissible",
    "simulate_chain_point",
    "simulate_chunk",
    "simulate_line",
    "simulate_point",
    "warm_up",
]

POINT_KEYS = (
    "theta",
    "sigma",
    "gamma_s",
    "gamma_r",
    "xi",
    "g1",
    "g2",
    "modes",
    "coupling",
    "xi_b",
    "e1",
    "e2",
)
#: A chain point's keys besides ``POINT_KEYS`` (``chain_of``): N and the graded lists.
CHAIN_POINT_KEYS = ("cells", "cell_sigma", "cell_g1", "cell_g2")

#: The methods that run chains of N > 1 cells (docs/model.md §11), for now.
CHAIN_METHODS = ("euler", "exponential")
CHAIN_RUNS: dict[str, type[ChainSteppingRun]] = {
    "euler": ChainEulerRun,
    "exponential": ChainExponentialRun,
}

# How long a first compilation usually takes on a 2-core machine (measured; README).
COMPILE_SECONDS = {"event": "60–240", "exponential": "20–60", "euler": "40–120"}


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
        ``[u; q]`` at τ = 0 (default: rest), used as given: :func:`initial_state` and
        :func:`project_admissible` make admissible ones.
    forcing : bool
        Switch the base excitation off (energy checks).
    limits : PointLimits, optional
        Wall-time and step budget of the point (default ``PointLimits()``); a point over its
        budget is ``failed`` with that reason.
    cancelled : callable, optional
        Polled between batches of periods; when it returns true the point raises
        :class:`PointCancelled`.
    **options
        Method options: ``event_tol`` (``event``).

    Returns
    -------
    PointResult
        ``outcome`` says how the point ended; ``failed`` points carry a reason and ``None``
        values. ``final_state`` is the state at a period boundary of the reported response.

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
    x0 = _start(initial_state, nx)
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
        bound = engine_config.DIVERGENCE_FACTOR * scale
        return RUNS[settings.method](sys_, settings, tail, forcing, bound, **options)

    return run_point(make_run, sys_, tail, settings, x0, history_periods, limits, cancelled)


def _start(initial_state: np.ndarray | None, nx: int) -> np.ndarray:
    """The initial state as given (rest where None), checked: ``nx`` finite numbers."""
    if initial_state is None:
        return np.zeros(nx)
    x0 = np.asarray(initial_state, dtype=float)
    if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"initial_state must be {nx} finite numbers, got shape {x0.shape}")
    return x0


def simulate_chain_point(
    chain: ChainParams,
    settings: SolverSettings | None = None,
    *,
    history_periods: int = 0,
    initial_state: np.ndarray | None = None,
    limits: PointLimits | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> PointResult:
    """Simulate a chain of N cells (docs/model.md §11) to its proven end and measure its last
    cell.

    N = 1 is :func:`simulate_point` of the unit cell (the same result, bit for bit, with any
    method). For N > 1 only the methods of ``CHAIN_METHODS`` run: ``euler`` (the paper's scheme,
    with 2N contacts) and ``exponential`` (the chain's exact propagator with Moreau impulses).
    ``transmittance_db`` is Γ_N of the last cell's outer mass;
    ``transmittance_linear_db`` is Γ_N,lin of the chain's closed form; impacts are summed over
    the cells (stop 1, stop 2); the history's channels are the last cell's, its ``state`` the
    whole chain's. Other arguments as :func:`simulate_point` (``initial_state``: the chain's
    ``[u; q]``, 2N(n + 1) numbers).

    Raises
    ------
    ValueError
        A method that does not run chains, invalid settings or state, a pinned cell
        (g1 = g2 = 0), an unstable Euler step for the chain, or an exponential fine step that
        cannot resolve a cell's tip modes.
    """
    settings = settings or SolverSettings()
    if not isinstance(chain, ChainParams):
        raise ValueError(f"chain must be a ChainParams, got {type(chain).__name__}")
    if chain.n_cells == 1:
        return simulate_point(chain.cells[0], settings, history_periods=history_periods,
                              initial_state=initial_state, limits=limits,
                              cancelled=cancelled)  # fmt: skip
    if settings.method not in CHAIN_METHODS:
        raise ValueError(
            f"method {settings.method!r} does not run chains of n_cells > 1 yet; for chains "
            f"method must be one of {', '.join(CHAIN_METHODS)}"
        )
    elastic = [j + 1 for j, c in enumerate(chain.cells) if c.elastic]
    if elastic:
        raise ValueError(
            f"cells {elastic} have e1 or e2 > 0: chains of n_cells > 1 run plastic impacts "
            "only (e1 = e2 = 0)"
        )
    history_periods = int_in("history_periods", history_periods, 0, 100_000)
    cs = assemble_chain(chain)
    nx = 2 * cs.ndof
    x0 = _start(initial_state, nx)
    run_class = CHAIN_RUNS[settings.method]
    run_class.check_point(cs, settings)
    tail = chain_tail(cs)
    gaps = max(max(p.g1, p.g2) for p in chain.cells)
    scale = max(tail.scale, float(np.max(np.abs(x0))), gaps if math.isfinite(gaps) else 0.0)

    def make_run() -> ChainSteppingRun:
        bound = engine_config.DIVERGENCE_FACTOR * scale
        return run_class(cs, settings, tail, True, bound)

    # the engine sees the chain through its last cell (γ_r, θ, base scale, κ) and the chain's
    # tail (a duck-typed LinearTail: Γ_N,lin, the per-cell proof)
    res = run_point(make_run, engine_view(cs), tail, settings, x0,  # type: ignore[arg-type]
                    history_periods, limits, cancelled)  # fmt: skip
    return _with_cells(res, chain, make_run)


def _with_cells(
    res: PointResult, chain: ChainParams, make_run: Callable[[], ChainSteppingRun]
) -> PointResult:
    """``res`` with its chain fields: N, Γ_j,lin and the proven Γ_j of every cell (the closed
    form at a linear point, the orbit's p periods run again at a periodic one)."""
    res.cells = chain.n_cells
    # the chain's impact observables are not reported (its kernels sum them over the cells)
    res.contact_fraction = res.contact_fraction_se = res.impact_velocity = None
    res.impacts_per_period_se = res.impact_velocity_se = None
    res.impact_energy = res.impact_energy_se = res.impact_energy_share = None
    lin = cell_linear_db(chain)
    res.cell_transmittance_linear_db = lin
    if res.outcome == "linear":
        res.cell_transmittance_db = lin  # type: ignore[assignment]
    elif res.outcome == "periodic" and res.final_state is not None:
        half = make_run().cell_ranges(res.final_state, res.response_period)
        scale = chain.cell.base_scale
        res.cell_transmittance_db = [transmittance_db(float(a), scale) for a in half]
    return res


def simulate_chunk(
    points: Iterable[Mapping[str, Any]],
    solver: Mapping[str, Any] | None = None,
    limits: Mapping[str, Any] | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> list[dict[str, Any]]:
    """Run many points (one dask task). A point that fails is reported, never raised.

    Each point is a mapping of ``CellParams`` fields and optionally ``"initial"`` (the start:
    ``{"kind": "rest"|"linear"|"random", "seed": …, "index": …}``, see :func:`initial_state`;
    absent means rest); ``solver`` holds ``SolverSettings`` fields and ``limits``
    ``PointLimits`` fields. Returns one ``PointResult.as_dict()`` per point, in order. When
    ``cancelled()`` turns true (checked between points and inside each point) the chunk stops
    and returns the records finished so far: fewer than the points.
    """
    settings = SolverSettings(**(solver or {}))
    budget = PointLimits(**(limits or {}))
    results: list[dict[str, Any]] = []
    for pt in points:
        if cancelled is not None and cancelled():
            break
        try:
            results.append(_run_point(pt, settings, budget, cancelled)[0])
        except PointCancelled:
            break
    return results


def simulate_line(
    points: Iterable[Mapping[str, Any]],
    solver: Mapping[str, Any] | None = None,
    limits: Mapping[str, Any] | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> list[dict[str, Any]]:
    """Run one sweep line (one dask task): the points in sweep order, each from the last one's
    final state.

    The first point starts from its ``"initial"`` (default rest); each next one from the
    previous point's ``final_state`` (a period boundary of its reported response), projected
    onto its own admissible set (the gaps may change along the line). After a failed point, or
    where the state sizes differ (a sweep over ``modes``), the next point starts from its own
    ``"initial"`` again. Every record is ``PointResult.as_dict()`` plus ``"started_from"``:
    ``"initial"`` or ``"previous"`` (only records of lines carry it). Failures, limits and
    cancelling as :func:`simulate_chunk`.
    """
    settings = SolverSettings(**(solver or {}))
    budget = PointLimits(**(limits or {}))
    results: list[dict[str, Any]] = []
    previous: np.ndarray | None = None
    for pt in points:
        if cancelled is not None and cancelled():
            break
        try:
            record, previous = _run_point(pt, settings, budget, cancelled, previous, line=True)
        except PointCancelled:
            break
        results.append(record)
    return results


def _run_point(
    pt: Mapping[str, Any],
    settings: SolverSettings,
    budget: PointLimits,
    cancelled: Callable[[], bool] | None,
    previous: np.ndarray | None = None,
    line: bool = False,
) -> tuple[dict[str, Any], np.ndarray | None]:
    """One point's record and final state, from ``previous`` (a sweep line's hand-over) or
    from the point's own ``"initial"``; ``line`` adds ``started_from`` to the record. A point
    that cannot be run is a failed record (final state ``None``); a cancel is raised."""
    params: CellParams | None = None
    started = "initial"
    if "cells" in pt:
        return _run_chain_point(pt, settings, budget, cancelled, line), None
    try:
        params = CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt})
        parse_initial(pt.get("initial"))  # a bad entry fails its point, used or not
        x0: np.ndarray | None = None
        if previous is not None and previous.shape == (2 * (params.modes + 1),):
            x0 = project_admissible(assemble(params), previous)
            started = "previous"
        elif pt.get("initial") is not None:
            x0 = initial_state(params, pt["initial"])
        # no "initial": x0 stays None, today's rest start bit for bit
        res = simulate_point(params, settings, initial_state=x0, limits=budget,
                             cancelled=cancelled)  # fmt: skip
        record, final = res.as_dict(), res.final_state
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        # a refused point of a valid cell still has its linear reference
        lin = linear_reference(params) if params is not None else None
        record, final = failed_result(settings, str(exc), lin), None
    if line:
        record["started_from"] = started
    return record, final


def chain_of(pt: Mapping[str, Any]) -> ChainParams:
    """The chain of a point dict with ``cells`` (``CHAIN_POINT_KEYS``): its cell from the
    ``CellParams`` keys, per-cell lists from ``cell_sigma``, ``cell_g1``, ``cell_g2``."""
    cell = CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt})
    return ChainParams(cell, pt["cells"], sigma=pt.get("cell_sigma"), g1=pt.get("cell_g1"),
                       g2=pt.get("cell_g2"))  # fmt: skip


def _run_chain_point(
    pt: Mapping[str, Any],
    settings: SolverSettings,
    budget: PointLimits,
    cancelled: Callable[[], bool] | None,
    line: bool,
) -> dict[str, Any]:
    """A chain point's record (a chain starts from rest; a sweep line's hand-over is the unit
    cell's); a point that cannot be run is a failed record with the chain's fields."""
    chain: ChainParams | None = None
    try:
        chain = chain_of(pt)
        if parse_initial(pt.get("initial"))[0] != "rest":
            raise ValueError(f"a chain of cells starts from rest, got initial {pt['initial']!r}")
        record = simulate_chain_point(chain, settings, limits=budget,
                                      cancelled=cancelled).as_dict()  # fmt: skip
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        lin = cell_linear_db(chain) if chain is not None else None
        record = failed_result(settings, str(exc), lin[-1] if lin else None)
        record.update(cells=pt.get("cells"), cell_transmittance_db=None,
                      cell_transmittance_linear_db=lin)  # fmt: skip
    if line:
        record["started_from"] = "initial"
    return record


def cell_linear_db(chain: ChainParams) -> list[float | None]:
    """Γ_j,lin of every cell of ``chain`` (cell 1 first), all ``None`` where no closed form
    exists (an undamped resonance)."""
    try:
        return [float(v) for v in chain_linear_transmittance_db(chain)]
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return [None] * chain.n_cells


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
    the service's ``/timeseries``). The point starts from its ``"initial"`` (default rest),
    not from a sweep line's predecessor. Raises ``ValueError`` for a point that cannot be run."""
    params = CellParams(**{k: point[k] for k in POINT_KEYS if k in point})
    init = point.get("initial")
    return simulate_point(
        params, SolverSettings(**solver), history_periods=periods,
        initial_state=None if init is None else initial_state(params, init),
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
    return on_disk(_kernel(method))


_warm: set[str] = set()  # methods whose kernels are compiled or loaded in this process


def _warm_mark(method: str) -> str:
    """The name of the cache's mark of a finished warm-up of ``method``."""
    return f"warm-{method}"


def cache_ready(method: str | None = None) -> bool:
    """Whether a :func:`warm_up` of ``method`` (default: every method) finished with these
    sources, so numba's on-disk cache holds everything a point compiles: a process starting
    workers need not load anything itself, and its workers load it as they start."""
    return all(
        marked_done(_warm_mark(m)) and kernels_cached(m)
        for m in (METHODS if method is None else (method,))
    )


def fill_cache(method: str | None = None) -> None:
    """Compile ``method``'s code into numba's on-disk cache unless it is there: what a process
    that hands points to local workers does before they load it (no worker compiles)."""
    if not cache_ready(method):
        warm_up(method)


def warm_up(method: str | None = None, *, quiet: bool = False) -> None:
    """Compile (or load from numba's cache) a method's kernels once per process (default:
    every method), so no point's ``wall_s`` includes it. A first compilation on a machine says
    what it is doing and how long it usually takes; ``impactcell warmup`` does it ahead."""
    for m in METHODS if method is None else (method,):
        if m in _warm:
            continue
        _warm.add(m)
        if cache_ready(m):
            _warm_one(m, False, quiet)
            continue
        # Processes sharing the cache (an API and a CLI run, test workers) compile a method one
        # at a time; the later ones load what the first wrote.
        with exclusive(_warm_mark(m), None if quiet else functools.partial(_say_waiting, m)):
            _warm_one(m, kernels_cached(m) is False, quiet)


def _say_waiting(method: str) -> None:
    print(f"impactcell: another process is compiling method {method!r} into the same cache; "
          "waiting to load it from there ...", file=sys.stderr, flush=True)  # fmt: skip


def _warm_one(method: str, compiling: bool, quiet: bool) -> None:
    """Run the points that compile (or load) every kernel of ``method``; mark the cache."""
    if compiling and not quiet:
        print(
            f"impactcell: compiling the numba kernels of method {method!r} (once per machine, "
            f"then cached; usually {COMPILE_SECONDS[method]} s) ...",
            file=sys.stderr, flush=True,
        )  # fmt: skip
    t0 = time.perf_counter()
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, modes=1)
    s = SolverSettings(method=method, steps_per_period=64, max_periods=3, window=1)
    talk = compile_progress(method) if compiling and not quiet else contextlib.nullcontext()
    with talk:
        # a point that impacts and a point that is linear at once: every kernel path compiles
        simulate_point(p, s, initial_state=np.r_[0.0, 0.0, 2.0, 0.0])
        if method in CHAIN_METHODS:  # the chain's kernel (two cells), its first tip struck
            struck = np.r_[np.zeros(4), 2.0, np.zeros(3)]
            simulate_chain_point(ChainParams(p, 2), s, initial_state=struck)
        compile_helpers()  # what only longer points reach (extrapolated orbits), if not cached
        RUNS[method].compile_helpers()  # the method's own (event: the exact monodromy matrix)
    mark_done(_warm_mark(method))
    if compiling and not quiet:
        print(f"impactcell: {method!r} kernels ready in {time.perf_counter() - t0:.0f} s",
              file=sys.stderr, flush=True)  # fmt: skip
