"""``/studies``: submit, list, inspect, cancel and resume studies."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from service.api.catalogue import RUNNING, STATUSES
from service.api.deps import CatalogueDep, JobsDep, SettingsDep, StudyId, study_or_404
from service.api.guard import hide_paths
from service.api.jobs import StateError
from service.api.schemas import ErrorOut, StudyList, StudyOut
from service.studies.files import StudyFileError, parse_study_text
from service.studies.schema import StudyError, parse_study

router = APIRouter(prefix="/studies", tags=["studies"])

_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorOut, "description": "missing or wrong bearer token"},
    404: {"model": ErrorOut, "description": "no such study"},
}
_YAML_TYPES = ("application/yaml", "application/x-yaml", "text/yaml", "text/x-yaml")


def study_out(rec: dict[str, Any], positions: dict[str, int] | None = None) -> dict[str, Any]:
    """A catalogue record with progress, queue position, rate, ETA, a hint and links.

    ``positions``: the queue positions (``Catalogue.queue_positions``), read once per request.
    """
    base = f"/studies/{rec['id']}"
    total, done, wall = rec["points_total"], rec["points_done"], rec["wall_s"]
    running = rec["status"] in RUNNING
    # The rate over every run of the study (its running time, resumed runs included).
    rate = done / wall if running and wall and done else None
    out = {
        **rec,
        "error": hide_paths(rec.get("error")),  # an OSError names a file of the data dir
        "progress": 1.0 if total == 0 else min(1.0, done / total),
        "queue_position": (positions or {}).get(rec["id"]) if rec["status"] == "queued" else None,
        "rate_points_per_s": rate,
        "eta_s": (total - done) / rate if rate else None,
        "hint": _HINTS.get(rec["status"], "").format(id=rec["id"]) or None,
        "links": {
            "self": base,
            "dataset": f"{base}/dataset",
            "data": f"{base}/data",
            "bandgap": f"{base}/bandgap",
            "plots": f"{base}/plots/transmittance.png",
        },
    }
    d = rec.get("definition") or {}
    if d.get("sweep") or d.get("initial"):  # only where there is a hysteresis to show
        out["links"]["hysteresis"] = f"{base}/hysteresis"
        out["links"]["hysteresis_plot"] = f"{base}/plots/hysteresis.png"
    return out


_HINTS = {
    "waiting": (
        "waiting (see error): the catalogue database or the disk is away; its finished work is "
        "kept and it goes on by itself when they are back"
    ),
    "cancelled": (
        "cancelled: POST /studies/{id}/resume (or submit it again with ?resume=true) continues "
        "from its finished chunks"
    ),
    "failed": (
        "failed (see error): POST /studies/{id}/resume (or submit it again with ?resume=true) "
        "tries again from its finished chunks"
    ),
}


def _parse_body(raw: bytes, content_type: str) -> Any:
    kind = content_type.split(";")[0].strip().lower()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise HTTPException(400, "request body is not UTF-8 text") from None
    if kind in _YAML_TYPES:
        fmt = "yaml"
    elif kind in ("application/json", ""):
        fmt = "json"
    else:
        raise HTTPException(
            415, f"Content-Type {kind!r} is not accepted; use application/json or "
            "application/yaml"
        )  # fmt: skip
    try:
        return parse_study_text(text, fmt)
    except StudyFileError as exc:  # "not valid YAML: ..." / "nested more than 32 levels ..."
        raise HTTPException(400, f"request body is {exc}") from None


@router.post(
    "",
    status_code=202,
    response_model=StudyOut,
    responses={
        200: {"model": StudyOut, "description": "an identical study exists: it is returned"},
        400: {"model": ErrorOut, "description": "body is not JSON/YAML"},
        401: _ERRORS[401],
        413: {"model": ErrorOut, "description": "body too large"},
        415: {"model": ErrorOut, "description": "unsupported content type"},
        422: {"model": ErrorOut, "description": "invalid study (every problem, with its path)"},
    },
    openapi_extra={
        "requestBody": {
            "required": True,
            "description": "a study definition (the study file format), JSON or YAML",
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "application/yaml": {"schema": {"type": "string"}},
            },
        }
    },
)
async def submit_study(
    request: Request,
    response: Response,
    settings: SettingsDep,
    jobs: JobsDep,
    resume: Annotated[
        bool, Query(description="queue an identical cancelled or failed study again")
    ] = False,
) -> dict[str, Any]:
    """Submit a study; an identical definition returns the existing study (no second run),
    or with ``resume=true`` queues it again if it was cancelled or failed."""
    # Decoding, parsing and validating a body of up to max_body_bytes takes CPU time: in a
    # worker thread, so that the event loop (and /health) keeps answering meanwhile.
    body = await request.body()
    data = await run_in_threadpool(_parse_body, body, request.headers.get("content-type", ""))
    if not isinstance(data, dict):
        raise HTTPException(422, "a study definition must be a mapping of keys to values")
    try:
        study = await run_in_threadpool(
            parse_study, data, max_points=settings.max_points, source="body"
        )
    except StudyError as exc:
        problems = [{"path": p or "(root)", "message": m} for p, m in exc.problems]
        raise HTTPException(422, {"detail": str(exc), "problems": problems}) from None
    # the catalogue is a blocking database: off the event loop too
    rec, created = await run_in_threadpool(jobs.submit, study, resume=resume)
    response.status_code = 202 if created else 200
    response.headers["Location"] = f"/studies/{rec['id']}"
    return study_out(rec)


@router.get("", response_model=StudyList, responses={401: _ERRORS[401]})
def list_studies(
    catalogue: CatalogueDep,
    status: Annotated[str | None, Query(description="|".join(STATUSES))] = None,
    name: Annotated[str | None, Query(max_length=200, description="substring of the name")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=2**31)] = 0,
    full: Annotated[
        bool, Query(description="include each study's definition (else null: a light page)")
    ] = False,
) -> dict[str, Any]:
    """Studies, newest first, filtered by status and name; definitions with ``full=true``."""
    if status is not None and status not in STATUSES:
        raise HTTPException(422, f"status must be one of {', '.join(STATUSES)}, got {status!r}")
    items, total = catalogue.list_studies(status=status, name=name, limit=limit, offset=offset)
    positions = catalogue.queue_positions()
    if not full:  # definitions can be long: a list shows the records, GET /studies/{id} all
        items = [{**r, "definition": None} for r in items]
    return {"items": [study_out(r, positions) for r in items], "total": total, "limit": limit,
            "offset": offset}  # fmt: skip


@router.get("/{study_id}", response_model=StudyOut, responses=_ERRORS)
def get_study(study_id: StudyId, catalogue: CatalogueDep) -> dict[str, Any]:
    """A study's status, progress, queue position, rate, ETA, timings and failures."""
    return study_out(study_or_404(catalogue, study_id), catalogue.queue_positions())


@router.post(
    "/{study_id}/cancel",
    response_model=StudyOut,
    responses={**_ERRORS, 409: {"model": ErrorOut, "description": "not queued or running"}},
)
def cancel_study(study_id: StudyId, catalogue: CatalogueDep, jobs: JobsDep) -> dict[str, Any]:
    """Cancel a study: its running tasks stop within seconds, finished chunks are kept, status
    ``cancelled`` (resume continues from them)."""
    study_or_404(catalogue, study_id)
    try:
        return study_out(jobs.cancel(study_id))
    except StateError as exc:
        raise HTTPException(409, str(exc)) from None


@router.delete("/{study_id}", status_code=204, responses=_ERRORS)
def delete_study(study_id: StudyId, catalogue: CatalogueDep, jobs: JobsDep) -> Response:
    """Remove a study: stop it if it is queued or running, delete its chunks, its results file
    and its record. Submitting the same definition later computes it again."""
    study_or_404(catalogue, study_id)
    try:
        jobs.delete(study_id)
    except KeyError:
        raise HTTPException(404, f"no study with id {study_id!r}") from None
    return Response(status_code=204)


@router.post(
    "/{study_id}/resume",
    status_code=202,
    response_model=StudyOut,
    responses={**_ERRORS, 409: {"model": ErrorOut, "description": "not cancelled or failed"}},
)
def resume_study(study_id: StudyId, catalogue: CatalogueDep, jobs: JobsDep) -> dict[str, Any]:
    """Queue a cancelled or failed study again; it continues from its finished chunks."""
    study_or_404(catalogue, study_id)
    try:
        return study_out(jobs.resume(study_id))
    except StateError as exc:
        raise HTTPException(409, str(exc)) from None
