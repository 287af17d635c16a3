"""The point engine: how a point ends, the same for every method (docs/solvers.md).

A point starts at its initial state (rest by default) and is advanced in batches of whole
periods by its method's kernel (``base.KernelRun``). It ends as soon as what it would report
is proven:

``linear``
    The linear tail test (``linear.py``) shows that the free motion from the current state can
    never reach a stop again: the steady state is the closed form, reported exactly.
``periodic``
    A period-p orbit with impacts. When the stroboscopic sequence converges geometrically
    (``measure.candidate``), the orbit is extrapolated from it (reduced rank extrapolation, the
    vector-extrapolation method of periodic-steady-state analysis in circuit simulators) and
    confirmed by integrating p periods from the extrapolated state: it must repeat to
    ``periodicity_tol`` (allowing for the estimated contraction), have the same impacts per
    period as the trajectory, and lie where the trajectory's own contraction is heading, so
    only an orbit reached from the point's start is reported. A sequence that repeats by
    itself (``measure.periodicity``) needs no extrapolation, once the repeat is shown not to be
    a shorter period still being approached (:func:`_divisors_steady`). An extrapolated orbit
    must also attract: its monodromy matrix (finite differences) has a spectral radius below 1, the
    reported Floquet multiplier; where the map is not smooth (no Jacobian) the orbit is
    reported only once the trajectory has reached it. The orbit is then measured over p
    periods; an orbit reached by itself gets its monodromy radius too where the map is smooth
    and the check at most triples the point's cost (``_measure_orbit``). Where no radius is
    computed, none is reported: no estimate stands in.
``irregular``
    Cycle-by-cycle statistics: Γ of the mean over periods of each period's half-range
    (max s − min s)/2; the initial transient is cut by the MSER rule; the point ends when the
    standard error of Γ (batch means, batches doubled until their means decorrelate) is below
    ``stat_tol_db`` over at least ``MIN_STATIONARY`` periods (or a quarter of a shorter budget),
    the batch means show no trend, and impacts are still happening in the last quarter of the
    final window. Where the error bar cannot be trusted (undamped, intermittent, almost
    periodic) the reason says so.
``unsettled``
    The period budget ran out first; the numbers are kept and labelled, never called irregular.
``failed``
    Not finite, diverged (``base.KernelRun.failure_reason``), no steady state (undamped), a
    method's own reason, or over the point's budget (``PointLimits``: wall time or steps);
    values are ``None``.

Every result also carries the linear reference ``transmittance_linear_db`` (Γ_lin: the closed
form of the same cell without stops, ``LinearTail.steady``) and ``impact_effect_db`` = Γ − Γ_lin
(exactly 0 for ``linear``; ``None`` where Γ or Γ_lin is missing). A ``failed`` point keeps Γ_lin.
An ``irregular`` point where that impact-free response is admissible too is flagged
``may_be_transient``, with ``impacting_periods``, the periods its impacting motion has lasted.

Every result that is not ``failed`` carries ``final_state``: the state at a period boundary
(forcing phase 0) of what it reports — the orbit's start, the closed-form steady state, or the
end of the run for ``irregular``/``unsettled`` — which a sweep line hands to its next point.

Between batches the engine checks the point's limits and the caller's ``cancelled`` callback
(``PointCancelled``). A batch is shortened when periods are slow, so both are seen well within
a second.

The engine by concern:

- ``loop.py``: the time loop, its batches, limits and cancel, the budget's end;
- ``orbits.py``: orbit search and proof (extrapolation, Newton, multipliers, pending orbits);
- ``irregular.py``: the irregular statistics and when a claim may rest on them;
- ``tail.py``: the linear tail proof as the engine uses it, and the linear reference;
- ``point.py``: :func:`run_point`, from a start to a ``PointResult``;
- ``config.py``: every tuning constant, what it trades and the test that pins it.
"""

from worker.solvers.engine.config import DIVERGENCE_FACTOR, HISTORY, MIN_WINDOWS, RECENT
from worker.solvers.engine.irregular import (
    UNTRUSTED_NOTE,
    SeriesStats,
    budget_for_error,
    few_batches_factor,
    mser_start,
    series_stats,
)
from worker.solvers.engine.loop import compile_helpers
from worker.solvers.engine.orbits import eigen_frame, rre
from worker.solvers.engine.point import run_point
from worker.solvers.engine.tail import linear_reference_db
from worker.solvers.settings import TRANSIENT_NOTE

__all__ = [
    "DIVERGENCE_FACTOR",
    "HISTORY",
    "MIN_WINDOWS",
    "RECENT",
    "TRANSIENT_NOTE",
    "UNTRUSTED_NOTE",
    "SeriesStats",
    "budget_for_error",
    "compile_helpers",
    "eigen_frame",
    "few_batches_factor",
    "linear_reference_db",
    "mser_start",
    "rre",
    "run_point",
    "series_stats",
]
