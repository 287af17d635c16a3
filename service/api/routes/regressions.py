"""``/regressions``: the catalogued nightly regression reports, and running the suite now."""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path as FilePath
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Path, Query, Request, Response
from fastapi.responses import PlainTextResponse
from pydantic import BaseModel, ConfigDict, Field, model_validator

from service.api.deps import CatalogueDep, JobsDep, SettingsDep
from service.api.nightly import NightlyBusy, NightlyRunner
from service.api.schemas import ErrorOut, RegressionList, RegressionOut
from service.api.settings import Settings
from service.regression.report import map_text
from service.studies.files import nul_paths

router = APIRouter(prefix="/regressions", tags=["regressions"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorOut, "description": "missing or wrong bearer token"},
    404: {"model": ErrorOut, "description": "no such regression run"},
}


@router.get("", response_model=RegressionList, responses={401: _ERRORS[401]})
def list_regressions(
    catalogue: CatalogueDep,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=2**31)] = 0,
) -> dict[str, Any]:
    """Nightly regression runs, newest first."""
    items, total = catalogue.list_regressions(limit=limit, offset=offset)
    return {"items": items, "total": total, "limit": limit, "offset": offset}


@router.post(
    "",
    status_code=202,
    response_model=RegressionOut,
    responses={
        401: _ERRORS[401],
        409: {"model": ErrorOut, "description": "a nightly run is in progress"},
        503: {"model": ErrorOut, "description": "the service's job runner is not running"},
    },
)
def start_regression(
    request: Request, response: Response, catalogue: CatalogueDep, jobs: JobsDep
) -> dict[str, Any]:
    """Run the nightly suite now, through the service's own job queue.

    Every study of the suite is queued like a user's study (``GET /studies?name=nightly``),
    tagged with this run (``nightly-<time>``) so it is computed afresh. The report is
    ``GET /regressions/{id}`` once the run has finished (``finished_at`` set).
    """
    if not jobs.running:
        raise HTTPException(503, "the service's job runner is not running; no study would run")
    runner: NightlyRunner = request.app.state.nightly_runner
    try:
        reg_id = runner.start(trigger="api")
    except NightlyBusy as exc:
        raise HTTPException(409, str(exc)) from None
    response.headers["Location"] = f"/regressions/{reg_id}"
    rec = catalogue.get_regression(reg_id)
    assert rec is not None
    return rec


class _PostedReport(BaseModel):
    """What every nightly report has (``NightlyReport.to_json``); the rest is kept as given."""

    # strict: "yes" is not a boolean, 1 not a summary
    model_config = ConfigDict(extra="allow", strict=True)

    ok: bool
    summary: str = Field(max_length=10_000)
    studies: list[dict[str, Any]]


class RegressionReportIn(BaseModel):
    """The report of a suite run made elsewhere, e.g. by ``impactcell nightly --url``."""

    model_config = ConfigDict(extra="forbid", strict=True)

    report: _PostedReport
    markdown: str = ""

    @model_validator(mode="before")
    @classmethod
    def _no_nul(cls, data: Any) -> Any:
        # never part of a report; the catalogue's database refuses it
        nul = nul_paths(data)
        if nul:
            raise ValueError(f"must not contain a NUL character: {', '.join(nul[:10])}")
        return data


@router.post(
    "/reports",
    status_code=201,
    response_model=RegressionOut,
    responses={401: _ERRORS[401], 422: {"model": ErrorOut, "description": "not a report"}},
)
def record_regression(
    body: RegressionReportIn, response: Response, catalogue: CatalogueDep
) -> dict[str, Any]:
    """Catalogue the report of a nightly run made through this service by a client.

    ``impactcell nightly --url`` runs its suite's studies on this service and compares them
    where it runs; it then posts its report here, so the run is listed by ``GET /regressions``
    (``trigger`` ``client``) beside the service's own runs.
    """
    report = body.report.model_dump()
    try:  # when the run started, as the report says; else now
        started = dt.datetime.fromisoformat(str(report.get("started")))
    except ValueError:
        started = dt.datetime.now(dt.UTC)
    if started.tzinfo is None:
        started = started.replace(tzinfo=dt.UTC)
    try:
        reg_id = catalogue.add_finished_regression(
            "client", started_at=started, ok=body.report.ok, summary=body.report.summary,
            report=report, markdown=body.markdown,
        )  # fmt: skip
    except ValueError as exc:  # NaN or infinity in the report: JSON has no such numbers
        raise HTTPException(422, f"report: {exc}") from None
    response.headers["Location"] = f"/regressions/{reg_id}"
    rec = catalogue.get_regression(reg_id)
    assert rec is not None
    return rec


@router.get(
    "/{reg_id}",
    response_model=RegressionOut,
    responses={**_ERRORS, 200: {"content": {"text/markdown": {}}}},
)
def get_regression(
    catalogue: CatalogueDep,
    settings: SettingsDep,
    reg_id: Annotated[int, Path(ge=1, le=2**31)],
    format: Literal["json", "markdown"] = "json",  # noqa: A002 - the query parameter's name
) -> Any:
    """One regression run: its JSON report, or the markdown report with ``format=markdown``."""
    rec = catalogue.get_regression(reg_id)
    if rec is None:
        raise HTTPException(404, f"no regression run with id {reg_id}")
    rec = _without_server_paths(rec, settings)
    if format == "markdown":
        return PlainTextResponse(rec["markdown"] or "", media_type="text/markdown")
    return rec


def _without_server_paths(rec: dict[str, Any], settings: Settings) -> dict[str, Any]:
    """A record with the service's folders (data, suite) shown relative to themselves: reports
    catalogued by older runs, or errors, may name them."""
    from service.regression.suite import suite_folders

    suite, _ = suite_folders(settings.nightly_dir)
    roots = {str(settings.data_dir.resolve()): "<data>", str(FilePath(suite).resolve().parent): "."}
    roots = {k: v for k, v in roots.items() if len(FilePath(k).parts) > 1}  # never "/" itself
    pattern = re.compile(
        rf"(?<![\w/.-])({'|'.join(re.escape(k) for k in sorted(roots, key=len, reverse=True))})"
        rf"(?![\w.-])"
    )
    return map_text(lambda t: pattern.sub(lambda m: roots[m.group(1)], t), rec)
