"""``/points``: the point store, queried across studies (JSON, CSV or NetCDF), paged."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field, create_model

from service.api.admission import heavy
from service.api.deps import CatalogueDep
from service.api.points import FLOAT_PARAMS, MAX_PAGE, PointQuery, SqlPointStore, points_csv
from service.api.points import points_dataset as _dataset
from service.api.routes.results import NETCDF, RESULT_ERRORS
from service.studies.chunks import is_study_id
from service.studies.dataset import json_text, write_netcdf
from service.studies.variables import OUTCOMES
from worker.model.chain import MAX_CELLS
from worker.simulate import SOLVER_VERSION

router = APIRouter(prefix="/points", tags=["points"])


class _Common(BaseModel):
    model_config = ConfigDict(extra="forbid")

    modes: int | None = Field(None, ge=1, le=50, description="beam modes")
    coupling: Literal["paper", "full"] | None = Field(None, description="coupling model")
    method: str | None = Field(None, max_length=16, description="solver method")
    outcome: Literal[OUTCOMES] | None = Field(None, description="how the point ended")  # type: ignore[valid-type]
    cells: int | None = Field(
        None, ge=1, le=MAX_CELLS, description="chains of N cells only (1: the unit cell)"
    )
    version: str = Field(
        SOLVER_VERSION, max_length=16,
        description="solver version of the points (default: this service's); 'all' for every one",
    )  # fmt: skip
    study: str | None = Field(None, max_length=64, description="only the points of this study")
    after: str | None = Field(
        None, pattern=r"^[0-9a-f]{1,64}$", description="the previous page's `next` key"
    )
    limit: int = Field(1000, ge=1, le=MAX_PAGE, description="points per page")
    format: Literal["json", "csv", "netcdf"] = "json"


def _param_fields() -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in FLOAT_PARAMS:
        what = "g1 = g2 = gap" if name == "gap" else name
        out[name] = (float | None, Field(None, description=f"{what} equal to this value"))
        out[f"{name}_min"] = (float | None, Field(None, description=f"{what} >= this value"))
        out[f"{name}_max"] = (float | None, Field(None, description=f"{what} <= this value"))
    return out


#: The query parameters of ``GET /points``: a value or a range per parameter, filters, paging.
PointsParams = create_model("PointsParams", __base__=_Common, **_param_fields())


def _query(p: BaseModel) -> PointQuery:
    values: dict[str, float] = {}
    ranges: dict[str, tuple[float | None, float | None]] = {}
    for name in FLOAT_PARAMS:
        v, lo, hi = (getattr(p, n) for n in (name, f"{name}_min", f"{name}_max"))
        for field, x in ((name, v), (f"{name}_min", lo), (f"{name}_max", hi)):
            if x is not None and not math.isfinite(x):
                raise HTTPException(422, f"{field} must be a finite number, got {x}")
        if v is not None:
            if lo is not None or hi is not None:
                raise HTTPException(
                    422, f"give {name} or a range ({name}_min, {name}_max), not both"
                )
            values[name] = v
        elif lo is not None or hi is not None:
            if lo is not None and hi is not None and lo > hi:
                raise HTTPException(422, f"{name}_min ({lo}) is above {name}_max ({hi})")
            ranges[name] = (lo, hi)
    if p.study is not None and not is_study_id(p.study):
        raise HTTPException(422, f"study must be a study id (a hex digest), got {p.study!r}")
    return PointQuery(
        values=values, ranges=ranges, modes=p.modes, coupling=p.coupling, method=p.method,
        outcome=p.outcome, cells=p.cells, version=p.version, study=p.study, after=p.after,
        limit=p.limit,
    )  # fmt: skip


@router.get(
    "",
    responses={
        200: {
            "description": "one page of points: JSON {points, count, next}; CSV or NetCDF "
            "with the next page's key in the `X-Next-After` header",
            "content": {"text/csv": {}, NETCDF: {}},
        },
        401: RESULT_ERRORS[401],
        422: RESULT_ERRORS[422],
    },
)
@heavy
def list_points(
    params: Annotated[PointsParams, Query()],  # type: ignore[valid-type]
    catalogue: CatalogueDep,
) -> Response:
    """Computed points of every study, by parameter values or ranges (a value matches within
    a relative 1e-9), in key order, a page at a time: ask again with ``after=<next>`` until
    ``next`` is null. By default only points of this service's solver version."""
    q = _query(params)
    try:
        rows, nxt = SqlPointStore(catalogue.engine).query(q)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    headers = {"X-Next-After": nxt} if nxt else {}
    if params.format == "csv":
        return Response(points_csv(rows), media_type="text/csv; charset=utf-8", headers=headers)
    if params.format == "netcdf":
        return Response(_netcdf(rows), media_type=NETCDF, headers=headers)
    body = json_text({"points": rows, "count": len(rows), "next": nxt})
    return Response(body, media_type="application/json", headers=headers)


def _netcdf(rows: list[dict[str, Any]]) -> bytes:
    ds = _dataset(rows)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "points.nc"
        write_netcdf(ds, path)
        return path.read_bytes()
