"""Analysis of results datasets: selection by coordinate value, JSON slices, bandgap maps.

Pure numpy + xarray (no web framework, no plotting), so the CLI, the web service and the plots
share one implementation of "which slice of the results is meant" and "where are the bands".

Selections
    ``sel`` maps a coordinate name to a value (a number or a numeric string, as in a query
    string). A value matches a coordinate value within a relative tolerance of 1e-9; with
    ``nearest=True`` the closest value is taken instead. Every problem raises
    :class:`AnalysisError` (a ``ValueError``) whose message names the field, the value and what
    is allowed.

Bands
    A band (attenuation band, bandgap) is a maximal interval of ``x`` where the transmittance
    Γ is below ``threshold_db`` (strictly). Its edges are located by linear interpolation of Γ
    between the neighbouring grid points on either side of the crossing. Each edge has a kind:

    ``crossing``
        Γ crosses the threshold between two known grid points; the edge is interpolated.
    ``grid_end``
        The band reaches the first or last grid point; the edge is that grid end (the true
        edge lies beyond the grid).
    ``missing``
        The neighbouring grid point is missing (a failed point, NaN). Missing values are
        *unknown*: a band is never extended across a missing point, and its edge is put at the
        last known below-threshold point. So ``[-1, NaN, -1]`` gives two bands, each with a
        ``missing`` edge next to the NaN.

JSON
    Every ``*_json`` function returns plain Python data in which missing or non-finite numbers
    are ``None``, so ``json.dumps(..., allow_nan=False)`` always succeeds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import xarray as xr

__all__ = [
    "EDGE_KINDS",
    "AnalysisError",
    "coordinate_index",
    "jsonable",
    "values_text",
    "Band",
    "band_edges",
    "bandgap_json",
    "bandgap_map",
    "select",
    "slice_axes",
    "slice_json",
]

#: Edge kinds, in the order of their integer codes in :func:`bandgap_map`'s dataset.
EDGE_KINDS: tuple[str, ...] = ("crossing", "grid_end", "missing")

_RTOL = 1e-9
_MAX_LISTED = 8  # values listed in full in an error message; longer axes are abbreviated

Selection = Mapping[str, str | float]


class AnalysisError(ValueError):
    """A request that does not fit the dataset (unknown variable, coordinate or value)."""


class Band(NamedTuple):
    """One band: ``start <= stop`` in units of x, and the kind of each edge (``EDGE_KINDS``)."""

    start: float
    stop: float
    start_edge: str
    stop_edge: str


# --------------------------------------------------------------------------- formatting


def _fmt(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.10g}"
    if isinstance(v, (np.integer, np.bool_)):
        return str(v.item())
    return str(v)


def _values_text(values: np.ndarray) -> str:
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


def _number(name: str, raw: Any) -> float:
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
            f"{name}={_fmt(raw)} is not a coordinate value; values are {_values_text(vals)}"
        )
    f = vals.astype(np.float64)
    hits = np.flatnonzero(np.isclose(f, value, rtol=_RTOL, atol=0.0))
    if hits.size:
        return int(hits[0])
    if nearest:
        return int(np.nanargmin(np.abs(f - value)))
    raise AnalysisError(
        f"{name}={_fmt(raw)} is not a coordinate value; values are {_values_text(vals)} "
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
        A results dataset (:func:`service.store.results_from_records`).
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
        value = _number(name, raw) if coord.dtype.kind in "iufb" else math.nan
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
        listed = "; ".join(f"{d} (values {_values_text(ds[d].values)})" for d in missing)
        raise AnalysisError(f"select a value for every other dimension; missing: {listed}")
    return out.isel({d: 0 for d in rest}).transpose(*keep)


# --------------------------------------------------------------------------- JSON


def _jsonable(a: Any) -> Any:
    """Nested lists of plain Python values; NaN and ±inf become None."""
    arr = np.asarray(a)
    if arr.dtype.kind == "f":
        obj = arr.astype(object)
        obj[~np.isfinite(arr)] = None
        return obj.tolist()
    if arr.dtype.kind in "iub":
        return arr.tolist()
    if arr.dtype.kind == "c":
        raise AnalysisError("complex values cannot be written as JSON")
    if arr.dtype.kind == "M":
        return np.datetime_as_string(arr).tolist()
    return np.vectorize(lambda v: None if v is None else str(v), otypes=[object])(arr).tolist()


def coordinate_index(name: str, values: np.ndarray, raw: Any, nearest: bool = False) -> int:
    """Position of the value ``raw`` among a coordinate's ``values`` (the rule of :func:`select`).

    Raises
    ------
    AnalysisError
        Naming the coordinate, the value and the values allowed.
    """
    vals = np.asarray(values)
    value = _number(name, raw) if vals.dtype.kind in "iufb" else math.nan
    return _index(name, vals, raw, value, nearest)


def values_text(values: np.ndarray) -> str:
    """A coordinate's values for an error message (shortened when long)."""
    return _values_text(values)


def jsonable(a: Any) -> Any:
    """Nested lists of plain Python values; NaN and ±inf become None."""
    return _jsonable(a)


def _scalar_json(v: Any) -> Any:
    return _jsonable(np.asarray(v).reshape(()))


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
            scalars[str(name)] = _scalar_json(c.values)
        else:
            coords[str(name)] = _jsonable(c.values)
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
        "values": _jsonable(da.values),
    }
    if "flag_meanings" in da.attrs:
        out["flag_values"] = _jsonable(np.atleast_1d(da.attrs.get("flag_values", [])))
        out["flag_meanings"] = str(da.attrs["flag_meanings"]).split()
    return out


# --------------------------------------------------------------------------- bands


def _crossing(x0: float, g0: float, x1: float, g1: float, threshold: float) -> float:
    """Where the straight line through (x0, g0), (x1, g1) reaches ``threshold``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (threshold - g0) / (g1 - g0)
    if not math.isfinite(t):  # an infinite Γ: no slope to interpolate along
        t = 0.5
    t = min(max(t, 0.0), 1.0)
    return float(x0 + t * (x1 - x0))


def band_edges(
    x: Sequence[float] | np.ndarray, gamma: Any, threshold_db: float = 0.0
) -> list[Band]:
    """Intervals of ``x`` where ``gamma < threshold_db``, edges linearly interpolated.

    Parameters
    ----------
    x : array_like
        Strictly increasing grid, 1-d.
    gamma : array_like
        Γ at ``x`` (dB); NaN marks a missing point (see the module doc).
    threshold_db : float
        Γ strictly below it is attenuating.

    Returns
    -------
    list of Band
        In increasing order of ``x``, disjoint.

    Examples
    --------
    >>> band_edges([0, 1, 2, 3, 4], [1, -1, -3, 1, 2])
    [Band(start=0.5, stop=2.75, start_edge='crossing', stop_edge='crossing')]
    """
    xs = np.asarray(x, dtype=np.float64)
    g = np.asarray(gamma, dtype=np.float64)
    if xs.ndim != 1 or g.shape != xs.shape:
        raise AnalysisError(f"x and gamma must be 1-d of one length, got {xs.shape}, {g.shape}")
    if xs.size > 1 and not np.all(np.diff(xs) > 0):
        raise AnalysisError("x must be strictly increasing")
    thr = float(threshold_db)
    if not math.isfinite(thr):
        raise AnalysisError(f"threshold_db={threshold_db!r} is not a finite number")
    below = ~np.isnan(g) & (g < thr)
    known = ~np.isnan(g)
    n = xs.size
    edges = np.flatnonzero(np.diff(np.r_[0, below.view(np.int8), 0]))
    out: list[Band] = []
    for i, j in zip(edges[::2], edges[1::2] - 1, strict=True):  # run of below points i..j
        if i == 0:
            start, start_edge = float(xs[0]), "grid_end"
        elif not known[i - 1]:
            start, start_edge = float(xs[i]), "missing"
        else:
            start, start_edge = _crossing(xs[i - 1], g[i - 1], xs[i], g[i], thr), "crossing"
        if j == n - 1:
            stop, stop_edge = float(xs[-1]), "grid_end"
        elif not known[j + 1]:
            stop, stop_edge = float(xs[j]), "missing"
        else:
            stop, stop_edge = _crossing(xs[j], g[j], xs[j + 1], g[j + 1], thr), "crossing"
        out.append(Band(start, stop, start_edge, stop_edge))
    return out


def bandgap_map(
    ds: xr.Dataset,
    x: str,
    y: str | None = None,
    threshold_db: float = 0.0,
    sel: Selection | None = None,
    nearest: bool = False,
) -> xr.Dataset:
    """Transmittance over ``x`` (× ``y``) with the attenuating region and band edges.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset with ``transmittance_db``.
    x : str
        Dimension along which bands are found (e.g. ``gamma_r`` or ``frequency_hz``).
    y : str, optional
        Second dimension (e.g. ``gap``); bands are found for each of its values. Omit for a
        1-d map.
    threshold_db : float
        Γ strictly below it is attenuating.
    sel, nearest
        Values of every other dimension (see :func:`slice_axes`).

    Returns
    -------
    xarray.Dataset
        Sorted by ``x`` (and ``y``), with ``transmittance_db`` and ``attenuating`` (False where
        Γ is missing) over (y, x); ``band_start``, ``band_stop`` (NaN-padded) and
        ``band_start_edge``, ``band_stop_edge`` (codes into :data:`EDGE_KINDS`, -1 as padding)
        over (y, band); ``band_count`` over y. Attributes ``threshold_db``, ``x``, ``y`` (``""``
        for a 1-d map).
    """
    thr = _number("threshold_db", threshold_db)
    if y is not None and y == x:
        raise AnalysisError(f"x and y must differ, both are {x!r}")
    gamma = slice_axes(ds, "transmittance_db", [y, x], sel, nearest)
    gamma = gamma.sortby(x) if y is None else gamma.sortby([y, x])
    xv = gamma[x].values.astype(np.float64)
    rows = gamma.values.reshape(-1, xv.size)
    bands = [band_edges(xv, row, thr) for row in rows]
    nb = max((len(b) for b in bands), default=0)
    start = np.full((len(rows), nb), np.nan)
    stop = np.full((len(rows), nb), np.nan)
    start_edge = np.full((len(rows), nb), -1, dtype=np.int8)
    stop_edge = np.full((len(rows), nb), -1, dtype=np.int8)
    for r, row_bands in enumerate(bands):
        for k, b in enumerate(row_bands):
            start[r, k], stop[r, k] = b.start, b.stop
            start_edge[r, k] = EDGE_KINDS.index(b.start_edge)
            stop_edge[r, k] = EDGE_KINDS.index(b.stop_edge)
    counts = np.array([len(b) for b in bands], dtype=np.int64)
    ydims: tuple[str, ...] = () if y is None else (y,)
    if y is None:
        start, stop, start_edge, stop_edge = start[0], stop[0], start_edge[0], stop_edge[0]
        counts = counts.reshape(())
    xattrs = dict(gamma[x].attrs)
    edge_attrs = {
        "flag_values": np.arange(len(EDGE_KINDS), dtype=np.int8),
        "flag_meanings": " ".join(EDGE_KINDS),
        "comment": "-1 pads rows with fewer bands",
    }
    data_vars = {
        "transmittance_db": gamma,
        "attenuating": (
            gamma.dims,
            np.asarray(gamma.notnull() & (gamma < thr)),
            {"long_name": f"transmittance below {thr:g} dB (False where missing)"},
        ),
        "band_start": (
            (*ydims, "band"),
            start,
            {"units": xattrs.get("units", ""), "long_name": f"lower edge of the band in {x}"},
        ),
        "band_stop": (
            (*ydims, "band"),
            stop,
            {"units": xattrs.get("units", ""), "long_name": f"upper edge of the band in {x}"},
        ),
        "band_start_edge": ((*ydims, "band"), start_edge, dict(edge_attrs)),
        "band_stop_edge": ((*ydims, "band"), stop_edge, dict(edge_attrs)),
        "band_count": (ydims, counts, {"long_name": f"number of bands along {x}"}),
    }
    out = xr.Dataset(data_vars, coords={"band": np.arange(nb)})
    out.attrs = {
        "threshold_db": thr,
        "x": x,
        "y": y or "",
        "title": f"transmittance bands along {x}" + (f" for each {y}" if y else ""),
    }
    return out


def bandgap_json(ds_map: xr.Dataset) -> dict[str, Any]:
    """A :func:`bandgap_map` as JSON-ready data.

    Returns
    -------
    dict
        ``x``, ``y`` (names; ``y`` None for a 1-d map), ``threshold_db``, ``dims``, ``coords``
        (x and y values), ``units``, ``long_names``, ``scalars`` (the selected values),
        ``transmittance_db`` (None for missing), ``attenuating`` and ``edges``: one
        ``{"y": value, "bands": [[start, stop], ...], "kinds": [[start_kind, stop_kind], ...]}``
        per y value (a single entry with ``"y": None`` for a 1-d map).
    """
    x = str(ds_map.attrs["x"])
    y = str(ds_map.attrs.get("y") or "") or None
    gamma = ds_map["transmittance_db"]
    axes = [a for a in (x, y) if a is not None]
    coords = {a: _jsonable(ds_map[a].values) for a in axes}
    scalars = {
        str(k): _scalar_json(c.values)
        for k, c in gamma.coords.items()
        if c.ndim == 0 and k not in ("band",)
    }
    starts = np.atleast_2d(ds_map["band_start"].values)
    stops = np.atleast_2d(ds_map["band_stop"].values)
    s_edge = np.atleast_2d(ds_map["band_start_edge"].values)
    e_edge = np.atleast_2d(ds_map["band_stop_edge"].values)
    counts = np.atleast_1d(ds_map["band_count"].values)
    yvals = ds_map[y].values if y is not None else [None]
    edges = []
    for r, yv in enumerate(yvals):
        n = int(counts[r])
        edges.append(
            {
                "y": None if yv is None else _scalar_json(yv),
                "bands": [[float(starts[r, k]), float(stops[r, k])] for k in range(n)],
                "kinds": [[EDGE_KINDS[s_edge[r, k]], EDGE_KINDS[e_edge[r, k]]] for k in range(n)],
            }
        )
    return {
        "x": x,
        "y": y,
        "threshold_db": float(ds_map.attrs["threshold_db"]),
        "dims": [str(d) for d in gamma.dims],
        "coords": coords,
        "units": {a: str(ds_map[a].attrs.get("units", "")) for a in axes},
        "long_names": {a: str(ds_map[a].attrs.get("long_name", "")) for a in axes},
        "scalars": scalars,
        "transmittance_db": _jsonable(gamma.values),
        "attenuating": _jsonable(ds_map["attenuating"].values),
        "edges": edges,
    }
