"""Hysteresis maps of sweep and multi-start studies: branches, jumps and where they differ.

A sweep study carries the state from one point to the next along its swept axis, up and/or
down (dimension ``direction``); a multi-start study computes every point from several initial
states (dimension ``initial``). Each combination of their values is one **branch** (labelled
as continuation tools do: ``up``, ``down``, ``rest``, ``random-0/down``, ...). Along x
(default: the swept axis, attribute ``sweep_axis``, else the frequency axis) a hysteresis map
holds

* every branch's curve of ``variable`` (sorted by x; a ``down`` branch was computed in
  decreasing x),
* its **jumps**: steps between consecutive known points of a branch, in the order it was
  computed, that are discontinuities (:func:`jump_steps`; labelled ``J1``, ``J2``, ... branch
  by branch): more than ``jump_db`` and either more than :data:`JUMP_FACTOR` times what the
  slope of a neighbouring step predicts, or a step onto or off another branch,
* where the branches **differ**: grid points at which the largest and smallest known value
  over the branches are more than ``tol_db`` apart (for a sweep: |up − down| > ``tol_db``),
  as intervals of x from the first to the last grid point of each run,
* ``responses`` (the number of distinct responses per grid point) when the results have it.

Every other varying grid axis is fixed at its first value unless selected
(:func:`service.analysis.selection.default_view`, listed in the attribute ``fixed``). Branches
from different starts are never mixed: each is its own curve.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from service.analysis.selection import (
    BRANCH_DIMS,
    AnalysisError,
    Selection,
    default_view,
    fixed_slice_json,
    parse_number,
    slice_axes,
    sweep_x,
)
from service.studies.dataset import jsonable
from service.studies.variables import default_x, outcome_names

__all__ = [
    "JUMP_FACTOR",
    "NO_HYSTERESIS",
    "fixed_of",
    "hysteresis_csv",
    "hysteresis_json",
    "hysteresis_map",
    "jump_steps",
]

NO_HYSTERESIS = "this study has no sweep or several starts: no hysteresis"


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs ``[i, j)`` of true values of a 1-d mask."""
    edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(mask, dtype=np.int8), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _rows(
    ds: xr.Dataset,
    name: str,
    branch_dims: list[str],
    x: str,
    sel: Selection,
    nearest: bool,
    like: xr.DataArray,
) -> np.ndarray:
    """``name`` over (branch, x), sorted like ``like``; broadcast over branch dims it lacks."""
    own = [d for d in branch_dims if d in ds[name].dims]
    da = slice_axes(ds, name, [*own, x], sel, nearest).sortby(x)
    da = da.broadcast_like(like).transpose(*branch_dims, x)
    return np.asarray(da.values).reshape(-1, like.sizes[x])


#: A step is explained by a neighbouring step's slope when it is at most this many times
#: what that slope predicts over its width (same sign). On a smooth curve sampled coarsely,
#: neighbouring steps differ by less: the closed-form linear transmittance (ξ 0.01 to 0.05)
#: on grids of 12 to 126 points has no step over 1 dB that 3 times either neighbour's
#: prediction does not cover, while 1.5 or 2 leave steps on undersampled resonance peaks.
JUMP_FACTOR = 3.0


def _explained(d: np.ndarray, h: np.ndarray, i: int) -> bool:
    """Whether step ``i`` (change ``d[i]`` over width ``h[i]``) is what a neighbouring step's
    slope predicts, within :data:`JUMP_FACTOR`; a branch of two points has no neighbours."""
    for k in (i - 1, i + 1):
        if 0 <= k < d.size:
            predicted = d[k] / h[k] * h[i]
            if predicted * d[i] > 0 and abs(d[i]) <= JUMP_FACTOR * abs(predicted):
                return True
    return False


def _changes_branch(rows: np.ndarray, b: int, a: int, c: int, tol: float, jump: float) -> bool:
    """Whether branch ``b`` steps onto or off another branch between grid points ``a`` and
    ``c``: it agrees with that branch (within ``tol``) at one of them, is more than ``jump``
    from it at the other, and moves further than that branch does in the step."""
    mine = rows[b, c] - rows[b, a]
    for o in range(rows.shape[0]):
        if o == b or not (np.isfinite(rows[o, a]) and np.isfinite(rows[o, c])):
            continue
        gaps = sorted((abs(rows[b, a] - rows[o, a]), abs(rows[b, c] - rows[o, c])))
        if gaps[0] <= tol and gaps[1] > jump and abs(mine) > abs(rows[o, c] - rows[o, a]):
            return True
    return False


def jump_steps(
    xv: np.ndarray, rows: np.ndarray, b: int, decreasing: bool, jump: float, tol: float
) -> list[tuple[int, int, bool, str]]:
    """The jumps of branch ``b`` of ``rows`` (branch × sorted ``xv``): ``(from, to,
    across_missing, kind)`` in the order the branch was computed.

    Consecutive *known* points are compared. A step is a jump when it is more than ``jump``
    and it is a discontinuity that a finer grid would keep:

    * ``kind`` ``"discontinuity"``: no neighbouring step of the branch explains it (a
      neighbour explains it when its slope, extrapolated over the step's width, has the same
      sign and at least 1/:data:`JUMP_FACTOR` of its size). A steep but smooth slope, such as
      a resonance flank on a coarse grid, is explained by the steps on either side; a fold
      jump between two gentle slopes is not. A branch of two points: every step over
      ``jump``;
    * ``kind`` ``"branch change"``: the branch steps onto or off another branch (agrees with
      it within ``tol`` at one end, is more than ``jump`` away at the other, and moves further
      than it): coexisting responses, even where the jump runs along a steep slope.
    """
    order = np.arange(xv.size)[::-1] if decreasing else np.arange(xv.size)
    row = rows[b]
    known = np.array([int(i) for i in order if math.isfinite(row[i])], dtype=np.int64)
    if known.size < 2:
        return []
    d = np.diff(row[known])
    h = np.abs(np.diff(xv[known]))
    out = []
    for i, (a, c) in enumerate(itertools.pairwise(known.tolist())):
        if abs(d[i]) <= jump:
            continue
        if not _explained(d, h, i):
            out.append((a, c, abs(c - a) > 1, "discontinuity"))
        elif _changes_branch(rows, b, a, c, tol, jump):
            out.append((a, c, abs(c - a) > 1, "branch change"))
    return out


def hysteresis_map(
    ds: xr.Dataset,
    x: str | None = None,
    sel: Selection | None = None,
    nearest: bool = False,
    variable: str = "transmittance_db",
    jump_db: float = 1.0,
    tol_db: float = 0.05,
) -> xr.Dataset:
    """Branches of ``variable`` along ``x``, their jumps and where they differ.

    Parameters
    ----------
    ds : xarray.Dataset
        Results with a ``direction`` and/or ``initial`` dimension.
    x : str, optional
        The axis along x; default the swept axis (``ds.attrs["sweep_axis"]``), else the
        frequency axis.
    sel, nearest
        Values of other dimensions (:func:`service.analysis.selection.select`); the varying
        ones not given are fixed at their first value. Selecting ``direction`` or ``initial``
        keeps only those branches.
    variable : str
        A numeric variable that spans the branch dimensions.
    jump_db : float
        A jump is a step between consecutive points of a branch over this (> 0) that is a
        discontinuity (:func:`jump_steps`).
    tol_db : float
        Branches differ at a point where their values spread over this (>= 0).

    Returns
    -------
    xarray.Dataset
        ``variable`` (and ``outcome``, ``pending`` when present) over (branch, x), with
        ``branch_direction`` and ``branch_initial`` ("" when not applicable); ``spread_db``,
        ``differs`` and ``responses`` (when present) over x; ``jump_*`` over ``jump`` and
        ``region_*`` over ``region``; ``branch_order`` (``increasing``/``decreasing``: the
        order in which a branch's points are compared); ``jump_kind`` (``discontinuity`` or
        ``branch change``, :func:`jump_steps`). Attributes ``variable``, ``x``,
        ``jump_db``, ``tol_db``, ``branch_dims``, ``fixed`` (names, space separated),
        ``sweep_axis`` ("" without a sweep), ``along_sweep`` (1 when x is the swept axis),
        ``title``.

    Raises
    ------
    AnalysisError
        No ``direction``/``initial`` dimension, a bad axis, variable, threshold or selection.
    """
    present = [d for d in BRANCH_DIMS if d in ds.dims]
    if not present:
        raise AnalysisError(
            f"{NO_HYSTERESIS} (the results have no direction or initial dimension; dimensions "
            f"are {', '.join(str(d) for d in ds.dims) or '(none)'})"
        )
    if variable not in ds.data_vars:
        raise AnalysisError(
            f"variable={variable!r} is not in the results; variables are "
            f"{', '.join(sorted(str(v) for v in ds.data_vars))}"
        )
    if ds[variable].dtype.kind not in "iuf":
        raise AnalysisError(f"variable={variable!r} is not numeric: it has no curve")
    lacking = [d for d in present if d not in ds[variable].dims]
    if lacking:
        raise AnalysisError(
            f"variable={variable!r} does not vary with {', '.join(lacking)} (one value per "
            "grid point): it has no branches; choose e.g. transmittance_db"
        )
    jump = parse_number("jump_db", jump_db)
    tol = parse_number("tol_db", tol_db)
    if jump <= 0:
        raise AnalysisError(f"jump_db={jump_db!r} must be positive")
    if tol < 0:
        raise AnalysisError(f"tol_db={tol_db!r} must not be negative")
    if x is not None and x in BRANCH_DIMS:
        raise AnalysisError(f"x={x!r} labels branches; choose a grid axis as x")
    x = x or sweep_x(ds, variable)
    view = default_view(ds, variable, x, None, sel, auto_y=False, keep=present)
    x = view.x
    branch_dims = [d for d in present if d not in view.sel]
    curves = slice_axes(ds, variable, [*branch_dims, x], view.sel, nearest).sortby(x)
    curves = curves.transpose(*branch_dims, x)
    xv = curves[x].values.astype(np.float64)
    nx = xv.size
    rows = np.asarray(curves.values, dtype=np.float64).reshape(-1, nx)

    # Branch labels: initial/direction, selected ones included (from the scalar coordinates).
    values = {
        d: [str(v) for v in np.atleast_1d(curves[d].values)]
        for d in present
        if d in branch_dims or d in curves.coords
    }
    combos = list(itertools.product(*(values[d] for d in branch_dims))) or [()]
    labels, directions, initials = [], [], []
    for combo in combos:
        got = dict(zip(branch_dims, combo, strict=True))
        for d in present:
            if d not in got:
                got[d] = values.get(d, [str(view.sel[d])])[0]
        labels.append("/".join(got[d] for d in present))
        directions.append(got.get("direction", ""))
        initials.append(got.get("initial", ""))

    # Jumps, branch by branch, in the order each branch was computed: a down sweep went in
    # decreasing values of the swept axis (the default x when the attribute is absent).
    swept = str(ds.attrs.get("sweep_axis") or "") or default_x(ds[variable].dims) or ""
    along = "direction" in present and x == swept
    orders = ["decreasing" if along and d == "down" else "increasing" for d in directions]
    j_branch, j_from, j_to, j_across, j_kind = [], [], [], [], []
    for b in range(rows.shape[0]):
        for a, c, across, kind in jump_steps(xv, rows, b, orders[b] == "decreasing", jump, tol):
            j_branch.append(b)
            j_from.append(a)
            j_to.append(c)
            j_across.append(across)
            j_kind.append(kind)
    jb = np.array(j_branch, dtype=np.int64)
    jf = np.array(j_from, dtype=np.int64)
    jt = np.array(j_to, dtype=np.int64)

    # Where branches differ: the spread of the known values at each grid point.
    known = np.isfinite(rows)
    enough = known.sum(axis=0) >= 2
    spread = np.full(nx, np.nan)
    if enough.any():
        r = rows[:, enough]
        spread[enough] = np.nanmax(r, axis=0) - np.nanmin(r, axis=0)
    differs = np.where(np.isnan(spread), False, spread > tol)
    runs = _runs(differs)

    units = str(ds[variable].attrs.get("units", ""))
    xattrs = dict(curves[x].attrs)
    xunits = str(xattrs.get("units", ""))
    data_vars: dict[str, Any] = {
        variable: (("branch", x), rows, dict(curves.attrs)),
        "spread_db": (
            (x,),
            spread,
            {"units": units, "long_name": f"largest minus smallest {variable} over the branches"},
        ),
        "differs": (
            (x,),
            differs,
            {"long_name": f"the branches differ by more than {tol:g} {units}".rstrip()},
        ),
        "jump_branch": (("jump",), jb, {"long_name": "index of the branch that jumps"}),
        "jump_label": (("jump",), np.array([f"J{k + 1}" for k in range(jb.size)], dtype=object)),
        "jump_from": (("jump",), xv[jf], {"units": xunits, "long_name": f"{x} before the jump"}),
        "jump_to": (("jump",), xv[jt], {"units": xunits, "long_name": f"{x} after the jump"}),
        "jump_from_value": (("jump",), rows[jb, jf], {"units": units}),
        "jump_to_value": (("jump",), rows[jb, jt], {"units": units}),
        "jump_size_db": (
            ("jump",),
            rows[jb, jt] - rows[jb, jf],
            {"units": units, "long_name": "value after minus value before the jump"},
        ),
        "jump_across_missing": (
            ("jump",),
            np.array(j_across, dtype=bool),
            {"long_name": "a missing point lies between the two points compared"},
        ),
        "jump_kind": (
            ("jump",),
            np.array(j_kind, dtype=object),
            {
                "long_name": "discontinuity (no neighbouring slope explains the step) or branch "
                "change (the step joins or leaves another branch)"
            },
        ),
        "region_start": (("region",), np.array([xv[i] for i, _ in runs]), {"units": xunits}),
        "region_stop": (("region",), np.array([xv[j - 1] for _, j in runs]), {"units": xunits}),
        "region_points": (("region",), np.array([j - i for i, j in runs], dtype=np.int64)),
        "region_max_spread_db": (
            ("region",),
            np.array([float(np.max(spread[i:j])) for i, j in runs]),
            {"units": units},
        ),
    }
    if "outcome" in ds.data_vars:
        codes = _rows(ds, "outcome", branch_dims, x, view.sel, nearest, curves)
        data_vars["outcome"] = (("branch", x), codes, dict(ds["outcome"].attrs))
    if "may_be_transient" in ds.data_vars:
        flag = _rows(ds, "may_be_transient", branch_dims, x, view.sel, nearest, curves)
        data_vars["may_be_transient"] = (("branch", x), flag.astype(bool),
                                         dict(ds["may_be_transient"].attrs))  # fmt: skip
    if "pending" in ds.data_vars:
        pend = _rows(ds, "pending", branch_dims, x, view.sel, nearest, curves).astype(bool)
        data_vars["pending"] = (("branch", x), pend, dict(ds["pending"].attrs))
    if "responses" in ds.data_vars:
        resp = slice_axes(ds, "responses", [x], view.sel, nearest).sortby(x)
        data_vars["responses"] = ((x,), resp.values, dict(resp.attrs))
    coords: dict[str, Any] = {
        x: (x, xv, xattrs),
        "branch": ("branch", np.array(labels, dtype=object)),
        "branch_direction": ("branch", np.array(directions, dtype=object)),
        "branch_initial": ("branch", np.array(initials, dtype=object)),
        "branch_order": ("branch", np.array(orders, dtype=object)),
        "jump": np.arange(jb.size),
        "region": np.arange(len(runs)),
    }
    for name, c in curves.coords.items():
        if c.ndim == 0:
            coords[str(name)] = c
    out = xr.Dataset(data_vars, coords=coords)
    out.attrs = {
        "variable": variable,
        "x": x,
        "jump_db": jump,
        "tol_db": tol,
        "branch_dims": " ".join(present),
        "fixed": " ".join(view.fixed),
        "sweep_axis": swept if "direction" in present else "",
        "along_sweep": int(along),
        "title": f"{variable} along {x}: branches {', '.join(labels)}",
    }
    return out


def fixed_of(h: xr.Dataset) -> dict[str, Any]:
    """The axes a :func:`hysteresis_map` fixed at their first value, with those values."""
    return {k: np.asarray(h[k].values).item() for k in str(h.attrs.get("fixed", "")).split()}


# --------------------------------------------------------------------------- JSON and CSV


def _meaning(h: xr.Dataset, units: str) -> tuple[str, str]:
    u = f" {units}" if units else ""
    order = "in the order it was computed: decreasing x for a down sweep, increasing x otherwise"
    if not h.attrs.get("along_sweep"):
        order = "in increasing x"
        if h.attrs.get("sweep_axis"):
            order += " (x is not the swept axis: each point is on a sweep line of its own)"
    jump = (
        f"a jump is a step of more than {float(h.attrs['jump_db']):g}{u} between consecutive "
        f"known points of a branch, {order}, that is a discontinuity: more than "
        f"{JUMP_FACTOR:g} times what the slope of a neighbouring step predicts, or a step "
        "onto or off another branch (a steep smooth slope on a coarse grid is no jump)"
    )
    tol = (
        f"the branches differ at a grid point where their largest and smallest known values "
        f"are more than {float(h.attrs['tol_db']):g}{u} apart; an interval runs from the first "
        "to the last grid point of a run of such points"
    )
    return jump, tol


def _none(v: str) -> str | None:
    return v or None


def hysteresis_json(h: xr.Dataset) -> dict[str, Any]:
    """A :func:`hysteresis_map` as JSON-ready data that describes itself.

    Returns
    -------
    dict
        ``variable`` (name, units, long name), ``x`` and ``axes.x`` (name, units, long name,
        values), ``sweep_axis``, ``branch_dims``, ``slice`` (every fixed coordinate: value,
        units, long name, ``default``), ``jump_db`` and ``tol_db`` (value, units, meaning),
        ``branches`` (label, direction, initial, order, values along x, outcomes,
        ``may_be_transient`` along x (None when the results lack the flag), jumps),
        ``jumps`` (label, branch, direction, initial, from, to, interval, from_value,
        to_value, size_db, across_missing, kind), ``differing`` (start, stop, points,
        max_spread_db), ``spread_db`` and ``differs`` along x, ``responses`` (None when the
        results lack it) and ``counts``. Missing numbers are None.
    """
    variable = str(h.attrs["variable"])
    x = str(h.attrs["x"])
    da = h[variable]
    units = str(da.attrs.get("units", ""))
    fixed = set(str(h.attrs.get("fixed", "")).split())
    xv = h[x].values
    names = outcome_names(h["outcome"]) if "outcome" in h.data_vars else None
    if names is not None and "pending" in h.data_vars:
        names = names.astype(object)
        names[np.asarray(h["pending"].values, dtype=bool)] = "pending"
    transient = (
        np.asarray(h["may_be_transient"].values, dtype=bool)
        if "may_be_transient" in h.data_vars
        else None
    )
    labels = [str(v) for v in h["branch"].values]
    jumps = []
    for k in range(h.sizes["jump"]):
        b = int(h["jump_branch"].values[k])
        a, c = float(h["jump_from"].values[k]), float(h["jump_to"].values[k])
        jumps.append(
            {
                "label": str(h["jump_label"].values[k]),
                "branch": labels[b],
                "direction": _none(str(h["branch_direction"].values[b])),
                "initial": _none(str(h["branch_initial"].values[b])),
                "from": a,
                "to": c,
                "interval": [min(a, c), max(a, c)],
                "from_value": jsonable(h["jump_from_value"].values[k]),
                "to_value": jsonable(h["jump_to_value"].values[k]),
                "size_db": jsonable(h["jump_size_db"].values[k]),
                "across_missing": bool(h["jump_across_missing"].values[k]),
                "kind": str(h["jump_kind"].values[k]),
            }
        )
    branches = []
    for b, label in enumerate(labels):
        direction = str(h["branch_direction"].values[b])
        row = da.values[b]
        branches.append(
            {
                "label": label,
                "direction": _none(direction),
                "initial": _none(str(h["branch_initial"].values[b])),
                "order": str(h["branch_order"].values[b]),
                "values": jsonable(row),
                "points": int(np.isfinite(row).sum()),
                "outcomes": None if names is None else [str(n) for n in names[b]],
                "may_be_transient": None if transient is None else [bool(t) for t in transient[b]],
                "jumps": [j["label"] for j in jumps if j["branch"] == label],
            }
        )
    differing = [
        {
            "start": float(h["region_start"].values[k]),
            "stop": float(h["region_stop"].values[k]),
            "points": int(h["region_points"].values[k]),
            "max_spread_db": jsonable(h["region_max_spread_db"].values[k]),
        }
        for k in range(h.sizes["region"])
    ]
    slice_ = fixed_slice_json(da, fixed)
    responses = jsonable(h["responses"].values) if "responses" in h.data_vars else None
    jump_meaning, tol_meaning = _meaning(h, units)
    resp = np.asarray(h["responses"].values, dtype=np.float64) if responses is not None else None
    return {
        "variable": {
            "name": variable,
            "units": units,
            "long_name": str(da.attrs.get("long_name", "")),
        },
        "x": x,
        "axes": {
            "x": {
                "name": x,
                "units": str(h[x].attrs.get("units", "")),
                "long_name": str(h[x].attrs.get("long_name", "")),
                "values": jsonable(xv),
            }
        },
        "sweep_axis": _none(str(h.attrs.get("sweep_axis", ""))),
        "along_sweep": bool(h.attrs.get("along_sweep", 0)),
        "branch_dims": str(h.attrs.get("branch_dims", "")).split(),
        "slice": slice_,
        "jump_db": {"value": float(h.attrs["jump_db"]), "units": units, "meaning": jump_meaning},
        "tol_db": {"value": float(h.attrs["tol_db"]), "units": units, "meaning": tol_meaning},
        "branches": branches,
        "jumps": jumps,
        "differing": differing,
        "spread_db": jsonable(h["spread_db"].values),
        "differs": jsonable(h["differs"].values),
        "responses": responses,
        "counts": {
            "branches": len(branches),
            "jumps": len(jumps),
            "differing_points": int(np.asarray(h["differs"].values).sum()),
            "coexisting_points": None if resp is None else int(np.sum(resp > 1)),
        },
    }


def _cell(v: Any) -> str:
    """A CSV field: empty for missing, ``repr`` precision for floats."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    return str(v)


def hysteresis_csv(h: xr.Dataset) -> str:
    """A :func:`hysteresis_map` as CSV text in long form: one row per branch and x value.

    Columns: ``branch``, ``direction``, ``initial``, x's name, the variable, ``outcome``,
    ``may_be_transient`` (empty when the results lack the flag), ``jump`` (the label of a jump
    that lands on this point, else empty), ``jump_size_db``,
    ``spread_db``, ``differs``, ``responses``, then one column per fixed coordinate.
    """
    doc = hysteresis_json(h)
    x, variable = doc["x"], doc["variable"]["name"]
    fixed = list(doc["slice"])
    landing: dict[tuple[str, float], Mapping[str, Any]] = {
        (j["branch"], j["to"]): j for j in doc["jumps"]
    }
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["branch", "direction", "initial", x, variable, "outcome", "may_be_transient",
                "jump",
                "jump_size_db", "spread_db", "differs", "responses", *fixed])  # fmt: skip
    tail = [_cell(doc["slice"][k]["value"]) for k in fixed]
    xs = doc["axes"]["x"]["values"]
    responses = doc["responses"] or [None] * len(xs)
    for br in doc["branches"]:
        for i, xv in enumerate(xs):
            j = landing.get((br["label"], xv))
            outcome = br["outcomes"][i] if br["outcomes"] is not None else None
            flag = br["may_be_transient"][i] if br["may_be_transient"] is not None else None
            w.writerow([br["label"], _cell(br["direction"]), _cell(br["initial"]), _cell(xv),
                        _cell(br["values"][i]), _cell(outcome), _cell(flag),
                        j["label"] if j else "",
                        _cell(j["size_db"]) if j else "", _cell(doc["spread_db"][i]),
                        _cell(doc["differs"][i]), _cell(responses[i]), *tail])  # fmt: skip
    return buf.getvalue()
