"""``/studies/{id}/timeseries``: one point recomputed with its time histories (never stored).

The recomputation runs on the service's dask cluster (never in the API process: it would hold
its GIL), within ``Settings.timeseries_time_limit_s``; answers are kept in a small cache, so
asking again for the same point is free.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
from collections import OrderedDict
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import xarray as xr
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response

from service.analysis.selection import AnalysisError, coordinate_index, values_text
from service.api.admission import heavy
from service.api.deps import CatalogueDep, JobsDep, SettingsDep, StudyId
from service.api.routes.results import (
    NETCDF,
    RESULT_ERRORS,
    coords_of,
    json_response,
    study_of,
)
from service.studies.dataset import FILL_FLOAT, jsonable, write_netcdf
from service.studies.schema import Study
from service.studies.specs import initial_states
from worker.simulate import EVENT_FIELDS, HISTORY_FIELDS, PointLimits, point_history

__all__ = ["router"]

router = APIRouter(prefix="/studies/{study_id}", tags=["results"])

_MAX_HISTORY_PERIODS = 50
_CACHE_BYTES = 64 << 20  # answers kept (they are small: at most 50 periods of one point)


class _Answers:
    """Finished answers by (study, point, periods, format): an LRU bounded in bytes."""

    def __init__(self, limit: int) -> None:
        self._items: OrderedDict[tuple[str, int, int, str, str], Response] = OrderedDict()
        self._size = 0
        self._limit = limit
        self._lock = threading.Lock()

    def get(self, key: tuple[str, int, int, str, str]) -> Response | None:
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
            return hit

    def put(self, key: tuple[str, int, int, str, str], resp: Response) -> None:
        with self._lock:
            if key in self._items:
                return
            self._items[key] = resp
            self._size += len(resp.body)
            while self._size > self._limit and self._items:
                _, old = self._items.popitem(last=False)
                self._size -= len(old.body)


_answers = _Answers(_CACHE_BYTES)


@router.get(
    "/timeseries",
    responses={
        **RESULT_ERRORS,
        200: {"content": {"application/json": {}, NETCDF: {}}, "description": "histories"},
    },
)
@heavy
def timeseries(
    request: Request,
    study_id: StudyId,
    catalogue: CatalogueDep,
    settings: SettingsDep,
    jobs: JobsDep,
    periods: Annotated[int, Query(ge=1, le=_MAX_HISTORY_PERIODS)] = 5,
    format: Literal["json", "netcdf"] = "json",  # noqa: A002 - the query parameter's name
    nearest: bool = False,
    initial: Annotated[
        str | None,
        Query(max_length=64, description="the initial state's label (studies with several)"),
    ] = None,
) -> Response:
    """Recompute one point with time histories on (never stored); select it by coordinates.

    Runs on the cluster within the service's time limit for it; a point over the limit is a
    422 saying so. Repeated requests are answered from a cache. The point starts from its
    initial state (``initial``: one of the study's labels, default the first), never from a
    sweep predecessor: in a sweep study the response found may be another branch's."""
    _, study = study_of(catalogue, study_id)
    sel = coords_of(request)
    sel.pop("direction", None)  # a sweep direction is not a property of one recomputed point
    sel.pop("initial", None)  # the query parameter above, not a grid coordinate
    labels = study.initial_labels()
    label = labels[0] if initial is None else initial
    if label not in labels:
        raise HTTPException(
            422, f"initial must be one of the study's initial states {', '.join(labels)}; "
            f"got {initial!r}"
        )  # fmt: skip
    try:
        index, coords = _point_index(study, sel, nearest)
    except AnalysisError as exc:
        raise HTTPException(422, str(exc)) from None
    key = (study_id, index, periods, format, label)
    hit = _answers.get(key)
    if hit is not None:
        return hit
    pt = study.points(index, index + 1, grid=True)[0]  # the grid's own order, not work order
    if study.initial is not None:
        pt["initial"] = initial_states(study.initial)[labels.index(label)]
    limit = settings.timeseries_time_limit_s
    args = (pt, study.solver.settings().__dict__.copy(), periods,
            asdict(PointLimits(wall_s=limit, steps=settings.point_step_limit)))  # fmt: skip
    try:
        if jobs.running:  # on the cluster: the API process never holds its GIL for a point
            r = jobs.compute(point_history, *args, method=study.solver.method,
                             timeout=limit + 30.0)  # fmt: skip
        else:  # no runner (the API's own tests): in this request's worker thread
            r = point_history(*args)
    except ValueError as exc:
        raise HTTPException(422, f"point {coords} cannot be simulated: {exc}") from None
    except TimeoutError:
        raise HTTPException(
            503, f"the cluster did not answer within {limit + 30:g} s; try again later"
        ) from None
    if r.outcome == "failed":
        raise HTTPException(422, f"point {coords} cannot be simulated: {r.reason}")
    resp = _answer(study_id, coords, periods, format, r)
    _answers.put(key, resp)
    return resp


def _answer(study_id: str, coords: dict[str, float], periods: int, format: str,  # noqa: A002
            r: Any) -> Response:  # fmt: skip
    """The response for a recomputed point (JSON, or NetCDF bytes)."""
    hist = _distinct_times(r.history or {})
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
    """Flat index and coordinates of the grid point that ``sel`` picks (every varying axis).

    An axis with one value (θ fixed by the study) may be given too, and must match it as in
    ``/data`` (:func:`service.analysis.selection.coordinate_index`)."""
    axes = study.axes()
    unknown = sorted(set(sel) - set(axes))
    if unknown:
        raise AnalysisError(
            f"unknown coordinate {unknown[0]!r}; the study's axes are {', '.join(axes)}"
        )
    dims = study.dims()
    idx: list[int] = []
    for name, values in axes.items():
        if name in sel:
            i = coordinate_index(name, values, sel[name], nearest)
        elif values.size == 1:
            i = 0
        else:
            raise AnalysisError(
                f"{name} must be given to pick one point; values are {values_text(values)}"
            )
        if name in dims:
            idx.append(i)
    coords = {name: float(v[i]) for (name, v), i in zip(dims.items(), idx, strict=True)}
    flat = int(np.ravel_multi_index(tuple(idx), tuple(v.size for v in dims.values())))
    return flat, coords


def _distinct_times(hist: dict[str, Any]) -> dict[str, Any]:
    """The histories with one sample per time: ``time`` strictly increasing.

    The event method records an impact twice at the same time, the state just before it (the
    end of a smooth piece) and just after (kind 1/2, its impulse applied); only the velocities
    differ. The sample after is kept: the state from the impact on, as every later sample;
    the impulse and the event log say how large the jump was.
    """
    tau = np.asarray(hist.get("tau", ()), dtype=np.float64)
    if tau.size < 2:
        return hist
    keep = np.append(tau[1:] > tau[:-1], True)
    if keep.all():
        return hist
    return {k: v if k == "events" else np.asarray(v)[keep] for k, v in hist.items()}


def _event_columns(events: np.ndarray) -> dict[str, np.ndarray]:
    """The event log as named columns (``column_<i>`` if its layout is not the known one)."""
    ev = np.asarray(events, dtype=np.float64)
    if ev.ndim != 2:  # an empty log (a linear point: no events) has no row length to infer
        ev = ev.reshape(len(ev), -1) if ev.size else ev.reshape(0, len(EVENT_FIELDS))
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
    try:
        write_netcdf(ds, tmp, enc)
        body = Path(tmp).read_bytes()  # small (≤ 50 periods of one point): cached as bytes
    finally:
        os.unlink(tmp)
    disposition = f'attachment; filename="{study_id}-timeseries.nc"'
    return Response(body, media_type=NETCDF, headers={"content-disposition": disposition})
