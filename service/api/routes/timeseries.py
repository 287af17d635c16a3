"""``/studies/{id}/timeseries``: one point recomputed with its time histories (never stored)."""

from __future__ import annotations

import json
import os
import tempfile
from typing import Annotated, Any, Literal

import numpy as np
import xarray as xr
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse, Response
from starlette.background import BackgroundTask

from service.analysis.selection import AnalysisError, coordinate_index, values_text
from service.api.deps import CatalogueDep, StudyId
from service.api.routes.results import coords_of, json_response, study_of
from service.api.schemas import ErrorOut
from service.studies.dataset import FILL_FLOAT, jsonable
from service.studies.schema import Study
from worker.simulate import EVENT_FIELDS, HISTORY_FIELDS

__all__ = ["router"]

router = APIRouter(prefix="/studies/{study_id}", tags=["results"])

_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorOut, "description": "missing or wrong bearer token"},
    404: {"model": ErrorOut, "description": "no such study"},
    422: {"model": ErrorOut, "description": "bad selection (names the field and the value)"},
}
_NETCDF = "application/x-netcdf"
_MAX_HISTORY_PERIODS = 50


@router.get(
    "/timeseries",
    responses={
        **_ERRORS,
        200: {"content": {"application/json": {}, _NETCDF: {}}, "description": "histories"},
    },
)
def timeseries(
    request: Request,
    study_id: StudyId,
    catalogue: CatalogueDep,
    periods: Annotated[int, Query(ge=1, le=_MAX_HISTORY_PERIODS)] = 5,
    format: Literal["json", "netcdf"] = "json",  # noqa: A002 - the query parameter's name
    nearest: bool = False,
) -> Response:
    """Recompute one point with time histories on (never stored); select it by coordinates."""
    from worker.model import CellParams
    from worker.simulate import POINT_KEYS, simulate_point

    _, study = study_of(catalogue, study_id)
    try:
        index, coords = _point_index(study, coords_of(request), nearest)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    pt = study.points(index, index + 1)[0]
    try:
        params = CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt})
        r = simulate_point(params, study.solver.settings(), history_periods=periods)
    except ValueError as exc:
        raise HTTPException(422, f"point {coords} cannot be simulated: {exc}") from None
    hist = r.history or {}
    result = {k: jsonable(v) for k, v in r.as_dict().items()}
    if format == "netcdf":
        return _history_netcdf(study_id, coords, hist, result)
    series = {k: jsonable(v) for k, v in hist.items() if k not in ("state", "events")}
    body = {"study_id": study_id, "coords": coords, "result": result, "periods": periods,
            "series": series}  # fmt: skip
    if "events" in hist:
        body["events"] = {k: jsonable(v) for k, v in _event_columns(hist["events"]).items()}
    return json_response(body)


def _point_index(study: Study, sel: dict[str, str], nearest: bool) -> tuple[int, dict[str, float]]:
    """Flat index and coordinates of the grid point that ``sel`` picks (every varying axis)."""
    dims = study.dims()
    unknown = sorted(set(sel) - set(dims))
    if unknown:
        raise AnalysisError(
            f"unknown coordinate {unknown[0]!r}; the study's axes are {', '.join(dims)}"
        )
    idx: list[int] = []
    for name, values in dims.items():
        if name in sel:
            idx.append(coordinate_index(name, values, sel[name], nearest))
        elif values.size == 1:
            idx.append(0)
        else:
            raise AnalysisError(
                f"{name} must be given to pick one point; values are {values_text(values)}"
            )
    coords = {name: float(v[i]) for (name, v), i in zip(dims.items(), idx, strict=True)}
    flat = int(np.ravel_multi_index(tuple(idx), tuple(v.size for v in dims.values())))
    return flat, coords


def _event_columns(events: np.ndarray) -> dict[str, np.ndarray]:
    """The event log as named columns (``column_<i>`` if its layout is not the known one)."""
    ev = np.asarray(events, dtype=np.float64).reshape(len(events), -1)
    names = list(EVENT_FIELDS) if ev.shape[1] == len(EVENT_FIELDS) else None
    return {(names[i] if names else f"column_{i}"): ev[:, i] for i in range(ev.shape[1])}


def _history_netcdf(
    study_id: str, coords: dict[str, float], hist: dict[str, np.ndarray], result: dict[str, Any]
) -> Response:
    tau = np.asarray(hist.get("tau", np.zeros(0)))
    data_vars: dict[str, Any] = {}
    enc: dict[str, dict[str, Any]] = {}
    for k, v in hist.items():
        if k in ("tau", "state", "events"):
            continue
        a = np.asarray(v)
        data_vars[k] = ("time", a, {"units": "1", "long_name": HISTORY_FIELDS.get(k, k)})
        integer = a.dtype.kind in "iub"
        enc[k] = {"zlib": True} if integer else {"_FillValue": FILL_FLOAT, "zlib": True}
    if "events" in hist:
        for k, v in _event_columns(hist["events"]).items():
            name = f"event_{k}"
            data_vars[name] = ("event", v, {"units": "1", "long_name": EVENT_FIELDS.get(k, k)})
            enc[name] = {"_FillValue": FILL_FLOAT, "zlib": True}
    ds = xr.Dataset(
        data_vars,
        coords={"time": ("time", tau, {"units": "1", "long_name": "non-dimensional time tau"})},
        attrs={
            "study_id": study_id,
            "point": json.dumps(coords),
            "result": json.dumps(result),
        },  # fmt: skip
    )
    fd, tmp = tempfile.mkstemp(suffix=".nc", prefix="impactcell-ts-")
    os.close(fd)
    ds.to_netcdf(tmp, engine="netcdf4", encoding=enc)
    return FileResponse(tmp, media_type=_NETCDF, filename=f"{study_id}-timeseries.nc",
                        background=BackgroundTask(os.unlink, tmp))  # fmt: skip
