"""Solver settings, the outcomes a point can end with, and the result record of one point."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from worker.checks import check_fields, integer
from worker.limits import POINT_STEPS, POINT_STEPS_MAX, POINT_WALL_S, POINT_WALL_S_MAX

__all__ = [
    "CHAIN_FIELDS",
    "DEFAULT_METHOD",
    "LCP_SOLVERS",
    "PER_STOP",
    "MAX_EVENTS_PER_PERIOD",
    "MAX_STEPS_PER_PERIOD",
    "METHODS",
    "OUTCOMES",
    "SOLVER_VERSION",
    "OVER_STEPS",
    "OVER_TIME",
    "PointCancelled",
    "PointLimits",
    "PointResult",
    "SolverSettings",
    "TRANSIENT_NOTE",
    "int_in",
]

# Bumped whenever the numbers a point reports may change: it is part of every study id.
SOLVER_VERSION = "24"
METHODS = ("event", "exponential", "euler")
DEFAULT_METHOD = "event"
LCP_SOLVERS = ("closed", "lemke")
MAX_STEPS_PER_PERIOD = 10_000_000
MAX_EVENTS_PER_PERIOD = 10**9  # the widest event budget a point may be given

#: How a point ended (docs/solvers.md, "How a point ends"). The order is the CF flag order.
OUTCOMES = ("linear", "periodic", "irregular", "unsettled", "failed")


def int_in(name: str, value: Any, lo: int, hi: int) -> int:
    """``value`` as an int in ``lo…hi``, or a ``ValueError`` naming the field."""
    return integer(name, value, lo, hi)


#: How the reason of a point over its ``PointLimits`` begins (the rest says by how much).
OVER_TIME = "time limit of "
OVER_STEPS = "step budget of "
#: The end of the reason of an irregular point flagged ``may_be_transient`` (the engine's note
#: for a human reader; programs read the flag).
TRANSIENT_NOTE = "this irregular motion may be transient"


@dataclass(frozen=True)
class PointLimits:
    """How much one point may cost before it is given up (``failed`` with the reason).

    Execution limits, not physics: they are not part of a study's definition or id. A point
    that reaches one is reported ``failed`` ("time limit …" / "step budget …"), so one
    pathological point can never hold a worker for longer than ``wall_s``.

    Parameters
    ----------
    wall_s : float
        Wall-clock seconds one point may run (checked between batches of periods; a batch is
        shortened when periods are slow, so the limit holds to well under a second).
    steps : int
        Time steps (events for ``event``) one point may take.
    """

    wall_s: float = field(default=POINT_WALL_S, metadata={"gt": 0.0, "le": POINT_WALL_S_MAX})
    steps: int = field(
        default=POINT_STEPS, metadata={"integer": True, "ge": 1, "le": POINT_STEPS_MAX}
    )

    def __post_init__(self) -> None:
        check_fields(self)


class PointCancelled(Exception):
    """The caller asked a running point to stop (its chunk's study was cancelled)."""


@dataclass(frozen=True)
class SolverSettings:
    """How a point is integrated and how it ends.

    Parameters
    ----------
    method : {"event", "exponential", "euler"}
        The event-driven solver (default: free flight and the stuck phases exact, impacts and
        releases located to ``1e-12`` of a period), the exact propagator with Moreau impulses in
        fine steps near the stops, or the paper's semi-implicit Euler scheme.
    steps_per_period : int or None
        ``event``: sub-grid intervals per period for bracketing events (default 64; sets the
        cost, not the answer). ``exponential``: fine steps per period near the stops (default
        2048; refined where the fine step would not resolve the lowest mode). ``euler``: time
        steps per period (default 1024 or enough for Δτ·ω̃_max <= 1).
    coarse_steps : int
        ``exponential`` only: free-flight steps per period.
    max_periods : int
        Period budget. A point that has not ended by then is ``unsettled``.
    periodicity_tol : float
        Relative tolerance of a periodic orbit: the confirmed orbit repeats, and its estimated
        distance to the exact orbit is below this fraction of the state's size.
    window : int
        Periods per window: an irregular response's statistics are checked at each window's
        end, and its impacts per period are those of the final window. Its Γ, the cycle-by-cycle
        mean over periods, does not depend on it (docs/solvers.md).
    stat_tol_db : float
        Standard error of Γ (dB) at which the statistics of an irregular response count as
        converged.
    near_margin : float
        ``exponential`` only: its cheap no-contact test keeps this fraction of a gap clear
        (``event``'s cheap test is a rigorous bound and needs no margin).
    adaptive : bool
        ``exponential`` only: whole coarse steps in free flight (off: fine steps everywhere).
    early_stop : bool
        End a point as soon as its outcome is proven (off: run the whole budget, then classify).
    extrapolate : bool
        Accelerate convergence to a periodic orbit by vector extrapolation of the stroboscopic
        sequence (every accepted orbit is confirmed by integration either way).
    linear_tail : bool
        Prove impact-free tails and report the closed-form steady state (``linear``). Off:
        integrate them like any other response (to check a method against the closed form).
    lcp : {"closed", "lemke"}
        ``euler`` only: the two-stop LCP of each step in closed form or by Lemke's algorithm.
    max_events_per_period : int or None
        ``event`` only: the events (impacts, releases) one period may hold before the run ends
        ``failed`` as chattering (default 1000). Large-θ cells at low γ_r can have hundreds of
        real impacts a period; raising it lets them run, at about 10 µs an event.
    transient_guard : int or None
        The earliest period at which an irregular response may be claimed where the
        impact-free response is admissible too (its reason then says the motion may be
        transient: such chaos can die out after hundreds of periods). Default: a quarter of
        ``max_periods``, as for every irregular claim; at most ``max_periods`` (then such a
        claim waits for the budget's end). It moves no other claim, so it costs far less
        than a longer budget for all (docs/accuracy.md, "Irregular points").
    """

    method: str = field(default=DEFAULT_METHOD, metadata={"choices": METHODS})
    steps_per_period: int | None = field(
        default=None,
        metadata={"integer": True, "ge": 4, "le": MAX_STEPS_PER_PERIOD, "optional": True},
    )
    coarse_steps: int = field(default=64, metadata={"integer": True, "ge": 4, "le": 1 << 20})
    max_periods: int = field(default=1000, metadata={"integer": True, "ge": 2, "le": 10**7})
    periodicity_tol: float = field(default=1e-9, metadata={"gt": 0.0, "lt": 1e-2})
    window: int = field(default=20, metadata={"integer": True, "ge": 1, "le": 10**7})
    stat_tol_db: float = field(default=0.1, metadata={"gt": 0.0, "lt": 100.0})
    near_margin: float = field(default=0.1, metadata={"ge": 0.0, "lt": 1.0})
    adaptive: bool = field(default=True, metadata={"boolean": True})
    early_stop: bool = field(default=True, metadata={"boolean": True})
    extrapolate: bool = field(default=True, metadata={"boolean": True})
    linear_tail: bool = field(default=True, metadata={"boolean": True})
    lcp: str = field(default="closed", metadata={"choices": LCP_SOLVERS})
    max_events_per_period: int | None = field(
        default=None,
        metadata={"integer": True, "ge": 1, "le": MAX_EVENTS_PER_PERIOD, "optional": True},
    )
    transient_guard: int | None = field(
        default=None, metadata={"integer": True, "ge": 0, "le": 10**7, "optional": True}
    )

    def __post_init__(self) -> None:
        check_fields(self)  # every field's range is its metadata above
        if self.window >= self.max_periods:
            raise ValueError(
                f"window must be < max_periods ({self.max_periods}), got {self.window}"
            )
        if self.max_events_per_period is not None and self.method != "event":
            # the time-stepping methods count no events: a budget there would do nothing
            raise ValueError(
                f"max_events_per_period applies to method 'event' only, got method {self.method!r}"
            )
        if self.transient_guard is not None and self.transient_guard > self.max_periods:
            raise ValueError(
                f"transient_guard must be <= max_periods ({self.max_periods}): a claim cannot "
                f"wait past the budget; got {self.transient_guard}"
            )


# PointResult fields kept out of records (arrays: records stay JSON-able and column-able)
_NOT_IN_RECORD = ("history", "final_state")
#: A result's fields with one value per stop (stop 1, stop 2): lists in a record, and the
#: study variables along ``stop`` (``service.studies.variables.STOP_VARIABLES``).
PER_STOP = (
    "impacts_per_period",
    "impacts_per_period_se",
    "contact_fraction",
    "contact_fraction_se",
    "impact_velocity",
    "impact_velocity_se",
    "impact_energy",
    "impact_energy_se",
)
#: A chain's fields of a result (absent from a unit cell's record).
CHAIN_FIELDS = ("cells", "cell_transmittance_db", "cell_transmittance_linear_db")


@dataclass
class PointResult:
    """What one point reports (docs/model.md, "What a point reports").

    Measured values are ``None`` when the point failed. ``outcome`` says how the point ended
    and what its numbers are: ``linear`` (the closed-form steady state, proven impact-free for
    all future time), ``periodic`` (a confirmed period-``response_period`` orbit with impacts),
    ``irregular`` (per-period statistics converged: Γ is that of the mean half-range per
    excitation period, with standard error ``transmittance_db_se``), ``unsettled`` (the
    budget ran out first; numbers kept, not proven) or ``failed`` (``reason`` says why).

    ``transmittance_linear_db`` is Γ_lin, the closed-form Γ of the same cell with the stops
    removed (docs/model.md §7), and ``impact_effect_db`` = Γ − Γ_lin, what the impacts change
    (exactly 0 for a ``linear`` point). Both are ``None`` where no closed form exists (an
    undamped resonance). Γ_lin is a property of the cell, not a measurement, so a ``failed``
    point keeps it when it exists; its ``impact_effect_db`` is ``None``.

    ``may_be_transient`` flags an ``irregular`` point where the impact-free response is
    admissible too (damped, its tip clear of the stops): the impacting motion may be transient
    chaos that dies out into that response, whose Γ is ``transmittance_linear_db``, so its Γ is
    not a settled value. ``impacting_periods`` is how long that motion has lasted: the periods
    of the main trajectory from the point's start to the claim, with impacts in the last quarter
    of its final window (``None`` where the flag is not set).

    A chain of N > 1 cells (``worker.simulate.simulate_chain_point``) adds ``cells`` (N),
    ``cell_transmittance_linear_db`` (Γ_j,lin of every cell, cell 1 first) and
    ``cell_transmittance_db`` (Γ_j measured at every cell: exact over the orbit of a
    ``periodic`` point, the closed form at a ``linear`` one; ``None`` for irregular, unsettled
    and failed points, whose per-cell values are not proven). The unit cell leaves them
    ``None`` and its record without them.

    ``contact_fraction`` is the fraction of the period the tip spends on stop 1 and stop 2
    (the event method: stuck on it; time stepping: the steps whose impulse holds it there),
    exact over the orbit of a periodic point, 0 at a linear one, and at an irregular or
    unsettled point the mean over the stationary span's windows with its
    standard error ``contact_fraction_se`` (windows as batches). ``impacts_per_period`` is
    likewise exact over the orbit or the windows' mean, with ``impacts_per_period_se``.
    ``impact_velocity`` is the mean approach velocity of the impacts counted at each stop
    (``None`` where a stop had none), with ``impact_velocity_se`` at an irregular or unsettled
    point (the ratio estimator's, windows as batches).
    ``impact_energy`` is the energy the impulses at each stop take per excitation period,
    Σ ½(v⁻² − v⁺²)/G (exact over the orbit, 0 at a linear point, the windows' mean with
    standard error ``impact_energy_se`` at an irregular or unsettled one), and
    ``impact_energy_share`` their share of all the energy dissipated, the forcing's work
    (``full`` coupling only: ``None`` in ``paper``, which has no energy balance).
    Chains leave them ``None``.

    ``final_state`` is ``[u; q]`` at a period boundary (forcing phase 0) of the reported
    response, what a sweep line hands to its next point: the orbit's start (``periodic``), the
    closed-form steady state (``linear``), the state at the end of the run (``irregular``,
    ``unsettled``); ``None`` for ``failed``. Like ``history`` it is not in :meth:`as_dict`.
    """

    outcome: str
    transmittance_db: float | None
    transmittance_db_se: float | None
    amplitude: float | None
    theta_eff: float | None
    theta_eff_slope: float | None
    response_period: int
    impacts_per_period: tuple[float, float] | None
    peak_impulse: float | None
    floquet_multiplier: float | None
    periods: int
    steps: int
    contact_steps: int
    coarse_steps: int
    steady_period: int
    wall_s: float
    reason: str
    method: str
    steps_per_period: int
    transmittance_linear_db: float | None = None
    impact_effect_db: float | None = None
    may_be_transient: bool = False
    impacting_periods: int | None = None
    impacts_per_period_se: tuple[float, float] | None = None
    contact_fraction: tuple[float, float] | None = None
    contact_fraction_se: tuple[float, float] | None = None
    impact_velocity: tuple[float | None, float | None] | None = None
    impact_velocity_se: tuple[float | None, float | None] | None = None
    impact_energy: tuple[float, float] | None = None
    impact_energy_se: tuple[float, float] | None = None
    impact_energy_share: float | None = None
    cells: int | None = None
    cell_transmittance_db: list[float] | None = None
    cell_transmittance_linear_db: list[float | None] | None = None
    history: dict[str, np.ndarray] | None = field(default=None, repr=False)
    final_state: np.ndarray | None = field(default=None, repr=False)

    @property
    def failed(self) -> bool:
        """Whether the point failed (its measured values are ``None``)."""
        return self.outcome == "failed"

    @property
    def converged(self) -> bool:
        """Whether the point reached a proven steady state (``linear`` or ``periodic``)."""
        return self.outcome in ("linear", "periodic")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict (no history, no final state); ``failed`` is included for the
        record's readers."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in _NOT_IN_RECORD}
        if self.cells is None:
            for name in CHAIN_FIELDS:
                del out[name]  # a unit cell's record is what it always was
        for name in PER_STOP:
            if out[name] is not None:
                out[name] = list(out[name])
        out["failed"] = self.failed
        return out

    @classmethod
    def failure(
        cls, method: str, reason: str, linear_db: float | None = None, **counts: Any
    ) -> PointResult:
        """The record of a point that failed (or could not be run) with ``reason``; ``counts``
        may give the work done (``periods``, ``steps``, …, ``steps_per_period``) and
        ``linear_db`` the cell's linear reference Γ_lin (kept: it is not a measurement)."""
        work = dict(periods=0, steps=0, contact_steps=0, coarse_steps=0, steady_period=-1,
                    wall_s=0.0, steps_per_period=0)  # fmt: skip
        work.update({k: v for k, v in counts.items() if k in work})
        return cls(
            outcome="failed", transmittance_db=None, transmittance_db_se=None, amplitude=None,
            theta_eff=None, theta_eff_slope=None, response_period=0, impacts_per_period=None,
            peak_impulse=None, floquet_multiplier=None, reason=reason, method=method, **work,
            transmittance_linear_db=linear_db, impact_effect_db=None,
        )  # fmt: skip
