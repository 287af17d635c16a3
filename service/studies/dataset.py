"""Results datasets: collation of per-point results into xarray, NetCDF encoding, JSON.

A study's results are one dataset: one dimension per varying axis (after ``initial`` and
``direction`` for a study with several initial states or a sweep), CF ``units`` and
``long_name`` on every coordinate and variable (:mod:`service.studies.variables`), and the
study definition, its id, the code's provenance (:mod:`service.studies.provenance`) and the
solver settings as global attributes.

Missing values: a failed point has ``failed = 1``, ``outcome = failed``, a ``reason``, and every
measured variable missing. Some values are missing by nature at points that did not fail:
``transmittance_db_se`` (only irregular and unsettled points have one), ``floquet_multiplier``
(only linear and periodic points), ``impacting_periods`` (only points flagged
``may_be_transient``), ``theta_eff_slope`` (where the phase portrait has no slope),
``transmittance_linear_db`` and ``impact_effect_db`` (no closed form: an undamped resonance; or
a chunk written before they existed). ``transmittance_linear_db`` is a property of the cell and
is kept at failed points; ``impact_effect_db`` is missing there.
Floats are NaN in memory and the netCDF ``_FillValue`` on disk (no NaN is written); integer
variables that can be missing (``response_period``, ``impacting_periods``, ``steady_period``) are
stored as int32 with ``_FillValue = -1`` and read back by xarray as float with NaN.

JSON: NaN is never written. :func:`jsonable` and :func:`json_number` turn missing and
non-finite numbers into ``None``, and :func:`json_text` refuses any NaN that slipped through.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import threading
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from service.studies.coexistence import count_responses
from service.studies.provenance import provenance_attrs
from service.studies.schema import Study
from service.studies.variables import (
    AXES,
    CHAIN_VARIABLES,
    MISSING_INT,
    PHYSICAL_VARIABLES,
    STOP_VARIABLES,
    SWEEP_VARIABLES,
    VARIABLES,
    cell_coordinate,
    outcome_counts,
    outcome_names,
    result_values,
    stop_coordinate,
)
from worker.simulate import POINT_KEYS, SOLVER_VERSION

__all__ = [
    "FILL_FLOAT",
    "FILL_INT",
    "PENDING",
    "encoding",
    "lattice_stop_bands",
    "json_number",
    "json_text",
    "jsonable",
    "NETCDF_LOCK",
    "open_results",
    "results_from_records",
    "summarize",
    "write_netcdf",
]

FILL_FLOAT = 9.969209968386869e36  # netCDF's default double fill (NC_FILL_DOUBLE)
FILL_INT = MISSING_INT
PENDING = "pending: not computed yet"  # reason of points a partial dataset does not have yet
# Model parameters a physical study's dataset carries as coordinates beside the SI axes.
_DERIVED = ("gamma_r", "theta", "sigma", "gamma_s", "xi", "g1", "g2")


# --------------------------------------------------------------------------- collation


def _attrs(name: str) -> dict[str, str]:
    info = AXES[name]
    return {"units": info.units, "long_name": info.long_name}


#: Axes along which the infinite lattice of a chain study's cell stays the same (its stop
#: bands are those of the stop-free cell, in γ_r).
_LATTICE_FREE_AXES = frozenset({"cells", "gamma_r", "gap", "g1", "g2"})


def lattice_stop_bands(study: Study) -> list[tuple[float, float]] | None:
    """The stop bands (γ_r) of the infinite lattice of a chain study's cell, or ``None`` where
    the study has no single cell (σ graded or varied, θ, γ_s, ξ varied)."""
    from worker.model import CellParams
    from worker.model.chain import stop_bands

    if study.model.sigmas is not None or not set(study.dims()) <= _LATTICE_FREE_AXES:
        return None
    point = study.points(0, 1, grid=True)[0]
    return stop_bands(CellParams(**{k: point[k] for k in POINT_KEYS if k in point}))


def results_from_records(
    study: Study,
    cols: Mapping[str, np.ndarray],
    *,
    created: str | None = None,
    computed: np.ndarray | None = None,
) -> xr.Dataset:
    """Collate flat per-point arrays (work order, :meth:`Study.work_indices`: the grid's C
    order for a study without a sweep) into a Dataset.

    Dimensions: ``initial`` (several initial states), ``direction`` (a sweep), then the varying
    grid axes. A sweep adds ``started_from``; a study with an ``initial`` or ``direction``
    dimension adds ``responses`` (:func:`service.studies.coexistence.count_responses`).
    ``computed`` (a flat mask) marks a partial dataset: it adds a ``pending`` variable and the
    global attributes ``partial = 1`` and ``points_done``.
    """
    dims_map = study.result_dims()
    dims = tuple(dims_map)
    shape = study.shape
    grid_dims = tuple(study.dims())
    grid_shape = study.grid_shape
    if study.sweep is not None:
        # Work order -> the results' C order (a sweep's lines run along the swept axis).
        where = study.result_index(0, study.size)
        cols = {k: _to_result_order(np.asarray(v), where) for k, v in cols.items()}
        if computed is not None:
            computed = _to_result_order(np.asarray(computed), where)
    coords: dict[str, Any] = {k: (k, v, _attrs(k)) for k, v in dims_map.items()}
    for k, v in study.scalars().items():
        coords[k] = ((), v, _attrs(k))
    if study.initial is not None and study.n_initial == 1:
        coords["initial"] = ((), study.initial_labels()[0], _attrs("initial"))
    coords["stop"] = stop_coordinate()
    if study.is_physical:
        # Results carry the model's parameters too (γ_r next to Hz, and the rest).
        pts = study.points(0, study.grid_size, grid=True)
        cells = study.cells(0, study.grid_size, grid=True)
        derived = {k: np.array([p[k] for p in pts], dtype=np.float64) for k in _DERIVED}
        # U_g of each point: per frequency (a table, base acceleration) or the cell's own.
        derived["base_amplitude_m"] = np.array([c.base_amplitude_at(f) for c, f in cells])
        for k, v in derived.items():
            attrs = dict(_attrs(k))
            attrs["long_name"] += " (derived from the physical cell, docs/model.md section 8)"
            if k in coords:
                continue
            arr, kept = v.reshape(grid_shape), list(grid_dims)
            for ax in reversed(range(len(grid_dims))):  # keep only the dims it varies along
                if np.all(arr == arr.take([0], axis=ax)):
                    arr = arr.take(0, axis=ax)
                    kept.pop(ax)
            coords[k] = (tuple(kept), arr, attrs) if kept else ((), float(arr), attrs)

    failed = np.asarray(cols["failed"], dtype=bool)
    groups = {g for g, on in study.outputs.model_dump().items() if on} | {""}
    data_vars: dict[str, Any] = {}
    for name, var in VARIABLES.items():
        if var.group not in groups:
            continue
        a, attrs = result_values(name, cols[name], failed)
        if name in STOP_VARIABLES:
            data_vars[name] = ((*dims, "stop"), a.reshape(*shape, 2), attrs)
        else:
            data_vars[name] = (dims, a.reshape(shape), attrs)
    longest = study.max_cells()
    if longest > 1:  # a chain study: per-cell variables along ``cell``
        coords["cell"] = cell_coordinate(longest)
        if study.model.cells is not None:
            coords["cells"] = ((), np.int32(longest), _attrs("cells"))
        for name, var in CHAIN_VARIABLES.items():
            if var.group in groups and name in cols:
                a, attrs = result_values(name, cols[name], failed)
                data_vars[name] = ((*dims, "cell"), a.reshape(*shape, longest), attrs)
    if study.is_physical and "amplitude" in data_vars:
        # Metres as well as units of B; B = U_g/(θγ_s) differs from point to point.
        scale = np.array([c.length_scale_m(f) for c, f in cells]).reshape(grid_shape)
        var = PHYSICAL_VARIABLES["amplitude_m"]
        attrs = {"units": var.units, "long_name": var.long_name}
        data_vars["amplitude_m"] = (dims, data_vars["amplitude"][1] * scale, attrs)
    if study.sweep is not None:
        var = SWEEP_VARIABLES["started_from"]
        a = np.array([str(x) for x in cols["started_from"]], dtype=object)
        data_vars["started_from"] = (
            dims, a.reshape(shape), {"units": var.units, "long_name": var.long_name}
        )  # fmt: skip
    provenance = provenance_attrs()
    bands = lattice_stop_bands(study) if longest > 1 else None
    attrs = {
        "Conventions": "CF-1.8",
        "title": f"impactcell study {study.name}",
        "study_name": study.name,
        "study_id": study.id,
        "study": study.canonical_json(),
        "impactcell_version": provenance.pop("impactcell_version"),
        "solver_version": SOLVER_VERSION,
        "solver_settings": json.dumps(asdict(study.solver.settings()), sort_keys=True),
        "git_commit": provenance.pop("git_commit"),
        **provenance,  # git_dirty, and the versions of numpy, numba, xarray and dask
        "created": created or _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "source": "impactcell simulation of an impacting beam-in-mass metamaterial cell",
        "comment": (
            "failed = 1 marks a point that could not be computed; its measured variables are "
            "missing (_FillValue) and reason says why"
        ),
    }
    if bands is not None:
        # JSON text: a band open to gamma_r -> inf has null as its upper edge
        attrs["lattice_stop_bands"] = json.dumps(
            [[lo, hi if math.isfinite(hi) else None] for lo, hi in bands]
        )
    if computed is not None:
        data_vars["pending"] = (
            dims,
            ~np.asarray(computed, dtype=bool).reshape(shape),
            {"units": "1", "long_name": "point not computed yet (partial dataset)"},
        )
        attrs["partial"] = np.int8(1)
        attrs["points_done"] = int(np.sum(computed))
        attrs["comment"] += "; partial dataset: pending = 1 marks points not computed yet"
    if study.is_extended:
        attrs["initial_states"] = " ".join(study.initial_labels())
        if study.sweep is not None:
            attrs["sweep_axis"] = study.sweep.axis
            attrs["sweep_directions"] = " ".join(study.directions())
    ds = xr.Dataset(data_vars, coords=coords, attrs=attrs)
    if "outcome" in ds and any(d in ds.dims for d in ("initial", "direction")):
        tol = study.outputs.tol_db()
        ds["responses"] = count_responses(ds, tol)
        ds.attrs["coexistence_tol_db"] = tol
    return ds


def _to_result_order(a: np.ndarray, where: np.ndarray) -> np.ndarray:
    """Per-point values in work order placed at their results' flat index ``where``."""
    out = np.empty_like(a)
    out[where] = a
    return out


# --------------------------------------------------------------------------- NetCDF


def encoding(ds: xr.Dataset) -> dict[str, dict[str, Any]]:
    """NetCDF encoding: zlib everywhere it applies, fill values for missing, no NaN on disk."""
    enc: dict[str, dict[str, Any]] = {}
    for name in ds.data_vars:
        var = VARIABLES.get(str(name)) or SWEEP_VARIABLES.get(str(name))
        dt = ds[name].dtype
        kind = var.kind if var else {"O": "str", "b": "bool", "i": "int"}.get(dt.kind, "float")
        if kind == "str":
            enc[str(name)] = {}  # variable-length strings take no compression filter
        elif kind == "maskint":
            enc[str(name)] = {"dtype": "int32", "_FillValue": FILL_INT, "zlib": True}
        elif kind == "float":
            enc[str(name)] = {"_FillValue": FILL_FLOAT, "zlib": True}
        elif kind == "flag":
            enc[str(name)] = {"dtype": "int8", "_FillValue": None, "zlib": True}  # never missing
        else:
            enc[str(name)] = {"zlib": True}
    for name in ds.coords:
        if ds[name].dtype.kind == "f":
            enc[str(name)] = {"_FillValue": None}  # coordinates are never missing
    return enc


#: Held by every NetCDF read and write of this process. The netCDF-C and HDF5 libraries are
#: not thread-safe, and xarray's own lock is released between its calls into them (reading a
#: file's attributes, for one), so the service's threads (the runner writing a results file,
#: a request or the nightly reading another) crashed the process when they met.
NETCDF_LOCK = threading.RLock()


def open_results(path: str | os.PathLike[str]) -> xr.Dataset:
    """Open a results file fully into memory (the file is closed afterwards)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no such results file: {p}")
    try:
        with NETCDF_LOCK, xr.open_dataset(p, engine="netcdf4") as ds:
            return ds.load()
    except OSError as exc:
        raise ValueError(f"{p} is not a readable NetCDF file: {exc}") from None


def write_netcdf(
    ds: xr.Dataset, path: str | os.PathLike[str], enc: Mapping[str, Any] | None = None
) -> None:
    """Write ``ds`` as NetCDF4 to ``path`` (``enc``: its encoding), under :data:`NETCDF_LOCK`."""
    with NETCDF_LOCK:
        ds.to_netcdf(path, engine="netcdf4", encoding=dict(enc) if enc else None)


# --------------------------------------------------------------------------- counts


def summarize(ds: xr.Dataset, outcomes: Any = None) -> dict[str, int]:
    """Counts of a results dataset: ``points``, ``failed``, and points by outcome when known.

    The outcomes are the dataset's ``outcome`` variable, or ``outcomes`` (names, one per point)
    for a dataset that does not store it; without either, only ``points`` and ``failed``.
    """
    failed = ds["failed"].values.astype(bool)
    out = {"points": int(failed.size), "failed": int(failed.sum())}
    if outcomes is None and "outcome" in ds:
        outcomes = outcome_names(ds["outcome"])
    if outcomes is not None:
        out.update(outcome_counts(outcomes))
    return out


# --------------------------------------------------------------------------- JSON


def jsonable(a: Any) -> Any:
    """Nested lists of plain Python values; NaN and ±inf become None."""
    arr = np.asarray(a)
    if arr.dtype.kind == "f":
        obj = arr.astype(object)
        obj[~np.isfinite(arr)] = None
        return obj.tolist()
    if arr.dtype.kind in "iub":
        return arr.tolist()
    if arr.dtype.kind == "c":
        raise ValueError("complex values cannot be written as JSON")
    if arr.dtype.kind == "M":
        return np.datetime_as_string(arr).tolist()
    return np.vectorize(lambda v: None if v is None else str(v), otypes=[object])(arr).tolist()


def json_number(x: Any) -> float | int | None:
    """One number, JSON-safe: ``None`` for missing or non-finite, an int when it is whole."""
    if x is None:
        return None
    v = float(x)
    if not math.isfinite(v):
        return None
    return int(v) if v.is_integer() and abs(v) < 2**53 else v


def json_text(payload: Any, **kwargs: Any) -> str:
    """``json.dumps`` that refuses NaN: one that slipped through is a bug, never a result."""
    return json.dumps(payload, allow_nan=False, **kwargs)
