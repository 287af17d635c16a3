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

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import xarray as xr

from service.studies.dataset import jsonable

__all__ = [
    "AnalysisError",
    "Selection",
    "coordinate_index",
    "parse_number",
    "select",
    "slice_axes",
    "slice_json",
    "values_text",
]

_RTOL = 1e-9
_MAX_LISTED = 8  # values listed in full in an error message; longer axes are abbreviated

Selection = Mapping[str, str | float]


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
