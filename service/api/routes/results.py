"""Results of a study: the NetCDF file, JSON slices, bandgap maps and plots."""

from __future__ import annotations

import os
import tempfile
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Annotated, Any, Literal

import xarray as xr
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse, Response
from starlette.background import BackgroundTask

from service.analysis.bands import bandgap_json, bandgap_map
from service.analysis.selection import (
    AnalysisError,
    select,
    slice_json,
)
from service.api.catalogue import Catalogue
from service.api.deps import CatalogueDep, SettingsDep, StudyId, study_or_404
from service.api.schemas import ErrorOut
from service.studies.chunks import StudyStore
from service.studies.dataset import (
    encoding,
    json_text,
    open_results,
    results_from_records,
)
from service.studies.schema import Study, study_from_canonical
from service.studies.variables import FREQUENCY_AXES, MODEL_AXES, default_x

router = APIRouter(prefix="/studies/{study_id}", tags=["results"])

_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorOut, "description": "missing or wrong bearer token"},
    404: {"model": ErrorOut, "description": "no such study"},
    422: {"model": ErrorOut, "description": "bad selection (names the field and the value)"},
}
# Query parameters with a meaning of their own; every other one selects a coordinate value.
_RESERVED = {"variable", "nearest", "x", "y", "threshold_db", "hue", "periods", "format"}
_NETCDF = "application/x-netcdf"


class _Cache:
    """A few opened results files, keyed by path and modification time."""

    def __init__(self, size: int = 8) -> None:
        self._items: OrderedDict[tuple[str, int], xr.Dataset] = OrderedDict()
        self._lock = threading.Lock()
        self._size = size

    def get(self, path: Path) -> xr.Dataset:
        key = (str(path), path.stat().st_mtime_ns)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        ds = open_results(path)
        with self._lock:
            self._items[key] = ds
            while len(self._items) > self._size:
                self._items.popitem(last=False)
        return ds


_cache = _Cache()


def study_of(catalogue: Catalogue, study_id: str) -> tuple[dict[str, Any], Study]:
    rec = study_or_404(catalogue, study_id)
    return rec, study_from_canonical(rec["definition"], source=f"study {study_id}")


def load_dataset(
    settings: Any, catalogue: Catalogue, study_id: str
) -> tuple[xr.Dataset, Path | None]:
    """The study's dataset, and its results file (``None`` when partial: from chunks only)."""
    rec, study = study_of(catalogue, study_id)
    store = StudyStore(settings.data_dir, study)
    path = store.results_path
    if path.is_file() and (rec["status"] == "finished" or not store.has_retry_chunks()):
        return _cache.get(path), path
    cols, done = store.collect_partial()
    return results_from_records(study, cols, computed=done), None


def coords_of(request: Request) -> dict[str, str]:
    return {k: v for k, v in request.query_params.items() if k not in _RESERVED}


def json_response(payload: Any) -> Response:
    return Response(json_text(payload), media_type="application/json")


@router.get(
    "/dataset",
    responses={
        **_ERRORS,
        200: {"content": {_NETCDF: {}}, "description": "the NetCDF4 results file"},
    },
    response_class=Response,
)
def dataset(study_id: StudyId, settings: SettingsDep, catalogue: CatalogueDep) -> Response:
    """The results as NetCDF; for unfinished studies, from finished chunks (``partial = 1``)."""
    ds, path = load_dataset(settings, catalogue, study_id)
    partial = path is None
    headers = {"X-Impactcell-Partial": "1" if partial else "0"}
    name = f"{study_id}{'-partial' if partial else ''}.nc"
    if path is not None:
        return FileResponse(path, media_type=_NETCDF, filename=name, headers=headers)
    fd, tmp = tempfile.mkstemp(suffix=".nc", prefix="impactcell-partial-")
    os.close(fd)
    ds.to_netcdf(tmp, engine="netcdf4", encoding=encoding(ds))
    return FileResponse(
        tmp, media_type=_NETCDF, filename=name, headers=headers,
        background=BackgroundTask(os.unlink, tmp),
    )  # fmt: skip


@router.get("/data", responses=_ERRORS)
def data(
    request: Request,
    study_id: StudyId,
    settings: SettingsDep,
    catalogue: CatalogueDep,
    variable: Annotated[str, Query(max_length=64)] = "transmittance_db",
    nearest: bool = False,
) -> Response:
    """A JSON slice of one variable; other query parameters select coordinate values."""
    ds, path = load_dataset(settings, catalogue, study_id)
    try:
        da = select(ds, variable, coords_of(request), nearest=nearest)
        out = slice_json(da)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    out["partial"] = path is None
    return json_response(out)


@router.get("/bandgap", responses=_ERRORS)
def bandgap(
    request: Request,
    study_id: StudyId,
    settings: SettingsDep,
    catalogue: CatalogueDep,
    x: Annotated[str, Query(max_length=64)] = "gamma_r",
    y: Annotated[str | None, Query(max_length=64)] = None,
    threshold_db: Annotated[float, Query(ge=-1000, le=1000)] = 0.0,
    nearest: bool = False,
) -> Response:
    """The bandgap map: Γ over x × y, where Γ < threshold, and the band edges in x per y."""
    ds, path = load_dataset(settings, catalogue, study_id)
    try:
        m = bandgap_map(ds, x, y, threshold_db=threshold_db, sel=coords_of(request),
                        nearest=nearest)  # fmt: skip
        out = bandgap_json(m)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    out["partial"] = path is None
    return json_response(out)


@router.get(
    "/plots/{kind}.png",
    responses={**_ERRORS, 200: {"content": {"image/png": {}}, "description": "a PNG figure"}},
    response_class=Response,
)
def plot(
    request: Request,
    study_id: StudyId,
    kind: Literal["transmittance", "bandgap", "effective-mass"],
    settings: SettingsDep,
    catalogue: CatalogueDep,
    x: Annotated[str | None, Query(max_length=64)] = None,
    y: Annotated[str | None, Query(max_length=64)] = None,
    hue: Annotated[str | None, Query(max_length=64)] = None,
    threshold_db: Annotated[float, Query(ge=-1000, le=1000)] = 0.0,
    nearest: bool = False,
) -> Response:
    """A figure: transmittance (Fig. 5a style), bandgap map, or effective mass (Fig. 6)."""
    from service.analysis import plots

    ds, _path = load_dataset(settings, catalogue, study_id)
    sel = coords_of(request)
    xdim = x or default_x(ds.dims) or FREQUENCY_AXES[0]
    try:
        if kind == "transmittance":
            png = plots.transmittance_png(ds, sel, x=xdim, hue=hue, nearest=nearest)
        elif kind == "effective-mass":
            png = plots.effective_mass_png(ds, sel, x=xdim, nearest=nearest)
        else:
            ydim = y or _default_y(ds, xdim)
            m = bandgap_map(ds, xdim, ydim, threshold_db=threshold_db, sel=sel, nearest=nearest)
            png = plots.bandgap_png(m)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    return Response(png, media_type="image/png")


def _default_y(ds: xr.Dataset, x: str) -> str | None:
    for name in MODEL_AXES:
        if name != x and name in ds.dims and ds.sizes[name] > 1:
            return name
    others = [d for d in ds.dims if d != x and d != "stop" and ds.sizes[d] > 1]
    return str(others[0]) if others else None


__all__ = ["coords_of", "json_response", "load_dataset", "router", "study_of"]
