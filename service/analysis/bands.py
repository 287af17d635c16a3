"""Bands: where the transmittance is below a threshold, and bandgap maps.

A band (attenuation band, bandgap) is a maximal interval of ``x`` where the transmittance Γ is
below ``threshold_db`` (strictly). Its edges are located by linear interpolation of Γ between
the neighbouring grid points on either side of the crossing. Each edge has a kind:

``crossing``
    Γ crosses the threshold between two known grid points; the edge is interpolated.
``grid_end``
    The band reaches the first or last grid point; the edge is that grid end (the true edge
    lies beyond the grid).
``missing``
    The neighbouring grid point is missing (a failed point, NaN). Missing values are
    *unknown*: a band is never extended across a missing point, and its edge is put at the last
    known below-threshold point. So ``[-1, NaN, -1]`` gives two bands, each with a ``missing``
    edge next to the NaN.

Selections of the other axes are those of :mod:`service.analysis.selection`; :func:`bandgap_json`
returns plain Python data in which missing or non-finite numbers are ``None``.

Which quantity a map shows is ``variable`` (:data:`MAP_VARIABLES`), always with the same rule
"in a band where the value < ``threshold_db``":

``transmittance_db``
    Γ of the cell with its stops (default threshold 0 dB): where the cell attenuates.
``transmittance_linear_db``
    Γ_lin of the same cell without stops (closed form; default 0 dB): the linear cell's bands,
    e.g. base isolation above γ_r ≈ √2 in the paper coupling.
``impact_effect_db``
    Γ − Γ_lin (default threshold −1 dB): where the impacts add more than 1 dB of attenuation
    compared to the cell without stops. Bands of Γ that are not bands of this map are the
    linear cell's own.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import xarray as xr

from service.analysis.selection import (
    AnalysisError,
    Selection,
    fixed_slice_json,
    parse_number,
    slice_axes,
)
from service.studies.dataset import jsonable

__all__ = [
    "EDGE_KINDS",
    "MAP_VARIABLES",
    "Band",
    "band_edges",
    "bandgap_csv",
    "bandgap_json",
    "bandgap_map",
    "default_threshold",
    "threshold_meaning",
]

#: Edge kinds, in the order of their integer codes in :func:`bandgap_map`'s dataset.
EDGE_KINDS: tuple[str, ...] = ("crossing", "grid_end", "missing", "located", "uncertain")
_EDGE_MEANINGS = (
    "interpolated linearly between the grid points on either side of the threshold",
    "the band reaches the end of the grid; the true edge lies beyond it",
    "the neighbouring grid point is missing (failed); the edge is the last known point",
    "located by an adaptive study to its tolerance (the edge lies in its interval)",
    "an adaptive study could only bound it: the confidence band of irregular points straddles "
    "the threshold (or failed points hide the crossing); the edge lies in its interval",
)


#: Variables a bandgap map can show, with their default thresholds (dB).
MAP_VARIABLES: dict[str, float] = {
    "transmittance_db": 0.0,
    "transmittance_linear_db": 0.0,
    "impact_effect_db": -1.0,
}


def default_threshold(variable: str) -> float:
    """The default ``threshold_db`` of a map of ``variable`` (:data:`MAP_VARIABLES`)."""
    _check_variable(variable)
    return MAP_VARIABLES[variable]


def threshold_meaning(variable: str, threshold_db: float) -> str:
    """What "in a band" means for a map of ``variable`` at ``threshold_db``, in words."""
    thr = f"{threshold_db:g} dB"
    if variable == "impact_effect_db":
        text = f"a point is in a band where impact_effect_db = Γ − Γ_lin < {thr}"
        if threshold_db <= 0:
            text += (
                f": there the impacts attenuate over {-threshold_db:g} dB more than the same "
                "cell without stops"
            )
        return text
    if variable == "transmittance_linear_db":
        return (
            f"a point is in a band where transmittance_linear_db < {thr}: the cell without "
            "stops (closed form) attenuates there"
        )
    return f"a point is attenuating (in a band) where {variable} < {thr}"


def _check_variable(variable: str) -> None:
    if variable not in MAP_VARIABLES:
        raise AnalysisError(
            f"variable={variable!r} cannot be mapped; variables are {', '.join(MAP_VARIABLES)}"
        )


class Band(NamedTuple):
    """One band: ``start <= stop`` in units of x, and the kind of each edge (``EDGE_KINDS``)."""

    start: float
    stop: float
    start_edge: str
    stop_edge: str


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
    threshold_db: float | None = None,
    sel: Selection | None = None,
    nearest: bool = False,
    variable: str = "transmittance_db",
) -> xr.Dataset:
    """``variable`` over ``x`` (× ``y``) with the region below the threshold and band edges.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset with ``variable``.
    x : str
        Dimension along which bands are found (e.g. ``gamma_r`` or ``frequency_hz``).
    y : str, optional
        Second dimension (e.g. ``gap``); bands are found for each of its values. Omit for a
        1-d map.
    threshold_db : float, optional
        A value strictly below it is in a band (default :func:`default_threshold`: 0 dB for
        Γ and Γ_lin, −1 dB for the impact effect).
    sel, nearest
        Values of every other dimension (see :func:`slice_axes`).
    variable : str
        One of :data:`MAP_VARIABLES`.

    Returns
    -------
    xarray.Dataset
        Sorted by ``x`` (and ``y``), with ``variable`` and ``attenuating`` (False where the
        value is missing) over (y, x); ``outcome`` and ``pending`` (when the results have
        them: to mark irregular, unsettled, failed and not yet computed cells);
        ``band_start``, ``band_stop`` (NaN-padded) and ``band_start_edge``,
        ``band_stop_edge`` (codes into :data:`EDGE_KINDS`, -1 as padding) over (y, band);
        ``band_count`` over y. Attributes ``variable``, ``threshold_db``, ``x``, ``y`` (``""``
        for a 1-d map).
    """
    _check_variable(variable)
    if variable not in ds.data_vars and variable != "transmittance_db":
        raise AnalysisError(
            f"variable={variable!r} is not in these results: results made before the linear "
            "reference was added lack it (delete the study and submit it again to compute it)"
        )
    thr = default_threshold(variable) if threshold_db is None else parse_number(
        "threshold_db", threshold_db
    )  # fmt: skip
    if y is not None and y == x:
        raise AnalysisError(f"x and y must differ, both are {x!r}")
    gamma = slice_axes(ds, variable, [y, x], sel, nearest)
    gamma = gamma.sortby(x) if y is None else gamma.sortby([y, x])
    xv = gamma[x].values.astype(np.float64)
    rows = gamma.values.reshape(-1, xv.size)
    located = _located(ds, x, y, variable, thr, sel, nearest, rows)
    if located is None:
        bands = [band_edges(xv, row, thr) for row in rows]
        intervals: list[list[tuple[float, float, float, float]]] | None = None
    else:
        bands, intervals = located
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
    bounds = np.full((4, len(rows), nb), np.nan)  # start lo, start hi, stop lo, stop hi
    for r, row_iv in enumerate(intervals or []):
        for k, iv in enumerate(row_iv):
            bounds[:, r, k] = iv
    if y is None:
        start, stop, start_edge, stop_edge = start[0], stop[0], start_edge[0], stop_edge[0]
        counts = counts.reshape(())
        bounds = bounds[:, 0]
    xattrs = dict(gamma[x].attrs)
    edge_attrs = {
        "flag_values": np.arange(len(EDGE_KINDS), dtype=np.int8),
        "flag_meanings": " ".join(EDGE_KINDS),
        "comment": "-1 pads rows with fewer bands",
    }
    data_vars: dict[str, Any] = {
        variable: gamma,
        "attenuating": (
            gamma.dims,
            np.asarray(gamma.notnull() & (gamma < thr)),
            {"long_name": f"{variable} below {thr:g} dB (False where missing)"},
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
    if intervals is not None:  # an adaptive study's edges: the interval each is proven in
        units = xattrs.get("units", "")
        for i, (name, what) in enumerate((
            ("band_start_lo", "lower end of the interval the band's lower edge lies in"),
            ("band_start_hi", "upper end of the interval the band's lower edge lies in"),
            ("band_stop_lo", "lower end of the interval the band's upper edge lies in"),
            ("band_stop_hi", "upper end of the interval the band's upper edge lies in"),
        )):  # fmt: skip
            data_vars[name] = ((*ydims, "band"), bounds[i], {"units": units, "long_name": what})
    # to mark irregular (and may-be-transient), unsettled, failed, pending cells (and an
    # adaptive line's unsampled)
    for extra in ("outcome", "may_be_transient", "pending", "sampled"):
        if extra in ds.data_vars:
            da = slice_axes(ds, extra, [y, x], sel, nearest)
            data_vars[extra] = da.sortby(x) if y is None else da.sortby([y, x])
    out = xr.Dataset(data_vars, coords={"band": np.arange(nb)})
    out.attrs = {
        "variable": variable,
        "threshold_db": thr,
        "x": x,
        "y": y or "",
        "title": f"{variable} bands along {x}" + (f" for each {y}" if y else ""),
    }
    return out


def _located(
    ds: xr.Dataset,
    x: str,
    y: str | None,
    variable: str,
    thr: float,
    sel: Selection | None,
    nearest: bool,
    rows: np.ndarray,
) -> tuple[list[list[Band]], list[list[tuple[float, float, float, float]]]] | None:
    """The bands of an adaptive study's map from the edges it located (``band_edges``), when
    the map asks for what the study located (its axis, variable and threshold); else None.
    Returns the bands per row and, per band, (start lo, start hi, stop lo, stop hi)."""
    spec_text = ds.attrs.get("adaptive")
    if "band_edges" not in ds.data_vars or not spec_text:
        return None
    import json

    spec = json.loads(str(spec_text))
    if (spec.get("target") != "band_edges" or spec.get("axis") != x
            or spec.get("variable") != variable
            or not math.isclose(float(spec.get("threshold_db", 0.0)), thr,
                                rel_tol=0, abs_tol=1e-12)):  # fmt: skip
        return None
    get = {
        k: slice_axes(ds, k, [y, "edge"], sel, nearest).sortby(y).values.reshape(len(rows), -1)
        if y is not None
        else slice_axes(ds, k, ["edge"], sel, nearest).values.reshape(1, -1)
        for k in ("band_edges", "band_edge_lo", "band_edge_hi", "band_edge_rising",
                  "band_edge_certain")
    }  # fmt: skip
    xs = ds[x].values.astype(np.float64)
    lo_x, hi_x = float(np.nanmin(xs)), float(np.nanmax(xs))
    all_bands: list[list[Band]] = []
    all_iv: list[list[tuple[float, float, float, float]]] = []
    for r, row in enumerate(rows):
        n = int(np.sum(np.isfinite(get["band_edges"][r])))
        edges = [
            (float(get["band_edges"][r, k]), float(get["band_edge_lo"][r, k]),
             float(get["band_edge_hi"][r, k]), bool(get["band_edge_rising"][r, k] == 1),
             bool(get["band_edge_certain"][r, k] == 1))
            for k in range(n)
        ]  # fmt: skip
        if edges:
            below = edges[0][3]  # the first edge rises: the line starts below the threshold
        else:
            known = row[np.isfinite(row)]
            below = bool(known.size and known[0] < thr)
        bands: list[Band] = []
        ivs: list[tuple[float, float, float, float]] = []
        start = (lo_x, lo_x, lo_x, "grid_end") if below else None
        for ex, elo, ehi, rising, certain in edges:
            kind = "located" if certain else "uncertain"
            if not rising and start is None:
                start = (ex, elo, ehi, kind)
            elif rising and start is not None:
                bands.append(Band(start[0], ex, start[3], kind))
                ivs.append((start[1], start[2], elo, ehi))
                start = None
        if start is not None:
            bands.append(Band(start[0], hi_x, start[3], "grid_end"))
            ivs.append((start[1], start[2], hi_x, hi_x))
        all_bands.append(bands)
        all_iv.append(ivs)
    return all_bands, all_iv


def _axis_json(ds_map: xr.Dataset, name: str) -> dict[str, Any]:
    c = ds_map[name]
    return {
        "name": name,
        "units": str(c.attrs.get("units", "")),
        "long_name": str(c.attrs.get("long_name", "")),
        "values": jsonable(c.values),
    }


def bandgap_json(ds_map: xr.Dataset, fixed: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A :func:`bandgap_map` as JSON-ready data that describes itself.

    Parameters
    ----------
    ds_map : xarray.Dataset
        A :func:`bandgap_map`.
    fixed : mapping, optional
        Dimensions the caller left open and that were fixed at a default value
        (:func:`service.analysis.selection.default_view`); marked ``"default": true`` in
        ``slice``.

    Returns
    -------
    dict
        ``variable`` (name, units, long name of the mapped variable), ``threshold`` (value,
        units, meaning),
        ``axes`` (``x`` and ``y``: name, units, long name, values; ``y`` None for a 1-d map),
        ``slice`` (every fixed coordinate: value, units, long name, whether chosen by default),
        ``edge_kinds`` (what each edge kind means), and the data: ``dims``, the values keyed
        by the variable's name (``transmittance_db`` by default; None for missing),
        ``attenuating`` and ``edges``, one
        ``{"y": value, "bands": [[start, stop], ...], "kinds": [[start_kind, stop_kind], ...]}``
        per y value (a single entry with ``"y": None`` for a 1-d map), band edges in the units
        of x. Also, as before: ``x``, ``y``, ``threshold_db``, ``coords``, ``units``,
        ``long_names`` and ``scalars``.
    """
    fixed = dict(fixed or {})
    x = str(ds_map.attrs["x"])
    y = str(ds_map.attrs.get("y") or "") or None
    variable = str(ds_map.attrs.get("variable", "transmittance_db"))
    gamma = ds_map[variable]
    axes = [a for a in (x, y) if a is not None]
    coords = {a: jsonable(ds_map[a].values) for a in axes}
    scalars = {
        str(k): jsonable(c.values)
        for k, c in gamma.coords.items()
        if c.ndim == 0 and k not in ("band",)
    }
    slice_ = fixed_slice_json(gamma, fixed, skip=("band",))
    starts = np.atleast_2d(ds_map["band_start"].values)
    stops = np.atleast_2d(ds_map["band_stop"].values)
    s_edge = np.atleast_2d(ds_map["band_start_edge"].values)
    e_edge = np.atleast_2d(ds_map["band_stop_edge"].values)
    counts = np.atleast_1d(ds_map["band_count"].values)
    yvals = ds_map[y].values if y is not None else [None]
    bounds = (
        [np.atleast_2d(ds_map[k].values)
         for k in ("band_start_lo", "band_start_hi", "band_stop_lo", "band_stop_hi")]
        if "band_start_lo" in ds_map
        else None
    )  # fmt: skip
    edges = []
    for r, yv in enumerate(yvals):
        n = int(counts[r])
        row: dict[str, Any] = {
            "y": None if yv is None else jsonable(yv),
            "bands": [[float(starts[r, k]), float(stops[r, k])] for k in range(n)],
            "kinds": [[EDGE_KINDS[s_edge[r, k]], EDGE_KINDS[e_edge[r, k]]] for k in range(n)],
        }
        if bounds is not None:  # adaptive: where each edge is proven to lie
            row["intervals"] = [
                [[float(bounds[0][r, k]), float(bounds[1][r, k])],
                 [float(bounds[2][r, k]), float(bounds[3][r, k])]]
                for k in range(n)
            ]  # fmt: skip
        edges.append(row)
    thr = float(ds_map.attrs["threshold_db"])
    return {
        "variable": {
            "name": variable,
            "units": str(gamma.attrs.get("units", "dB")),
            "long_name": str(gamma.attrs.get("long_name", "")),
        },
        "threshold": {
            "value": thr,
            "units": "dB",
            "meaning": threshold_meaning(variable, thr),
        },
        "axes": {"x": _axis_json(ds_map, x), "y": None if y is None else _axis_json(ds_map, y)},
        "slice": slice_,
        "edge_units": str(ds_map[x].attrs.get("units", "")),
        "edge_kinds": dict(zip(EDGE_KINDS, _EDGE_MEANINGS, strict=True)),
        "x": x,
        "y": y,
        "threshold_db": thr,
        "dims": [str(d) for d in gamma.dims],
        "coords": coords,
        "units": {a: str(ds_map[a].attrs.get("units", "")) for a in axes},
        "long_names": {a: str(ds_map[a].attrs.get("long_name", "")) for a in axes},
        "scalars": scalars,
        variable: jsonable(gamma.values),
        "attenuating": jsonable(ds_map["attenuating"].values),
        "edges": edges,
    }


def bandgap_csv(ds_map: xr.Dataset) -> str:
    """The band edges of a :func:`bandgap_map` as CSV text, one row per band.

    Columns: ``y``'s name (2-d maps), ``band`` (0, 1, … along x), ``start`` and ``stop`` (in
    units of x), ``start_edge`` and ``stop_edge`` (:data:`EDGE_KINDS`), ``threshold_db``, then
    one column per fixed coordinate of the slice. A y value without a band has one row with
    ``band`` and the edges empty, so every y value appears.
    """
    doc = bandgap_json(ds_map)
    y = doc["y"]
    fixed = list(doc["scalars"])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ([y] if y else []) + ["band", "start", "stop", "start_edge", "stop_edge",
                                 "threshold_db"] + fixed  # fmt: skip
    w.writerow(head)
    tail = [doc["threshold_db"], *(_cell(doc["scalars"][k]) for k in fixed)]
    for row in doc["edges"]:
        lead = [_cell(row["y"])] if y else []
        if not row["bands"]:
            w.writerow([*lead, "", "", "", "", "", *tail])
        for k, ((a, b), (ka, kb)) in enumerate(zip(row["bands"], row["kinds"], strict=True)):
            w.writerow([*lead, k, _cell(a), _cell(b), ka, kb, *tail])
    return buf.getvalue()


def _cell(v: Any) -> str:
    """A CSV field: empty for missing, ``repr`` precision for floats."""
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)
