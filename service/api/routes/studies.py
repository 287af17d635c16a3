"""``/studies``: submit, list, inspect, cancel and resume studies."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response

from service.api.catalogue import STATUSES
from service.api.deps import CatalogueDep, JobsDep, SettingsDep, StudyId, study_or_404
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


def study_out(rec: dict[str, Any]) -> dict[str, Any]:
    """A catalogue record with progress and links."""
    base = f"/studies/{rec['id']}"
    total = rec["points_total"]
    return {
        **rec,
        "progress": 1.0 if total == 0 else min(1.0, rec["points_done"] / total),
        "links": {
            "self": base,
            "dataset": f"{base}/dataset",
            "data": f"{base}/data",
            "bandgap": f"{base}/bandgap",
            "plots": f"{base}/plots/transmittance.png",
        },
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
    except StudyFileError as exc:  # "not valid YAML: ..." / "not valid JSON: ..."
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
    request: Request, response: Response, settings: SettingsDep, jobs: JobsDep
) -> dict[str, Any]:
    """Submit a study; an identical definition returns the existing study (no second run)."""
    data = _parse_body(await request.body(), request.headers.get("content-type", ""))
    if not isinstance(data, dict):
        raise HTTPException(422, "a study definition must be a mapping of keys to values")
    try:
        study = parse_study(data, max_points=settings.max_points, source="body")
    except StudyError as exc:
        problems = [{"path": p or "(root)", "message": m} for p, m in exc.problems]
        raise HTTPException(422, {"detail": str(exc), "problems": problems}) from None
    rec, created = jobs.submit(study)
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
) -> dict[str, Any]:
    """Studies, newest first, filtered by status and name."""
    if status is not None and status not in STATUSES:
        raise HTTPException(422, f"status must be one of {', '.join(STATUSES)}, got {status!r}")
    items, total = catalogue.list_studies(status=status, name=name, limit=limit, offset=offset)
    return {"items": [study_out(r) for r in items], "total": total, "limit": limit,
            "offset": offset}  # fmt: skip


@router.get("/{study_id}", response_model=StudyOut, responses=_ERRORS)
def get_study(study_id: StudyId, catalogue: CatalogueDep) -> dict[str, Any]:
    """A study's status, progress, timings and failures."""
    return study_out(study_or_404(catalogue, study_id))


@router.delete(
    "/{study_id}",
    response_model=StudyOut,
    responses={**_ERRORS, 409: {"model": ErrorOut, "description": "not queued or running"}},
)
def cancel_study(study_id: StudyId, catalogue: CatalogueDep, jobs: JobsDep) -> dict[str, Any]:
    """Cancel a study: queued work stops, finished chunks are kept, status ``cancelled``."""
    study_or_404(catalogue, study_id)
    try:
        return study_out(jobs.cancel(study_id))
    except StateError as exc:
        raise HTTPException(409, str(exc)) from None


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
