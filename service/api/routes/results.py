"""Results of a study: the NetCDF file, JSON/CSV slices, bandgap maps and plots (PNG/SVG)."""

from __future__ import annotations

import hashlib
import logging
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import xarray as xr
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse, Response

from service.analysis import figures
from service.analysis.bands import bandgap_csv, bandgap_json, bandgap_map
from service.analysis.hysteresis import hysteresis_csv, hysteresis_json, hysteresis_map
from service.analysis.selection import (
    AnalysisError,
    default_view,
    select,
    slice_csv,
    slice_json,
)
from service.api.admission import heavy
from service.api.catalogue import Catalogue
from service.api.deps import CatalogueDep, SettingsDep, StudyId, study_or_404
from service.api.schemas import ErrorOut
from service.studies.chunks import PartialState, StudyStore, atomic_write
from service.studies.dataset import (
    encoding,
    json_text,
    open_results,
    results_from_records,
    write_netcdf,
)
from service.studies.schema import Study, study_from_canonical

router = APIRouter(prefix="/studies/{study_id}", tags=["results"])
log = logging.getLogger("impactcell.api")

RESULT_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorOut, "description": "missing or wrong bearer token"},
    404: {"model": ErrorOut, "description": "no such study"},
    422: {"model": ErrorOut, "description": "bad selection (names the field and the value)"},
    503: {"model": ErrorOut, "description": "results file damaged or missing: being rebuilt"},
}
# Query parameters with a meaning of their own; every other one selects a coordinate value.
_RESERVED = {"variable", "reference", "nearest", "x", "y", "threshold_db", "hue", "periods",
             "format", "jump_db", "tol_db"}  # fmt: skip
NETCDF = "application/x-netcdf"
_CSV = "text/csv; charset=utf-8"
#: The most values a JSON or CSV slice (or bandgap map) holds; beyond, 422 says how to select.
MAX_SLICE_VALUES = 100_000
#: What a bandgap map (``/bandgap``, ``/plots/bandgap``) can show (service.analysis.bands).
MapVariable = Literal["transmittance_db", "transmittance_linear_db", "impact_effect_db"]
Reference = Literal["none", "linear"]
_REFERENCE_DOC = (
    "linear: measure against the same cell without stops, i.e. map impact_effect_db "
    "(Γ − Γ_lin); none (default): the variable as given"
)


def map_variable(variable: str, reference: str) -> str:
    """The variable a map shows (:func:`service.analysis.figures.map_variable`; 422 if none)."""
    try:
        return figures.map_variable(variable, reference)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None


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


class _Partial:
    """One unfinished study: the chunks read so far, the dataset and NetCDF file built from
    them (rebuilt only when the set of chunk files changes)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.state: PartialState | None = None
        self.key: frozenset[tuple[str, int, int, int]] | None = None
        self.ds: xr.Dataset | None = None
        self.nc: Path | None = None


class _PartialCache:
    """Partial datasets of a few studies, built incrementally from their chunk files.

    A request reads only the chunk files that appeared since the previous one (one file of a
    chunk's points instead of every file of the study); the dataset is rebuilt only when the set of
    files changed, and its NetCDF file is written once per set and then served as a file.
    """

    def __init__(self, size: int = 2) -> None:  # each holds every point of a study, twice
        self._items: OrderedDict[str, _Partial] = OrderedDict()
        self._lock = threading.Lock()
        self._size = size

    def _entry(self, store: StudyStore) -> _Partial:
        key = str(store.folder)  # not the id alone: two data dirs may hold the same study
        with self._lock:
            entry = self._items.get(key)
            if entry is None:
                entry = self._items[key] = _Partial()
            self._items.move_to_end(key)
            while len(self._items) > self._size:
                self._items.popitem(last=False)
            return entry

    def get(
        self, store: StudyStore, netcdf: bool = False
    ) -> tuple[PartialState, xr.Dataset, Path | None]:
        """The up-to-date state and dataset, and (``netcdf``) the dataset's NetCDF file."""
        entry = self._entry(store)
        with entry.lock:  # one build per study at a time; other studies are not held up
            entry.state = state = store.update_partial(entry.state)
            if state.key != entry.key or entry.ds is None:
                entry.ds = results_from_records(
                    store.study, state.cols, computed=state.filled.copy()
                )
                entry.key, entry.nc = state.key, None
            if netcdf and (entry.nc is None or not entry.nc.is_file()):
                entry.nc = _write_partial(store, entry.ds, state)
            return state, entry.ds, entry.nc


_partials = _PartialCache()
_PARTIAL_FILE = "partial-{done}-{digest}.nc"


def _write_partial(store: StudyStore, ds: xr.Dataset, state: PartialState) -> Path:
    """Write a partial dataset next to the chunks; older partial files beyond the previous one
    are removed (the previous may still be streaming to a client)."""
    digest = hashlib.sha256(repr(sorted(state.key)).encode()).hexdigest()[:12]
    path = store.folder / _PARTIAL_FILE.format(done=int(state.filled.sum()), digest=digest)
    atomic_write(path, lambda p: write_netcdf(ds, p, encoding(ds)))
    older = sorted(
        (p for p in store.folder.glob("partial-*.nc") if p != path),
        key=lambda p: p.stat().st_mtime_ns if p.exists() else 0,
    )
    for stale in older[:-1]:
        stale.unlink(missing_ok=True)
    return path


def _tidy_partials(store: StudyStore) -> None:
    """Remove partial files once the results file is complete."""
    for stale in store.folder.glob("partial-*.nc"):
        stale.unlink(missing_ok=True)


def study_of(catalogue: Catalogue, study_id: str) -> tuple[dict[str, Any], Study]:
    """The study's catalogue record and its parsed definition (404 if unknown)."""
    rec = study_or_404(catalogue, study_id)
    return rec, study_from_canonical(rec["definition"], source=f"study {study_id}")


def _results_file(catalogue: Catalogue, rec: dict[str, Any], store: StudyStore) -> Path | None:
    """The complete results file, checked, when it is the study's current data (``None``: the
    data is the partial dataset of the study's chunks).

    A finished study's file that is missing or fails its check (set aside by
    :meth:`StudyStore.results_status`) is a 503: the study is queued to write it again.
    """
    if rec["status"] == "finished":
        status = store.results_status()
        if status != "ok":
            raise _rebuild(catalogue, rec, status)
        return store.results_path
    if store.results_status() != "ok":
        return None
    # A results file of an earlier run while failed tasks are retried: the chunks are newer.
    state, _, _ = _partials.get(store)
    return None if state.has_retry else store.results_path


def _rebuild(catalogue: Catalogue, rec: dict[str, Any], status: str) -> HTTPException:
    """Queue a finished study whose results file is missing or damaged, so that a run writes
    it again (from its chunks and the point store; only points neither holds are computed);
    the 503 that says so."""
    sid = rec["id"]
    if catalogue.set_status_if(sid, ("finished",), "queued", finished_at=None, error=None):
        log.warning("study %s: results file %s; queued to write it again", sid, status)
    why = "is missing" if status == "missing" else "failed its SHA-256 check and was set aside"
    return HTTPException(
        503,
        f"the results file of study {sid} {why}; the study is queued to write it again from its "
        f"finished points (computing only points the service does not hold); retry in a few "
        f"seconds (GET /studies/{sid} shows its progress; until it finishes, results are "
        f"partial)",
        headers={"Retry-After": "5"},
    )


def _open_checked(catalogue: Catalogue, rec: dict[str, Any], store: StudyStore,
                  path: Path) -> xr.Dataset:  # fmt: skip
    """The checked results file, opened (a file replaced or damaged since its check: 503)."""
    try:
        return _cache.get(path)
    except (OSError, ValueError):  # never the reader's message: it names the server's path
        status = store.results_status()
        if status != "ok" and rec["status"] == "finished":
            raise _rebuild(catalogue, rec, status) from None
        raise HTTPException(  # replaced while opened, or set aside (the next answer: partial)
            503,
            f"the results file of study {rec['id']} could not be opened; retry",
            headers={"Retry-After": "1"},
        ) from None


def load_dataset(
    settings: Any, catalogue: Catalogue, study_id: str
) -> tuple[xr.Dataset, Path | None]:
    """The study's dataset, and its results file (``None`` when partial: from chunks only)."""
    rec, study = study_of(catalogue, study_id)
    store = StudyStore(settings.data_dir, study)
    if study.is_adaptive:
        # Its points are placed on the union of what its lines sampled, known at the end.
        if rec["status"] == "finished":
            path = _results_file(catalogue, rec, store)
            assert path is not None  # a finished study's file, or a 503
            return _open_checked(catalogue, rec, store, path), path
        raise HTTPException(
            409, f"study {study_id} is adaptive and {rec['status']}: its dataset is assembled "
            "when it finishes (its points so far: GET /points?study=" + study_id + ")",
        )  # fmt: skip
    path = _results_file(catalogue, rec, store)
    if path is not None:
        return _open_checked(catalogue, rec, store, path), path
    _, ds, _ = _partials.get(store)
    return ds, None


def coords_of(request: Request) -> dict[str, str]:
    """The query parameters that select coordinate values (all but the reserved ones)."""
    return {k: v for k, v in request.query_params.items() if k not in _RESERVED}


def json_response(payload: Any) -> Response:
    """JSON without NaN (a NaN that slipped through is an error, never a result)."""
    return Response(json_text(payload), media_type="application/json")


def _csv_response(text: str, filename: str) -> Response:
    disposition = f'attachment; filename="{filename}"'
    return Response(text, media_type=_CSV, headers={"Content-Disposition": disposition})


def _check_size(study_id: str, what: str, dims: dict[str, int], ds: xr.Dataset) -> None:
    """422 when a slice is over :data:`MAX_SLICE_VALUES`, saying how to select a smaller one."""
    size = int(np.prod(list(dims.values()), dtype=np.int64)) if dims else 1
    if size <= MAX_SLICE_VALUES:
        return
    shape = " × ".join(f"{d} {n:,}" for d, n in dims.items())
    axes = ", ".join(f"{d} ({ds.sizes[d]:,} values)" for d in dims)
    example = "&".join(f"{d}={float(ds[d].values[0])!r}" for d in list(dims)[:-1])
    hint = f", e.g. ?{example}" if example else ""
    raise HTTPException(
        422,
        f"{what} would hold {size:,} values ({shape}), over the limit of "
        f"{MAX_SLICE_VALUES:,}; select coordinate values to make it smaller{hint} (axes: "
        f"{axes}; add nearest=true for the closest value), or download everything as NetCDF "
        f"from /studies/{study_id}/dataset",
    )


@router.get(
    "/dataset",
    responses={
        **RESULT_ERRORS,
        200: {"content": {NETCDF: {}}, "description": "the NetCDF4 results file"},
    },
    response_class=Response,
)
@heavy
def dataset(study_id: StudyId, settings: SettingsDep, catalogue: CatalogueDep) -> Response:
    """The results as NetCDF; for unfinished studies, from finished chunks (``partial = 1``).

    Both are streamed from a file: the finished results file as it is, a partial dataset from
    a file built once per set of finished chunks (reading only chunks new since the last).
    """
    rec, study = study_of(catalogue, study_id)
    store = StudyStore(settings.data_dir, study)
    if study.is_adaptive:
        _, path = load_dataset(settings, catalogue, study_id)  # 409 until it finishes
        return FileResponse(path, media_type=NETCDF, filename=f"{study_id}.nc",
                            headers={"X-Impactcell-Partial": "0"})  # fmt: skip
    path = _results_file(catalogue, rec, store)  # checked: never a file that fails its sum
    partial = path is None
    if path is None:
        _, _, path = _partials.get(store, netcdf=True)
        assert path is not None  # netcdf=True always writes it
    else:
        _tidy_partials(store)
    headers = {"X-Impactcell-Partial": "1" if partial else "0"}
    name = f"{study_id}{'-partial' if partial else ''}.nc"
    return FileResponse(path, media_type=NETCDF, filename=name, headers=headers)


@router.get(
    "/data",
    responses={
        **RESULT_ERRORS,
        200: {"content": {"application/json": {}, _CSV: {}}, "description": "the slice"},
    },
)
@heavy
def data(
    request: Request,
    study_id: StudyId,
    settings: SettingsDep,
    catalogue: CatalogueDep,
    variable: Annotated[str, Query(max_length=64)] = "transmittance_db",
    nearest: bool = False,
    format: Literal["json", "csv"] = "json",  # noqa: A002 - the query parameter's name
) -> Response:
    """A slice of one variable (JSON, or CSV in long form); other query parameters select
    coordinate values. A slice over 100,000 values is refused (422) with how to select."""
    ds, path = load_dataset(settings, catalogue, study_id)
    try:
        da = select(ds, variable, coords_of(request), nearest=nearest)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    _check_size(study_id, f"the slice of {variable}", {str(d): n for d, n in da.sizes.items()},
                ds)  # fmt: skip
    if format == "csv":
        return _csv_response(slice_csv(da), f"{study_id}-{variable}.csv")
    out = slice_json(da)
    out["partial"] = path is None
    return json_response(out)


@router.get(
    "/bandgap",
    responses={
        **RESULT_ERRORS,
        200: {"content": {"application/json": {}, _CSV: {}}, "description": "map or edges"},
    },
)
@heavy
def bandgap(
    request: Request,
    study_id: StudyId,
    settings: SettingsDep,
    catalogue: CatalogueDep,
    x: Annotated[str | None, Query(max_length=64)] = None,
    y: Annotated[str | None, Query(max_length=64)] = None,
    threshold_db: Annotated[float | None, Query(ge=-1000, le=1000)] = None,
    nearest: bool = False,
    format: Literal["json", "csv"] = "json",  # noqa: A002 - the query parameter's name
    variable: MapVariable = "transmittance_db",
    reference: Annotated[Reference, Query(description=_REFERENCE_DOC)] = "none",
) -> Response:
    """The bandgap map: a variable over x × y, where it is below the threshold, and the band
    edges in x per y.

    ``variable``: ``transmittance_db`` (Γ, default threshold 0 dB), ``transmittance_linear_db``
    (Γ_lin, the same cell without stops, 0 dB) or ``impact_effect_db`` (Γ − Γ_lin, −1 dB:
    bands are where impacts add more than 1 dB of attenuation). Without ``x`` and ``y`` the
    axes are those of the bandgap plot (x the frequency axis, y the first other varying axis
    with few values); every other varying axis not selected is fixed at its first value and
    listed in ``slice`` (``default: true``). ``format=csv`` gives the band edges, one row per
    band. ``reference=linear`` is the same as ``variable=impact_effect_db``.
    """
    variable = map_variable(variable, reference)
    ds, path = load_dataset(settings, catalogue, study_id)
    try:
        view = default_view(ds, "transmittance_db", x, y, coords_of(request))
        sizes = {a: ds.sizes[a] for a in (view.y, view.x) if a is not None and a in ds.sizes}
        _check_size(study_id, "the bandgap map", sizes, ds)
        m = bandgap_map(ds, view.x, view.y, threshold_db=threshold_db, sel=view.sel,
                        nearest=nearest, variable=variable)  # fmt: skip
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    if format == "csv":
        return _csv_response(bandgap_csv(m), f"{study_id}-bands.csv")
    out = bandgap_json(m, fixed=view.fixed)
    out["study_id"] = study_id
    out["partial"] = path is None
    return json_response(out)


_JUMP_DOC = (
    "a jump: a step of a branch over this (units of variable) that is a discontinuity "
    "(docs/service.md, What counts as a jump)"
)
_TOL_DOC = "the branches differ where their values spread over this (units of variable)"


def _hysteresis(
    study_id: str,
    ds: xr.Dataset,
    sel: dict[str, str],
    x: str | None,
    variable: str,
    jump_db: float,
    tol_db: float,
    nearest: bool,
) -> xr.Dataset:
    """The hysteresis map of a request (422 for an AnalysisError or a map over the cap)."""
    try:
        h = hysteresis_map(ds, x, sel, nearest=nearest, variable=variable, jump_db=jump_db,
                           tol_db=tol_db)  # fmt: skip
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    _check_hysteresis(study_id, h)
    return h


def _check_hysteresis(study_id: str, h: xr.Dataset) -> None:
    """422 when a hysteresis map is over :data:`MAX_SLICE_VALUES`, saying how to keep fewer."""
    size = h.sizes["branch"] * h.sizes[h.attrs["x"]]
    if size > MAX_SLICE_VALUES:
        raise HTTPException(
            422,
            f"the hysteresis map would hold {size:,} values ({h.sizes['branch']} branches × "
            f"{h.sizes[h.attrs['x']]:,} values of {h.attrs['x']}), over the limit of "
            f"{MAX_SLICE_VALUES:,}; select initial=… or direction=… to keep fewer branches, or "
            f"download everything as NetCDF from /studies/{study_id}/dataset",
        )


@router.get(
    "/hysteresis",
    responses={
        **RESULT_ERRORS,
        200: {"content": {"application/json": {}, _CSV: {}}, "description": "the branches"},
    },
)
@heavy
def hysteresis(
    request: Request,
    study_id: StudyId,
    settings: SettingsDep,
    catalogue: CatalogueDep,
    x: Annotated[str | None, Query(max_length=64)] = None,
    variable: Annotated[str, Query(max_length=64)] = "transmittance_db",
    jump_db: Annotated[float, Query(gt=0, le=1000, description=_JUMP_DOC)] = 1.0,
    tol_db: Annotated[float, Query(ge=0, le=1000, description=_TOL_DOC)] = 0.05,
    nearest: bool = False,
    format: Literal["json", "csv"] = "json",  # noqa: A002 - the query parameter's name
) -> Response:
    """The hysteresis map of a sweep or multi-start study: every branch (``up``, ``down``,
    each initial state, ``rest/up``, …) of ``variable`` along x, the jumps of each branch
    (labelled ``J1``, …), where the branches differ by more than ``tol_db`` (intervals of x)
    and the number of distinct responses per point.

    x defaults to the swept axis (else the frequency axis); every other varying grid axis
    not selected is fixed at its first value and listed in ``slice`` (``default: true``);
    ``direction=`` or ``initial=`` keep only those branches. A study without a sweep or
    several starts is 422. ``format=csv``: one row per branch and x value.
    """
    ds, path = load_dataset(settings, catalogue, study_id)
    h = _hysteresis(study_id, ds, coords_of(request), x, variable, jump_db, tol_db, nearest)
    if format == "csv":
        return _csv_response(hysteresis_csv(h), f"{study_id}-hysteresis.csv")
    out = hysteresis_json(h)
    out["study_id"] = study_id
    out["partial"] = path is None
    return json_response(out)


@router.get(
    "/plots/{kind}.{fmt}",
    responses={
        **RESULT_ERRORS,
        200: {
            "content": {"image/png": {}, "image/svg+xml": {}},
            "description": "a PNG or SVG figure",
        },
    },
    response_class=Response,
)
@heavy
def plot(
    request: Request,
    study_id: StudyId,
    kind: Literal["transmittance", "bandgap", "impact-effect", "effective-mass", "hysteresis"],
    fmt: Literal["png", "svg"],
    settings: SettingsDep,
    catalogue: CatalogueDep,
    x: Annotated[str | None, Query(max_length=64)] = None,
    y: Annotated[str | None, Query(max_length=64)] = None,
    hue: Annotated[str | None, Query(max_length=64)] = None,
    threshold_db: Annotated[float | None, Query(ge=-1000, le=1000)] = None,
    nearest: bool = False,
    variable: MapVariable = "transmittance_db",
    reference: Annotated[Reference, Query(description=_REFERENCE_DOC)] = "none",
    jump_db: Annotated[float, Query(gt=0, le=1000, description=_JUMP_DOC)] = 1.0,
    tol_db: Annotated[float, Query(ge=0, le=1000, description=_TOL_DOC)] = 0.05,
) -> Response:
    """A figure, PNG or SVG: transmittance (Fig. 5a style, with the linear reference Γ_lin
    dashed), bandgap map (of ``variable``, as in ``/bandgap``), impact-effect (the bandgap map
    of ``impact_effect_db``, Γ − Γ_lin, threshold −1 dB), effective mass (Fig. 6: θ_eff,
    the first harmonic, with the phase-portrait ratio θ_ps of ``theta_eff_slope`` dashed and
    named as such), or hysteresis (as ``/hysteresis``: up and down curves in two colours with
    markers pointing the way, jumps dashed, where they differ shaded; 422 without a sweep or
    several starts). Irregular (possibly transient ones apart), unsettled and failed points are
    marked and counted in the legend. Needs no
    parameters: x defaults to the frequency axis (the swept axis for hysteresis), the hue
    (transmittance) or y (bandgap) to the first other varying axis with few values, and every
    other varying axis is fixed at its first value, named in the title and the
    ``X-Impactcell-Fixed`` header (JSON)."""
    variable = map_variable(variable, reference)
    ds, _path = load_dataset(settings, catalogue, study_id)
    try:
        image, v, _ = figures.figure(
            ds, kind, fmt, coords_of(request), x=x, y=y, hue=hue, threshold_db=threshold_db,
            nearest=nearest, variable=variable, jump_db=jump_db, tol_db=tol_db,
            check=lambda h: _check_hysteresis(study_id, h),
        )  # fmt: skip
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    from service.analysis.plots import FORMATS  # matplotlib: loaded by the first figure

    return Response(image, media_type=FORMATS[fmt],
                    headers={"X-Impactcell-Fixed": json_text(figures.describe(v))})  # fmt: skip


__all__ = [
    "MAX_SLICE_VALUES",
    "NETCDF",
    "RESULT_ERRORS",
    "coords_of",
    "json_response",
    "load_dataset",
    "router",
    "study_of",
]
