"""Request and response schemas of the REST API (one module, shared by every route)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from service.api.catalogue import STATUSES

__all__ = [
    "ErrorOut",
    "Health",
    "Problem",
    "RegressionList",
    "RegressionOut",
    "StudyList",
    "StudyOut",
]

Status = Literal[STATUSES]  # type: ignore[valid-type]


class Problem(BaseModel):
    """One problem of a request, with the path of the offending field."""

    path: str
    message: str


class ErrorOut(BaseModel):
    """Every error response: a message, and the problems when there are several."""

    detail: str
    problems: list[Problem] | None = None


class FailedPoint(BaseModel):
    """A point that could not be computed."""

    index: int
    coords: dict[str, float]
    reason: str


class StudyOut(BaseModel):
    """A study in the catalogue: status, progress, timings, failures."""

    id: str
    name: str
    status: Status
    definition: dict[str, Any] | None = Field(
        description="the canonical definition (null in lists unless full=true)"
    )
    points_total: int
    points_done: int
    points_failed: int
    points_irregular: int = Field(description="points whose outcome is irregular")
    points_unsettled: int = Field(
        description="points whose outcome is unsettled (the period budget ran out first)"
    )
    points_computed: int = Field(
        0, description="points its last run computed (0 until it finishes)"
    )
    points_reused: int = Field(
        0,
        description="points its last run did not compute: taken from the point store (known "
        "from other studies) or from an interrupted run's chunks (0 until it finishes)",
    )
    progress: float = Field(description="points_done / points_total, 0…1")
    submitted_at: str
    started_at: str | None
    finished_at: str | None
    wall_s: float | None = Field(
        description="running time in seconds, summed over every run of the study"
    )
    error: str | None
    failures: list[FailedPoint] = Field(description="a sample of failed points (at most 20)")
    queue_position: int | None = Field(
        None, description="1-based place in the queue (queued studies only)"
    )
    rate_points_per_s: float | None = Field(
        None, description="points per second over the study's running time (running only)"
    )
    eta_s: float | None = Field(
        None, description="seconds left at that rate (running studies only)"
    )
    hint: str | None = Field(None, description="what to do next (cancelled or failed studies)")
    links: dict[str, str]


class StudyList(BaseModel):
    """A page of studies, newest first."""

    items: list[StudyOut]
    total: int
    limit: int
    offset: int


class RegressionOut(BaseModel):
    """A nightly regression run."""

    id: int
    started_at: str
    finished_at: str | None
    ok: bool | None
    trigger: str
    summary: str
    error: str | None
    report: dict[str, Any] | None = None
    markdown: str | None = None


class RegressionList(BaseModel):
    """A page of regression runs, newest first."""

    items: list[RegressionOut]
    total: int
    limit: int
    offset: int


class Health(BaseModel):
    """Liveness, versions, queue and the latest nightly result."""

    status: Literal["ok"]
    version: str
    solver_version: str
    studies: dict[str, int]
    nightly_cron: str | None
    nightly: RegressionOut | None
