"""What a run of a study did (``RunSummary``), and how a run is stopped (``Cancelled``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Cancelled", "RunSummary"]


class Cancelled(Exception):
    """Raised inside the runner when its ``cancel`` callback says stop."""


@dataclass
class RunSummary:
    """What a run did."""

    study_id: str
    path: Path
    points: int
    computed: int  # points computed by this run
    reused: int  # points not computed now: from the point store or an interrupted run's chunks
    failed: int
    irregular: int  # outcome irregular: converged statistics of a non-periodic response
    unsettled: int  # outcome unsettled: the period budget ran out before the point ended
    wall_s: float
    kernel_s: float  # sum of per-point kernel times of the points computed now
    workers: int
    chunk_size: int
    cached: bool = False  # the results file already existed
    cancelled: bool = False  # stopped on request: finished chunks kept, no results file yet
    # points by outcome (linear, periodic, irregular, unsettled, failed); empty when unknown
    outcomes: dict[str, int] = field(default_factory=dict)
