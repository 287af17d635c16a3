"""Selecting results by coordinate value, and slices as JSON.

Pure numpy + xarray (no web framework, no plotting), so the CLI, the web service and the plots
share one implementation of "which slice of the results is meant".

``sel`` maps a coordinate name to a value (a number or a numeric string, as in a query
string). A value matches a coordinate value within a relative tolerance of 1e-9; with
``nearest=True`` the closest value is taken instead. Every problem raises
:class:`AnalysisError` (a ``ValueError``) whose message names the field, the value and what
is allowed.

JSON: :func:`slice_json` returns plain Python data in which missing or non-finite numbers are
``None`` (:func:`service.studies.dataset.jsonable`), so ``json.dumps(..., allow_nan=False)``
always succeeds.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import xarray as xr

from service.studies.dataset import jsonable
from service.studies.variables import MODEL_AXES, default_x

__all__ = [
    "BRANCH_DIMS",
    "FEW_VALUES",
    "AnalysisError",
    "Selection",
    "View",
    "coordinate_index",
    "default_view",
    "default_y",
    "fixed_slice_json",
    "parse_number",
    "select",
    "slice_axes",
    "slice_csv",
    "slice_json",
    "sweep_x",
    "values_text",
]

_RTOL = 1e-9
_MAX_LISTED = 8  # values listed in full in an error message; longer axes are abbreviated

Selection = Mapping[str, str | float]
_DTYPES = {"f": "float", "i": "int", "u": "int", "b": "bool", "U": "str", "O": "str", "S": "str"}


class AnalysisError(ValueError):
    """A request that does not fit the dataset (unknown variable, coordinate or value)."""


# --------------------------------------------------------------------------- formatting


def _fmt(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.10g}"
    if isinstance(v, (np.integer, np.bool_)):
        return str(v.item())
    return str(v)


def values_text(values: np.ndarray) -> str:
    """Coordinate values for an error message (abbreviated when long)."""
    vals = np.asarray(values).ravel()
    if vals.size <= _MAX_LISTED:
        return ", ".join(_fmt(v) for v in vals)
    head = ", ".join(_fmt(v) for v in vals[:3])
    tail = ", ".join(_fmt(v) for v in vals[-2:])
    return f"{head}, ..., {tail} ({vals.size} values from {_fmt(vals[0])} to {_fmt(vals[-1])})"


def _names(names: Sequence[Any]) -> str:
    return ", ".join(str(n) for n in names) if names else "(none)"


# --------------------------------------------------------------------------- selection


def _variable(ds: xr.Dataset, variable: str) -> xr.DataArray:
    if variable == "pending" and variable not in ds.data_vars and "outcome" in ds.data_vars:
        # A complete dataset has nothing pending: asked of it (a page that saw the study
        # running a moment before it finished), every point is computed.
        return (
            xr.zeros_like(ds["outcome"], dtype=bool)
            .rename("pending")
            .assign_attrs(units="1", long_name="point not computed yet (partial dataset)")
        )
    if variable not in ds.data_vars:
        raise AnalysisError(
            f"variable={variable!r} is not in the results; variables are "
            f"{_names(sorted(str(v) for v in ds.data_vars))}"
        )
    return ds[variable]


def parse_number(name: str, raw: Any) -> float:
    """``raw`` (a number or numeric string) as a finite float; else an AnalysisError."""
    if isinstance(raw, bool):
        raise AnalysisError(f"{name}={raw!r} is not a number")
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise AnalysisError(f"{name}={raw!r} is not a number") from None
    if not math.isfinite(value):
        raise AnalysisError(f"{name}={raw!r} is not a finite number")
    return value


def _coordinate(ds: xr.Dataset, name: str) -> xr.DataArray:
    """The coordinate ``name`` of ``ds`` if it can be selected on (a dim or a scalar)."""
    if name in ds.dims:
        return ds[name]  # a dim without a coordinate variable reads as 0, 1, 2, ...
    if name in ds.coords:
        c = ds.coords[name]
        if c.ndim == 0:
            return c
        raise AnalysisError(
            f"{name} is not a dimension of the results (it is derived and varies with "
            f"{_names(list(c.dims))}); select by {_names(list(c.dims))} instead"
        )
    scalars = sorted(str(k) for k, c in ds.coords.items() if c.ndim == 0)
    also = f" and scalar coordinates {_names(scalars)}" if scalars else ""
    raise AnalysisError(
        f"{name} is not a coordinate of the results; dimensions are {_names(list(ds.dims))}{also}"
    )


def _index(name: str, coord: np.ndarray, raw: Any, value: float, nearest: bool) -> int:
    """Position of ``value`` in the 1-d ``coord`` (exact within tolerance, or nearest)."""
    vals = np.asarray(coord)
    if vals.dtype.kind not in "iufb":
        hits = np.flatnonzero(vals.astype(str) == str(raw))
        if hits.size:
            return int(hits[0])
        raise AnalysisError(
            f"{name}={_fmt(raw)} is not a coordinate value; values are {values_text(vals)}"
        )
    f = vals.astype(np.float64)
    hits = np.flatnonzero(np.isclose(f, value, rtol=_RTOL, atol=0.0))
    if hits.size:
        return int(hits[0])
    if nearest:
        return int(np.nanargmin(np.abs(f - value)))
    raise AnalysisError(
        f"{name}={_fmt(raw)} is not a coordinate value; values are {values_text(vals)} "
        "(use nearest=true)"
    )


def select(
    ds: xr.Dataset,
    variable: str,
    sel: Selection | None = None,
    nearest: bool = False,
) -> xr.DataArray:
    """One variable of ``ds`` at the coordinate values in ``sel``.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset (:func:`service.studies.dataset.results_from_records`).
    variable : str
        Name of a data variable.
    sel : mapping, optional
        Coordinate name -> value (number or numeric string). Names must be dimensions of
        ``ds`` or scalar coordinates (a scalar coordinate must match its value); a dimension
        the variable does not have is checked but has no effect.
    nearest : bool
        Take the closest coordinate value instead of requiring a match (rtol 1e-9).

    Returns
    -------
    xarray.DataArray
        The variable with every selected dimension dropped (kept as a scalar coordinate).

    Raises
    ------
    AnalysisError
        Unknown variable or coordinate, non-numeric or unmatched value.
    """
    da = _variable(ds, variable)
    indexers: dict[str, int] = {}
    for name, raw in (sel or {}).items():
        coord = _coordinate(ds, name)
        value = parse_number(name, raw) if coord.dtype.kind in "iufb" else math.nan
        if coord.ndim == 0:
            _index(name, coord.values.reshape(1), raw, value, nearest)
            continue
        i = _index(name, coord.values, raw, value, nearest)
        if name in da.dims:
            indexers[name] = i
    return da.isel(indexers)


def slice_axes(
    ds: xr.Dataset,
    variable: str,
    axes: Sequence[str | None],
    sel: Selection | None = None,
    nearest: bool = False,
) -> xr.DataArray:
    """``variable`` over exactly ``axes`` (in that order), every other dimension selected.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset.
    variable : str
        Name of a data variable.
    axes : sequence of str or None
        Dimensions to keep (``None`` entries are ignored), e.g. ``[y, x]``.
    sel, nearest
        As in :func:`select`. Every other dimension of the variable with more than one value
        must be given in ``sel``; dimensions of size 1 are taken at their only value.

    Returns
    -------
    xarray.DataArray
        Dimensions ``axes``.

    Raises
    ------
    AnalysisError
        An axis that is not a dimension, an axis also in ``sel``, a dimension left unselected.
    """
    da = _variable(ds, variable)
    keep = [a for a in axes if a is not None]
    if len(set(keep)) != len(keep):
        raise AnalysisError(f"axes must be distinct, got {_names(keep)}")
    for a in keep:
        if a not in da.dims:
            hint = ""
            if a in ds.coords and ds.coords[a].ndim > 0:
                hint = f" ({a} is derived and varies with {_names(list(ds.coords[a].dims))})"
            elif a in ds.coords:
                hint = f" ({a} has a single value, {_fmt(ds.coords[a].values.item())})"
            raise AnalysisError(
                f"axis {a!r} is not a dimension of {variable}{hint}; dimensions are "
                f"{_names(list(da.dims))}"
            )
    sel = dict(sel or {})
    clash = [a for a in keep if a in sel]
    if clash:
        raise AnalysisError(
            f"{_names(clash)} is a plot axis and cannot also be selected; remove it from the "
            "selection"
        )
    out = select(ds, variable, sel, nearest)
    rest = [d for d in out.dims if d not in keep]
    missing = [d for d in rest if out.sizes[d] > 1]
    if missing:
        listed = "; ".join(f"{d} (values {values_text(ds[d].values)})" for d in missing)
        raise AnalysisError(f"select a value for every other dimension; missing: {listed}")
    return out.isel({d: 0 for d in rest}).transpose(*keep)


# --------------------------------------------------------------------------- defaults

#: A second axis (hue of a line plot, y of a bandgap map) is preferably one with at most this
#: many values: a legend of more lines is unreadable.
FEW_VALUES = 12
#: Dimensions of sweep and multi-start studies that label a branch (which start, which sweep
#: direction), not a parameter: never a default plot axis, fixed at their first value unless
#: selected or kept (:func:`default_view`).
BRANCH_DIMS: tuple[str, ...] = ("initial", "direction")


class View(NamedTuple):
    """What a figure or a bandgap map shows: ``x``, the second axis ``y`` (a plot's hue; None
    for none), the full selection ``sel`` of every other dimension, and ``fixed``: the
    dimensions the caller left open that were fixed at their first value."""

    x: str
    y: str | None
    sel: dict[str, Any]
    fixed: dict[str, Any]


def _varying(ds: xr.Dataset, variable: str) -> list[str]:
    dims = ds[variable].dims if variable in ds.data_vars else tuple(ds.dims)
    return [str(d) for d in dims if d not in ("stop", "cell") and ds.sizes[d] > 1]


def default_y(
    ds: xr.Dataset, x: str, sel: Selection | None = None, variable: str = "transmittance_db"
) -> str | None:
    """The default second axis: a varying dimension other than ``x`` and the selected ones,
    the first in model order (gap, g1, g2, theta, ...) with at most :data:`FEW_VALUES` values,
    else the first; None when nothing else varies. Plots (hue, map y) and ``/bandgap`` share it.
    """
    chosen = set(sel or {})
    order = {a: i for i, a in enumerate(MODEL_AXES)}
    cands = [
        d for d in _varying(ds, variable) if d != x and d not in chosen and d not in BRANCH_DIMS
    ]
    cands.sort(key=lambda d: order.get(d, len(order)))  # stable: others in dataset order
    few = [d for d in cands if ds.sizes[d] <= FEW_VALUES]
    return (few or cands or [None])[0]


def default_view(
    ds: xr.Dataset,
    variable: str = "transmittance_db",
    x: str | None = None,
    y: str | None = None,
    sel: Selection | None = None,
    *,
    auto_y: bool = True,
    keep: Sequence[str] = (),
) -> View:
    """Fill in what a request left open, so a figure or map needs no parameters at all.

    ``x`` defaults to the frequency axis (:func:`service.studies.variables.default_x`), ``y``
    (when ``auto_y``) to :func:`default_y`; every other varying dimension of ``variable`` that
    ``sel`` does not give and ``keep`` does not name is fixed at its first value and reported
    in ``View.fixed``.
    """
    _variable(ds, variable)
    sel = dict(sel or {})
    if x is None:
        x = default_x(_varying(ds, variable)) or default_x(ds[variable].dims)
    if x is None:
        raise AnalysisError(
            "x is required: neither gamma_r nor frequency_hz is a dimension; dimensions are "
            f"{_names(list(ds[variable].dims))}"
        )
    if y is None and auto_y:
        y = default_y(ds, x, sel, variable)
    fixed: dict[str, Any] = {}
    for d in _varying(ds, variable):
        if d not in (x, y) and d not in sel and d not in keep:
            v = ds[d].values[0]
            fixed[d] = v.item() if hasattr(v, "item") else v
            sel[d] = repr(float(fixed[d])) if ds[d].dtype.kind in "iuf" else str(fixed[d])
    return View(x, y, sel, fixed)


def sweep_x(ds: xr.Dataset, variable: str = "transmittance_db") -> str | None:
    """The swept axis of a sweep study (attribute ``sweep_axis``) when it is a varying
    dimension of ``variable``; else None (callers then take the default x)."""
    axis = ds.attrs.get("sweep_axis")
    if axis is None or str(axis) == "":
        return None
    return str(axis) if str(axis) in _varying(ds, variable) else None


# --------------------------------------------------------------------------- JSON


def coordinate_index(name: str, values: np.ndarray, raw: Any, nearest: bool = False) -> int:
    """Position of the value ``raw`` among a coordinate's ``values`` (the rule of :func:`select`).

    Raises
    ------
    AnalysisError
        Naming the coordinate, the value and the values allowed.
    """
    vals = np.asarray(values)
    value = parse_number(name, raw) if vals.dtype.kind in "iufb" else math.nan
    return _index(name, vals, raw, value, nearest)


def fixed_slice_json(
    da: xr.DataArray, fixed: Mapping[str, Any], skip: Sequence[str] = ()
) -> dict[str, dict[str, Any]]:
    """The scalar coordinates a map or curve was taken at, for its JSON ``slice``: value,
    units, long name and whether the axis was fixed by default (in ``fixed``)."""
    return {
        str(k): {
            "value": jsonable(c.values),
            "units": str(c.attrs.get("units", "")),
            "long_name": str(c.attrs.get("long_name", "")),
            "default": str(k) in fixed,
        }
        for k, c in da.coords.items()
        if c.ndim == 0 and k not in skip
    }


def slice_json(da: xr.DataArray) -> dict[str, Any]:
    """A selection as JSON-ready data.

    Returns
    -------
    dict
        ``variable``, ``units``, ``long_name``, ``dims``, ``coords`` (every coordinate with
        dimensions, as (nested) lists), ``coord_dims`` (their dimensions), ``scalars``
        (0-d coordinates, e.g. the selected values) and ``values`` (nested lists). Missing and
        non-finite numbers are ``None``. A CF flag variable (``outcome``) also gives
        ``flag_values`` and ``flag_meanings`` (lists, in the same order).
    """
    coords: dict[str, Any] = {}
    coord_dims: dict[str, list[str]] = {}
    scalars: dict[str, Any] = {}
    for name, c in da.coords.items():
        if c.ndim == 0:
            scalars[str(name)] = jsonable(c.values)
        else:
            coords[str(name)] = jsonable(c.values)
            coord_dims[str(name)] = [str(d) for d in c.dims]
    for d in da.dims:  # dims without a coordinate variable
        if d not in coords:
            coords[str(d)] = list(range(da.sizes[d]))
            coord_dims[str(d)] = [str(d)]
    out = {
        "variable": None if da.name is None else str(da.name),
        "dtype": _DTYPES.get(da.dtype.kind, "str"),
        "units": str(da.attrs.get("units", "")),
        "long_name": str(da.attrs.get("long_name", "")),
        "dims": [str(d) for d in da.dims],
        "coords": coords,
        "coord_dims": coord_dims,
        "scalars": scalars,
        "values": jsonable(da.values),
    }
    if "flag_meanings" in da.attrs:
        out["flag_values"] = jsonable(np.atleast_1d(da.attrs.get("flag_values", [])))
        out["flag_meanings"] = str(da.attrs["flag_meanings"]).split()
    return out


def _csv_cells(a: np.ndarray) -> list[str]:
    """Flat CSV fields of an array: empty for missing, ``repr`` precision for floats."""
    flat = np.asarray(a).ravel()
    if flat.dtype.kind == "f":
        return ["" if not math.isfinite(v) else repr(v) for v in flat.tolist()]
    if flat.dtype.kind == "b":
        return ["true" if v else "false" for v in flat.tolist()]
    return ["" if v is None else str(v) for v in flat.tolist()]


def slice_csv(da: xr.DataArray) -> str:
    """A selection as CSV text in long form: one row per value.

    Columns: one per dimension (its coordinate value), then the variable (named as it is),
    then one per 0-d coordinate (the selected and fixed values, constant). Missing values are
    empty fields, booleans ``true``/``false``, and a CF flag variable (``outcome``) is written
    as its meanings (``linear``, ``periodic``, …), not its codes.
    """
    name = "value" if da.name is None else str(da.name)
    values = da.values
    meanings = str(da.attrs.get("flag_meanings", "")).split()
    if meanings:
        flags = np.asarray(da.attrs.get("flag_values", np.arange(len(meanings)))).ravel()
        table = dict(zip(flags.tolist(), meanings, strict=False))
        values = np.vectorize(lambda v: table.get(int(v), str(v)), otypes=[object])(values)
    dims = [str(d) for d in da.dims]
    grids = np.meshgrid(
        *[da[d].values if d in da.coords else np.arange(da.sizes[d]) for d in dims],
        indexing="ij",
    )
    columns = [_csv_cells(g) for g in grids] + [_csv_cells(values)]
    scalars = {str(k): c for k, c in da.coords.items() if c.ndim == 0}
    const = [_csv_cells(c.values.reshape(1))[0] for c in scalars.values()]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*dims, name, *scalars])
    for row in zip(*columns, strict=True) if columns else ():
        w.writerow([*row, *const])
    return buf.getvalue()
