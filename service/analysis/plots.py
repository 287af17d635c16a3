"""PNG and SVG figures of results datasets (the only module that imports matplotlib).

Every ``*_figure`` function builds its own :class:`matplotlib.figure.Figure` with a
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg` (no pyplot state), so figures can
be drawn from several threads of a web server at once; tests inspect these objects. Each
``*_png`` function returns the bytes of that figure at a fixed size (``figsize × dpi``; no
tight bounding box): PNG, or SVG with ``fmt="svg"``. Points that are not a proven steady state
(irregular, unsettled, failed) are marked the same way in every figure (:data:`MARKS`) and
counted in its legend, so a jump in a curve is never mistaken for a resolved feature; an
irregular point flagged ``may_be_transient`` (its impacts may still die out into the
impact-free response) has a mark of its own. Axes
that a request left open and that were fixed at a default (``fixed``, from
:func:`service.analysis.selection.default_view`) are named in the title.

Selections go through :mod:`service.analysis.selection`, so a bad selection raises
:class:`~service.analysis.selection.AnalysisError` with the same message as everywhere else.
Symbols and units of the axes come from :mod:`service.studies.variables`.
"""

from __future__ import annotations

import io
import itertools
import json
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import matplotlib
import numpy as np
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from matplotlib.ticker import FuncFormatter

from service.analysis.bands import EDGE_KINDS, band_edges
from service.analysis.hysteresis import fixed_of
from service.analysis.selection import AnalysisError, Selection, slice_axes
from service.studies.variables import AXES, axis_symbol, default_x, outcome_names

# Select the non-interactive backend before pyplot is loaded anywhere (this module never
# does: figures are drawn with the object API).
matplotlib.use("Agg")

__all__ = [
    "DPI",
    "FIGSIZE",
    "FORMATS",
    "MARKS",
    "TRANSIENT",
    "bandgap_figure",
    "bandgap_png",
    "cell_edges",
    "effective_mass_figure",
    "effective_mass_png",
    "hysteresis_figure",
    "hysteresis_png",
    "transmittance_figure",
    "transmittance_png",
    "warm_up",
]

FIGSIZE: tuple[float, float] = (8.0, 5.0)  # inches
DPI = 120  # FIGSIZE × DPI = 960 × 600 pixels
Format = Literal["png", "svg"]
FORMATS: dict[str, str] = {"png": "image/png", "svg": "image/svg+xml"}  # format -> media type


def _units(da: xr.DataArray) -> str:
    u = str(da.attrs.get("units", "") or "")
    return "–" if u in ("", "1") else u


#: Prefixed units figures write an SI axis in, largest first, with the factor of each: the
#: largest whose value is at least 0.1 is used (0.0005 m is 0.5 mm, 0.02 kg is 20 g).
_PREFIXES: dict[str, tuple[tuple[str, float], ...]] = {
    "m": (("m", 1.0), ("mm", 1e-3), ("µm", 1e-6), ("nm", 1e-9)),
    "Pa": (("GPa", 1e9), ("MPa", 1e6), ("kPa", 1e3), ("Pa", 1.0)),
    "kg": (("kg", 1.0), ("g", 1e-3), ("mg", 1e-6)),
    "N m-1": (("kN m-1", 1e3), ("N m-1", 1.0)),
}


def _scale(name: str, values: Any, units: str | None = None) -> tuple[float, str]:
    """The factor and (prefixed) units an axis's ``values`` are written in: ``(1e-3, "mm")``
    for gaps in metres below a metre; units from the coordinate, else the axis registry."""
    if units is None:
        info = AXES.get(name)
        units = info.units if info is not None else ""
    choices = _PREFIXES.get(units)
    if not choices:
        return 1.0, units
    v = np.abs(np.asarray(values, dtype=np.float64).ravel())
    big = float(v[np.isfinite(v)].max()) if np.isfinite(v).any() else 0.0
    for text, factor in choices:
        if big / factor >= 0.1:
            return factor, text
    return choices[-1][1], choices[-1][0]


def _quantity(name: str, value: Any, units: str | None = None, scale: Any = None) -> str:
    """``θ = 0.3``, ``gap = 0.5 mm``: an axis's symbol and value in its (prefixed) units;
    ``scale`` (values) chooses the prefix, so that the entries of one legend share it."""
    v = np.asarray(value).item()
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return f"{axis_symbol(name)} = {v}"
    factor, u = _scale(name, value if scale is None else scale, units)
    u = "" if u in ("", "1") else f" {u}"
    return f"{axis_symbol(name)} = {_value(v / factor)}{u}"


def _axis_label(name: str, coord: xr.DataArray) -> str:
    """``γ_r = Ω/ω_b (–)``, ``frequency (Hz)``, ``gap (mm)``."""
    _, units = _scale(name, coord.values, str(coord.attrs.get("units", "") or ""))
    units = "–" if units in ("", "1") else units
    info = AXES.get(name)
    if info is not None and info.label:
        return f"{info.label} ({units})"
    symbol, definition = axis_symbol(name), info.definition if info is not None else ""
    text = f"{symbol} = {definition}" if definition and definition != symbol else symbol
    return f"{text} ({units})"


def _label_axis(axis: Any, name: str, coord: xr.DataArray) -> None:
    """Label a matplotlib axis with :func:`_axis_label`, its ticks in the same prefixed units."""
    axis.set_label_text(_axis_label(name, coord))
    factor, _ = _scale(name, coord.values, str(coord.attrs.get("units", "") or ""))
    if factor != 1.0:
        axis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v / factor:.6g}"))


def _value(v: Any) -> str:
    v = np.asarray(v).item()
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _subtitle(da: xr.DataArray, skip: Sequence[str] = ()) -> str:
    """The fixed parameters of a slice (its 0-d coordinates), e.g. ``θ = 0.3, σ = 0.05``; the
    axes fixed by default are in ``skip`` (:func:`_fixed_text` names them)."""
    parts = [
        _quantity(str(name), c.values, str(c.attrs.get("units", "") or "") or None)
        for name, c in da.coords.items()
        if c.ndim == 0 and name not in skip and c.dtype.kind in "iuf"
    ]
    lines, line = [], ""
    for p in parts:  # wrap so that a physical study's many parameters stay readable
        if line and len(line) + len(p) > 95:
            lines.append(line)
            line = p
        else:
            line = f"{line}, {p}" if line else p
    if line:
        lines.append(line)
    return "\n".join(lines)


def _figure() -> tuple[Figure, Any]:
    fig = Figure(figsize=FIGSIZE, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _check_format(fmt: str) -> None:
    if fmt not in FORMATS:
        raise AnalysisError(f"format={fmt!r} is not a figure format; formats are png, svg")


def _png(fig: Figure, fmt: Format = "png") -> bytes:
    _check_format(fmt)
    buf = io.BytesIO()
    # A fixed hash salt and no date: the same figure gives the same SVG bytes (cacheable).
    metadata = {"Date": None} if fmt == "svg" else None
    with matplotlib.rc_context({"svg.hashsalt": "impactcell"}):
        fig.savefig(buf, format=fmt, dpi=DPI, metadata=metadata)
    return buf.getvalue()


def _fixed_text(fixed: Mapping[str, Any] | None) -> str:
    """``by default at the first value: θ = 0.1`` for defaulted axes (how to choose others
    is the API's to say: the ``X-Impactcell-Fixed`` header and the JSON's ``slice``)."""
    if not fixed:
        return ""
    return "by default at the first value: " + ", ".join(_quantity(k, v) for k, v in fixed.items())


def _title(*lines: str) -> str:
    return "\n".join(line for line in lines if line)


def _default_x(ds: xr.Dataset, variable: str) -> str:
    dims = ds[variable].dims if variable in ds else ds.dims
    x = default_x(dims)
    if x is not None:
        return x
    raise AnalysisError(
        f"x is required: neither gamma_r nor frequency_hz is a dimension; dimensions are "
        f"{', '.join(str(d) for d in dims)}"
    )


# --------------------------------------------------------------------------- outcome marks

#: The mark of an irregular point flagged ``may_be_transient`` (it replaces ``irregular``).
TRANSIENT = "may_be_transient"
#: How points that are not a proven steady state are marked, in every figure (outcome ->
#: Line2D style). Irregular and unsettled points sit on their curve (their Γ is a window mean,
#: not an orbit's); failed points have no value and sit on a strip at the bottom of the axes.
MARKS: dict[str, dict[str, Any]] = {
    "irregular": {"marker": "x", "ms": 6, "mew": 1.4, "color": "k", "mfc": "k"},
    # an irregular point flagged may_be_transient: its Γ is not a settled value
    TRANSIENT: {"marker": "D", "ms": 5, "mew": 1.3, "color": "C1", "mfc": "none"},
    "unsettled": {"marker": "s", "ms": 6, "mew": 1.3, "color": "C3", "mfc": "none"},
    "failed": {"marker": "X", "ms": 7, "mew": 0.6, "color": "C3", "mfc": "C3", "mec": "k"},
}
_MARK_LABELS = {TRANSIENT: "irregular, may be transient"}  # legend text ("" = the name)
_STRIP = 0.03  # height (axes fraction) of the strip where points without a value are marked
_VARIABLE_TEXT = {  # symbol (titles, legends) and axis label of each mappable variable
    "transmittance_db": ("Γ", "transmittance Γ (dB)"),
    "transmittance_linear_db": ("Γ_lin", "transmittance without stops Γ_lin (dB)"),
    "impact_effect_db": ("Γ − Γ_lin", "impact effect Γ − Γ_lin (dB)"),
}


#: Outcome name of the values an adaptive line did not take (never marked, never drawn).
UNSAMPLED = "unsampled"


def _outcomes(
    ds: xr.Dataset,
    axes: Sequence[str | None],
    sel: Selection | None,
    nearest: bool,
    like: xr.DataArray,
) -> np.ndarray:
    """Outcome names of the points of ``like`` (a slice of ``ds`` over ``axes``, sorted like
    it). Without an ``outcome`` variable a missing value counts as ``failed``; points a partial
    dataset has not computed yet are ``pending``."""
    x = str(like.dims[-1])
    names = np.where(np.isnan(like.values.astype(np.float64)), "failed", "").astype(object)
    if "outcome" in ds.data_vars:
        o = slice_axes(ds, "outcome", axes, sel, nearest).sortby(x).transpose(*like.dims)
        names = outcome_names(o).astype(object)
    if TRANSIENT in ds.data_vars:
        f = slice_axes(ds, TRANSIENT, axes, sel, nearest).sortby(x).transpose(*like.dims)
        names = _with_transient(names, f.values)
    if "pending" in ds.data_vars:
        pend = slice_axes(ds, "pending", axes, sel, nearest).sortby(x).transpose(*like.dims)
        names[np.asarray(pend.values, dtype=bool)] = "pending"
    if "sampled" in ds.data_vars:  # an adaptive study: values its lines did not take
        took = slice_axes(ds, "sampled", axes, sel, nearest).sortby(x).transpose(*like.dims)
        names[~np.asarray(took.values, dtype=bool)] = UNSAMPLED
    return names.astype(str)


def _with_transient(names: np.ndarray, flag: Any) -> np.ndarray:
    """``names`` with the irregular points that ``flag`` (``may_be_transient``) marks named
    :data:`TRANSIENT`."""
    out = np.asarray(names).astype(object)
    out[(out == "irregular") & np.asarray(flag, dtype=bool)] = TRANSIENT
    return out


def _mark_label(kind: str, n: int) -> str:
    return f"{_MARK_LABELS.get(kind, kind)} ({n})"


def _taken(names: np.ndarray) -> np.ndarray:
    """Points to draw a curve through: all but the values an adaptive line did not take (a
    line through them would break at every other line's sample)."""
    return np.asarray(names) != UNSAMPLED


def _mark_outcomes(ax: Any, xv: np.ndarray, values: np.ndarray, names: np.ndarray) -> None:
    """Mark irregular and unsettled points on their curve and failed ones on the bottom strip,
    one artist per outcome (``gid`` ``outcome-<name>``) labelled with its count; points not
    computed yet are only counted."""
    xs = np.broadcast_to(xv, values.shape)
    for kind, style in MARKS.items():
        hit = names == kind
        n = int(hit.sum())
        if not n:
            continue
        label = _mark_label(kind, n)
        if kind == "failed":
            ax.plot(
                xs[hit],
                np.full(n, _STRIP),
                ls="none",
                transform=ax.get_xaxis_transform(),
                clip_on=False,
                zorder=4,
                label=label,
                gid=f"outcome-{kind}",
                **style,
            )
            continue
        on = hit & np.isfinite(values)  # a missing value (e.g. no slope) has nowhere to go
        ax.plot(xs[on], values[on], ls="none", zorder=4, label=label, gid=f"outcome-{kind}",
                **style)  # fmt: skip
    pending = int(np.sum(names == "pending"))
    if pending:
        ax.plot([], [], " ", label=f"not computed yet ({pending})")


def _legend(ax: Any, **kwargs: Any) -> None:
    n = len(ax.get_legend_handles_labels()[1])
    ax.legend(fontsize=7 if n > 8 else 8, ncols=2 if n > 8 else 1, **kwargs)


# --------------------------------------------------------------------------- figures


def transmittance_figure(
    ds: xr.Dataset,
    sel: Selection | None = None,
    x: str | None = None,
    hue: str | None = None,
    nearest: bool = False,
    *,
    fixed: Mapping[str, Any] | None = None,
) -> Figure:
    """Transmittance Γ (dB) against ``x``, one line per value of ``hue`` (paper Fig. 5(a)).

    The linear reference Γ_lin (``transmittance_linear_db``, the same cell without stops) is a
    thin dashed line of the same colour, when the results have it. Irregular, unsettled and
    failed points are marked (:data:`MARKS`) and counted in the legend.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset with ``transmittance_db``.
    sel : mapping, optional
        Values of every dimension other than ``x`` and ``hue`` (see
        :func:`service.analysis.selection.slice_axes`).
    x : str, optional
        Horizontal axis; default ``gamma_r``, else ``frequency_hz``.
    hue : str, optional
        A dimension drawn as several lines (e.g. ``gap``).
    nearest : bool
        Take the closest coordinate values of ``sel``.
    fixed : mapping, optional
        Axes fixed by default (named in the title).

    Returns
    -------
    matplotlib.figure.Figure
        The figure (its canvas is Agg).
    """
    x = x or _default_x(ds, "transmittance_db")
    axes = [hue, x]
    da = slice_axes(ds, "transmittance_db", axes, sel, nearest).sortby(x)
    lin = None
    if "transmittance_linear_db" in ds.data_vars:
        lin = slice_axes(ds, "transmittance_linear_db", axes, sel, nearest).sortby(x)
    fig, ax = _figure()
    xv = da[x].values
    names = _outcomes(ds, axes, sel, nearest, da)
    taken = np.atleast_2d(_taken(names))
    rows = [da] if hue is None else [da.isel({hue: k}) for k in range(da.sizes[hue])]
    cmap = matplotlib.colormaps["viridis"]
    hue_units = None if hue is None else str(da[hue].attrs.get("units", "") or "") or None
    for k, row in enumerate(rows):
        color = "C0" if hue is None else cmap(k / max(len(rows) - 1, 1) * 0.9)
        label = "Γ" if hue is None else _quantity(hue, row[hue].values, hue_units, da[hue].values)
        on = taken[k]
        ax.plot(xv[on], row.values[on], marker=".", ms=3, lw=1.2, color=color, label=label)
        if lin is not None:
            ref = lin if hue is None else lin.isel({hue: k})
            ax.plot(xv[on], ref.values[on], ls="--", lw=0.8, color=color,
                    gid="linear-reference")  # fmt: skip
    chain = "cell" in ds.dims
    if lin is not None and np.isfinite(lin.values).any():
        what = "the chain" if chain else "the cell"
        ax.plot([], [], ls="--", lw=0.8, color="0.3", label=f"Γ_lin: {what} without stops")
    if x == "gamma_r" and "lattice_stop_bands" in ds.attrs and xv.size:
        _shade_stop_bands(ax, json.loads(str(ds.attrs["lattice_stop_bands"])), xv)
    ax.axhline(0.0, color="k", lw=0.8, ls=":", label="0 dB")
    _mark_outcomes(ax, xv, da.values.astype(np.float64), names)
    _label_axis(ax.xaxis, x, da[x])
    ax.set_ylabel("transmittance Γ (dB)")
    sub = _subtitle(da, skip=(x, *(fixed or {})) if hue is None else (x, hue, *(fixed or {})))
    ax.set_title(_title(sub, _fixed_text(fixed)), fontsize=9)
    ax.grid(True, lw=0.4, alpha=0.5)
    _legend(ax, loc="best", title=None if hue is None else axis_symbol(hue))
    return fig


def _shade_stop_bands(ax: Any, bands: Sequence[Sequence[float | None]], xv: np.ndarray) -> None:
    """Shade the infinite lattice's stop bands (γ_r; ``None``: open above) over ``xv``'s span."""
    lo_x, hi_x = float(np.min(xv)), float(np.max(xv))
    label = "stop band of the infinite lattice"
    for lo, hi in bands:
        a, b = max(float(lo or 0.0), lo_x), min(hi_x if hi is None else float(hi), hi_x)
        if a < b:
            ax.axvspan(a, b, color="0.6", alpha=0.2, lw=0, gid="stop-band", label=label)
            label = "_"  # one legend entry


def transmittance_png(
    ds: xr.Dataset,
    sel: Selection | None = None,
    x: str | None = None,
    hue: str | None = None,
    nearest: bool = False,
    *,
    fixed: Mapping[str, Any] | None = None,
    fmt: Format = "png",
) -> bytes:
    """:func:`transmittance_figure` as PNG (or SVG with ``fmt="svg"``) bytes."""
    _check_format(fmt)
    return _png(transmittance_figure(ds, sel, x, hue, nearest, fixed=fixed), fmt)


def cell_edges(values: np.ndarray) -> np.ndarray:
    """Edges of the cells centred on sorted grid ``values``: midpoints between neighbours, and
    half a step beyond each end (±0.5 around a single value)."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs ``[i, j)`` of true values of a 1-d mask."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def bandgap_figure(map_ds: xr.Dataset, *, fixed: Mapping[str, Any] | None = None) -> Figure:
    """A :func:`service.analysis.bands.bandgap_map` as a figure.

    Two-dimensional maps: the variable as a pcolormesh whose cells are centred on the grid
    points (edges at the midpoints, :func:`cell_edges`), with a diverging colormap (centred
    on the threshold; on 0 dB for the impact effect); the cells below the threshold hatched
    (one rectangle per run of such cells along x, on exactly those cells' edges, ``gid``
    ``attenuating``); band edges marked (``|`` at interpolated edges, ``>``/``<`` where the
    edge is the grid end or a missing point); irregular, unsettled and failed cells marked at
    their centres (:data:`MARKS`) and counted in the legend. One-dimensional maps: the
    variable against x with the bands shaded and the same marks. ``fixed`` axes are named in
    the title.
    """
    x = str(map_ds.attrs["x"])
    y = str(map_ds.attrs.get("y") or "") or None
    variable = str(map_ds.attrs.get("variable", "transmittance_db"))
    symbol, label = _VARIABLE_TEXT.get(variable, (variable, f"{variable} (dB)"))
    thr = float(map_ds.attrs["threshold_db"])
    gamma = map_ds[variable]
    xv = map_ds[x].values.astype(np.float64)
    names = None
    order = (*([y] if y else []), x)  # (y, x) or (x,), like the values below
    if "outcome" in map_ds.data_vars:
        names = outcome_names(map_ds["outcome"].transpose(*order)).astype(object)
        if TRANSIENT in map_ds.data_vars:
            names = _with_transient(names, map_ds[TRANSIENT].transpose(*order).values)
        if "pending" in map_ds.data_vars:
            names[np.asarray(map_ds["pending"].transpose(*order).values, dtype=bool)] = "pending"
        if "sampled" in map_ds.data_vars:
            took = np.asarray(map_ds["sampled"].transpose(*order).values, dtype=bool)
            names[~took] = UNSAMPLED
        names = names.astype(str)
    fig, ax = _figure()
    counts = np.atleast_1d(map_ds["band_count"].values)
    starts = np.atleast_2d(map_ds["band_start"].values)
    stops = np.atleast_2d(map_ds["band_stop"].values)
    s_edge = np.atleast_2d(map_ds["band_start_edge"].values)
    e_edge = np.atleast_2d(map_ds["band_stop_edge"].values)
    title = {
        "impact_effect_db": f"where impacts add attenuation ({symbol} < {thr:g} dB)",
        "transmittance_linear_db": f"bands of the cell without stops ({symbol} < {thr:g} dB)",
    }.get(variable, f"attenuation bands ({symbol} < {thr:g} dB)")
    sub = _subtitle(gamma, skip=(x, y or "", "band", *(fixed or {})))
    ax.set_title(_title(title, sub, _fixed_text(fixed)), fontsize=9)
    _label_axis(ax.xaxis, x, map_ds[x])

    if y is None:
        g = gamma.values.astype(np.float64)
        if names is not None:
            on = _taken(names)
            xv, g, names = xv[on], g[on], names[on]
        ax.plot(xv, g, marker=".", ms=3, lw=1.2, color="C0", label=symbol)
        ax.axhline(thr, color="k", lw=0.8, ls="--", label=f"threshold {thr:g} dB")
        for k in range(int(counts[0])):
            ax.axvspan(starts[0, k], stops[0, k], color="C1", alpha=0.25, lw=0,
                       label="band" if k == 0 else None)  # fmt: skip
        if names is None:
            names = np.where(np.isnan(g), "failed", "").astype(str)
        _mark_outcomes(ax, xv, g, names)
        ax.set_ylabel(label)
        ax.grid(True, lw=0.4, alpha=0.5)
        _legend(ax, loc="best")
        return fig

    yv = map_ds[y].values.astype(np.float64)
    values = gamma.transpose(y, x).values.astype(np.float64)
    below = np.asarray(map_ds["attenuating"].transpose(y, x).values, dtype=bool)
    if names is not None and (names == UNSAMPLED).any():
        # An adaptive study: each cell shows the line's last sample at or before it (a step
        # function of what was computed; the band edges drawn are the located ones).
        values, below = values.copy(), below.copy()
        for r in range(values.shape[0]):
            took = np.flatnonzero(names[r] != UNSAMPLED)
            if took.size:
                src = took[np.clip(np.searchsorted(took, np.arange(values.shape[1]),
                                                   side="right") - 1, 0, None)]  # fmt: skip
                values[r], below[r] = values[r, src], below[r, src]
    g = np.ma.masked_invalid(values)
    finite = g.compressed()
    centre = 0.0 if variable == "impact_effect_db" else thr
    lo = float(finite.min()) if finite.size else centre - 1.0
    hi = float(finite.max()) if finite.size else centre + 1.0
    span = max(abs(lo - centre), abs(hi - centre), 1e-6)
    norm = TwoSlopeNorm(vcenter=centre, vmin=centre - span, vmax=centre + span)
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad="0.75")
    xe, ye = cell_edges(xv), cell_edges(yv)
    mesh = ax.pcolormesh(xe, ye, g, cmap=cmap, norm=norm, shading="flat")
    cbar = fig.colorbar(mesh, ax=ax)
    cbar.set_label(label)
    cbar.ax.axhline(thr, color="k", lw=1.0)
    handles: list[Any] = []
    for r in range(yv.size):
        for i, j in _runs(below[r]):
            ax.add_patch(
                Rectangle(
                    (xe[i], ye[r]),
                    xe[j] - xe[i],
                    ye[r + 1] - ye[r],
                    fill=False,
                    hatch="//",
                    edgecolor="k",
                    lw=0.5,
                    gid="attenuating",
                )
            )
    if below.any():
        handles.append(
            Patch(
                facecolor="none",
                edgecolor="k",
                hatch="//",
                label=f"{symbol} < {thr:g} dB ({int(below.sum())} cells)",
            )
        )
    open_kinds = (EDGE_KINDS.index("grid_end"), EDGE_KINDS.index("missing"))
    uncertain = EDGE_KINDS.index("uncertain")
    for r, yy in enumerate(yv):
        for k in range(int(counts[r])):
            for val, kind, sym in (
                (starts[r, k], s_edge[r, k], "<"),
                (stops[r, k], e_edge[r, k], ">"),
            ):
                is_open = kind in open_kinds
                c = "0.45" if kind == uncertain else "k"
                # above the outcome marks (zorder 4): an edge is never hidden under a mark
                ax.plot([val], [yy], marker=sym if is_open else "|", ms=7 if is_open else 11,
                        mew=1.8, color=c, mfc="none" if is_open else c, ls="none", zorder=5,
                        gid="band-edge")  # fmt: skip
    kinds = {int(e[r, k]) for e in (s_edge, e_edge) for r in range(len(yv))
             for k in range(int(counts[r]))}  # fmt: skip
    if kinds & {EDGE_KINDS.index("crossing")}:
        handles.append(Line2D([], [], marker="|", ms=11, mew=1.8, color="k", ls="none",
                              label="band edge (interpolated)"))  # fmt: skip
    if kinds & {EDGE_KINDS.index("located")}:
        handles.append(Line2D([], [], marker="|", ms=11, mew=1.8, color="k", ls="none",
                              label="band edge (located to tol)"))  # fmt: skip
    if uncertain in kinds:
        handles.append(Line2D([], [], marker="|", ms=11, mew=1.8, color="0.45", ls="none",
                              label="band edge (uncertain: an interval)"))  # fmt: skip
    if any(
        (s_edge[r, k] in open_kinds) or (e_edge[r, k] in open_kinds)
        for r in range(len(yv))
        for k in range(int(counts[r]))
    ):
        handles.append(Line2D([], [], marker=">", ms=7, mew=1.5, color="k", mfc="none",
                              ls="none", label="edge at grid end / missing point"))  # fmt: skip
    if names is None:
        names = np.where(np.ma.getmaskarray(g), "failed", "").astype(str)
    xs, ys = np.meshgrid(xv, yv)
    for kind, style in MARKS.items():
        hit = names == kind
        n = int(hit.sum())
        if n:  # at the cell centres: every marked cell is a grid point
            ax.plot(xs[hit], ys[hit], ls="none", zorder=4, gid=f"outcome-{kind}", **style)
            handles.append(Line2D([], [], ls="none", label=_mark_label(kind, n), **style))
    pending = int(np.sum(names == "pending"))
    if pending:
        handles.append(Patch(facecolor="0.75", label=f"not computed yet ({pending})"))
    missing = int(np.sum(np.ma.getmaskarray(g) & ~np.isin(names, ["failed", "pending",
                                                                   UNSAMPLED])))  # fmt: skip
    if missing:
        handles.append(Patch(facecolor="0.75", label=f"missing ({missing})"))
    ax.set_xlim(xe[0], xe[-1])
    ax.set_ylim(ye[0], ye[-1])
    _label_axis(ax.yaxis, y, map_ds[y])
    if handles:
        fig.legend(handles=handles, fontsize=7, loc="outside lower center",
                   ncols=min(len(handles), 4))  # fmt: skip
    return fig


def bandgap_png(
    map_ds: xr.Dataset, *, fixed: Mapping[str, Any] | None = None, fmt: Format = "png"
) -> bytes:
    """:func:`bandgap_figure` as PNG (or SVG with ``fmt="svg"``) bytes."""
    _check_format(fmt)
    return _png(bandgap_figure(map_ds, fixed=fixed), fmt)


def effective_mass_figure(
    ds: xr.Dataset,
    sel: Selection | None = None,
    x: str | None = None,
    nearest: bool = False,
    *,
    fixed: Mapping[str, Any] | None = None,
) -> Figure:
    """Effective mass ratio θ_eff against ``x`` (paper Fig. 6): the first harmonic at γ_r
    (Eq. 35), the effective mass at every point (docs/model.md §6). The phase-portrait ratio
    θ_ps (``theta_eff_slope``: the slope of the velocity phase portrait, every harmonic weighted
    by its velocity power) is drawn beside it under its own name: equal to θ_eff where the
    motion is harmonic, not an effective mass at impacting points.

    Negative effective mass (θ_eff < 0) is shaded, with the shaded intervals' edges
    interpolated like band edges. When |θ_eff| spans more than two decades the y axis is
    symmetric-logarithmic (linear within ±1), so resonance peaks do not flatten the rest.
    Irregular, unsettled and failed points are marked on the θ_eff curve (:data:`MARKS`) and
    counted in the legend.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset with ``theta_eff`` (``theta_eff_slope``, θ_ps, is drawn when
        present).
    sel : mapping, optional
        Values of every dimension other than ``x``.
    x : str, optional
        Horizontal axis; default ``gamma_r``, else ``frequency_hz``.
    nearest : bool
        Take the closest coordinate values of ``sel``.
    fixed : mapping, optional
        Axes fixed by default (named in the title).

    Returns
    -------
    matplotlib.figure.Figure
        The figure (its canvas is Agg).
    """
    x = x or _default_x(ds, "theta_eff")
    harmonic = slice_axes(ds, "theta_eff", [x], sel, nearest).sortby(x)
    slope = (
        slice_axes(ds, "theta_eff_slope", [x], sel, nearest).sortby(x)
        if "theta_eff_slope" in ds.data_vars
        else None
    )
    names = _outcomes(ds, [x], sel, nearest, harmonic)
    on = _taken(names)
    xv = harmonic[x].values.astype(np.float64)[on]
    h = harmonic.values.astype(np.float64)[on]
    names = names[on]
    if slope is not None:
        slope = slope[on]
    fig, ax = _figure()
    for k, band in enumerate(band_edges(xv, h, 0.0)):
        ax.axvspan(band.start, band.stop, color="C3", alpha=0.15, lw=0,
                   label="θ_eff < 0 (negative effective mass)" if k == 0 else None)  # fmt: skip
    ax.plot(xv, h, marker=".", ms=3, lw=1.2, color="C0",
            label="θ_eff, effective mass (first harmonic, Eq. 35)")  # fmt: skip
    drawn_slope = slope is not None and np.isfinite(slope.values).any()
    if drawn_slope:
        ax.plot(xv, slope.values, marker="o", ms=3, lw=1.0, ls="--", mfc="none", color="C1",
                label="θ_ps, phase-portrait slope (all harmonics; not an effective mass "
                "at impacts)", gid="phase-portrait-ratio")  # fmt: skip
    ax.axhline(0.0, color="k", lw=0.8)
    _mark_outcomes(ax, xv, h, names)
    both = np.concatenate([h, slope.values if slope is not None else []])
    both = np.abs(both[np.isfinite(both)])
    if both.size and both.max() > 100 * max(np.median(both), 1.0):
        ax.set_yscale("symlog", linthresh=1.0)
    _label_axis(ax.xaxis, x, harmonic[x])
    ax.set_ylabel("effective mass ratio θ_eff" + (", θ_ps" if drawn_slope else "") + " (–)")
    what = "effective mass θ_eff: first harmonic at γ_r; shaded where negative"
    sub = _subtitle(harmonic, skip=(x, *(fixed or {})))
    ax.set_title(_title(what, sub, _fixed_text(fixed)), fontsize=9)
    ax.grid(True, lw=0.4, alpha=0.5)
    _legend(ax, loc="best")
    return fig


def effective_mass_png(
    ds: xr.Dataset,
    sel: Selection | None = None,
    x: str | None = None,
    nearest: bool = False,
    *,
    fixed: Mapping[str, Any] | None = None,
    fmt: Format = "png",
) -> bytes:
    """:func:`effective_mass_figure` as PNG (or SVG with ``fmt="svg"``) bytes."""
    _check_format(fmt)
    return _png(effective_mass_figure(ds, sel, x, nearest, fixed=fixed), fmt)


#: Colour, marker (pointing the way the sweep went) and line width of each sweep direction in
#: a hysteresis figure: up is drawn wider and first, so it shows where down lies on it.
_DIRECTION_STYLE: dict[str, tuple[str, str, float]] = {
    "up": ("C0", ">", 2.6),
    "down": ("C3", "<", 1.2),
}
_INITIAL_LINES = ("-", "--", ":", "-.")


def _branch_style(direction: str, k_initial: int, k: int) -> tuple[Any, str, str, float]:
    """Colour, marker, line style and width of a branch (direction: colour, marker and width;
    initial state without a direction: colour; with one: line style)."""
    if direction in _DIRECTION_STYLE:
        color, marker, lw = _DIRECTION_STYLE[direction]
        return color, marker, _INITIAL_LINES[k_initial % len(_INITIAL_LINES)], lw
    return f"C{k % 10}", ".", "-", 1.3


def hysteresis_figure(h: xr.Dataset, *, fixed: Mapping[str, Any] | None = None) -> Figure:
    """A :func:`service.analysis.hysteresis.hysteresis_map` as a figure.

    Every branch is a curve (up and down in two colours, with ``>``/``<`` markers pointing the
    way the sweep went; initial states in their own colours, or line styles under a sweep),
    broken at its jumps; each jump is a vertical dashed segment (``gid`` ``jump``) at the x the
    branch lands on, from the value before to the value after, labelled ``J1``, ... (``gid``
    ``jump-label``; when any two labels would overlap, none is drawn and the legend lists the
    jumps instead, :data:`_LISTED_JUMPS` at most); the grid
    cells where the branches differ are shaded (``gid`` ``differs``, edges at the midpoints
    between grid points, :func:`cell_edges`); irregular, unsettled and failed points are marked
    as in every figure (:data:`MARKS`). The legend counts points per branch, jumps, differing
    points and points with several responses. ``fixed`` defaults to the map's own.
    """
    x = str(h.attrs["x"])
    variable = str(h.attrs["variable"])
    da = h[variable]
    units = _units(da)
    symbol, label = _VARIABLE_TEXT.get(variable, (variable, f"{variable} ({units})"))
    jump_db, tol_db = float(h.attrs["jump_db"]), float(h.attrs["tol_db"])
    xv = h[x].values.astype(np.float64)
    rows = np.asarray(da.values, dtype=np.float64)
    labels = [str(v) for v in h["branch"].values]
    directions = [str(v) for v in h["branch_direction"].values]
    inits = [str(v) for v in h["branch_initial"].values]
    init_index = {v: k for k, v in enumerate(dict.fromkeys(inits))}
    if fixed is None:
        fixed = fixed_of(h)
    fig, ax = _figure()
    u = "" if units == "–" else f" {units}"

    differs = np.asarray(h["differs"].values, dtype=bool)
    edges = cell_edges(xv)
    what = "up and down differ" if set(directions) == {"up", "down"} and len(set(inits)) == 1 \
        else "branches differ"  # fmt: skip
    for k, (i, j) in enumerate(_runs(differs)):
        ax.axvspan(edges[i], edges[j], color="C1", alpha=0.18, lw=0, gid="differs",
                   label=f"{what} by > {tol_db:g}{u} ({int(differs.sum())} points)"
                   if k == 0 else None)  # fmt: skip

    jb = np.asarray(h["jump_branch"].values, dtype=np.int64)
    j_to = np.asarray(h["jump_to"].values, dtype=np.float64)
    j_from = np.asarray(h["jump_from"].values, dtype=np.float64)
    j_v0 = np.asarray(h["jump_from_value"].values, dtype=np.float64)
    j_v1 = np.asarray(h["jump_to_value"].values, dtype=np.float64)
    j_lab = [str(v) for v in h["jump_label"].values]
    styles = []
    for b, row in enumerate(rows):
        color, marker, ls, lw = _branch_style(directions[b], init_index[inits[b]], b)
        styles.append(color)
        # break the curve between the two points of each of its jumps
        cuts = sorted(int(np.searchsorted(xv, max(j_from[k], j_to[k]))) for k in
                      np.flatnonzero(jb == b))  # fmt: skip
        bounds = [0, *cuts, xv.size]
        n = int(np.isfinite(row).sum())
        for s, (a, c) in enumerate(itertools.pairwise(bounds)):
            ax.plot(xv[a:c], row[a:c], color=color, ls=ls, lw=lw, marker=marker, ms=2 + 1.5 * lw,
                    gid=f"branch-{labels[b]}",
                    label=f"{labels[b]} ({n} points)" if s == 0 else None)  # fmt: skip
    stacked: dict[float, int] = {}  # labels of jumps at one x go one under the other
    texts = []
    for k in range(jb.size):
        color = styles[jb[k]]
        row_k = stacked[float(j_to[k])] = stacked.get(float(j_to[k]), -1) + 1
        jump_label = f"jump > {jump_db:g}{u} ({jb.size})" if k == 0 else None
        ax.plot([j_to[k], j_to[k]], [j_v0[k], j_v1[k]], ls="--", lw=1.4, color=color,
                gid="jump", label=jump_label)  # fmt: skip
        texts.append(ax.annotate(
            j_lab[k], (j_to[k], 0.5 * (j_v0[k] + j_v1[k])), xytext=(3, -9 * row_k),
            textcoords="offset points", fontsize=7, color=color, gid="jump-label", zorder=6,
            bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8},
        ))  # fmt: skip

    if "outcome" in h.data_vars:
        names = outcome_names(h["outcome"]).astype(object)
        if TRANSIENT in h.data_vars:
            names = _with_transient(names, h[TRANSIENT].values)
        if "pending" in h.data_vars:
            names[np.asarray(h["pending"].values, dtype=bool)] = "pending"
        names = names.astype(str)
    else:
        names = np.where(np.isnan(rows), "failed", "").astype(str)
    _mark_outcomes(ax, xv, rows, names)
    if "responses" in h.data_vars:
        resp = np.asarray(h["responses"].values, dtype=np.float64)
        several = int(np.sum(resp > 1))
        if several:
            ax.plot([], [], " ", label=f"2 or more responses ({several} points)")
    title = f"hysteresis of {symbol} along {axis_symbol(x)}: {len(labels)} branches"
    sub = _subtitle(da, skip=(x, *fixed))
    ax.set_title(_title(title, sub, _fixed_text(fixed)), fontsize=9)
    _label_axis(ax.xaxis, x, h[x])
    ax.set_ylabel(label)
    ax.grid(True, lw=0.4, alpha=0.5)
    if _overlapping(fig, texts):
        # Labels that would pile over each other go to the legend, one line per jump.
        factor, xu = _scale(x, xv, str(h[x].attrs.get("units", "") or ""))
        xu = "" if xu in ("", "1") else f" {xu}"
        for t in texts:
            t.remove()
        for k in range(min(jb.size, _LISTED_JUMPS)):
            ax.plot([], [], ls="--", lw=1.4, color=styles[jb[k]],
                    label=f"{j_lab[k]} {labels[jb[k]]}: {axis_symbol(x)} "
                    f"{_value(j_from[k] / factor)} → {_value(j_to[k] / factor)}{xu}, "
                    f"{j_v1[k] - j_v0[k]:+.3g}{u}")  # fmt: skip
        if jb.size > _LISTED_JUMPS:
            ax.plot([], [], " ", label=f"… {jb.size - _LISTED_JUMPS} more jumps (JSON, CSV)")
    _legend(ax, loc="best")
    return fig


_LISTED_JUMPS = 8  # jumps a hysteresis figure's legend lists when their labels would overlap


def _overlapping(fig: Figure, texts: Sequence[Any]) -> bool:
    """Whether any two of ``texts`` overlap once the figure is laid out."""
    if len(texts) < 2:
        return False
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer) for t in texts]
    return any(a.overlaps(b) for a, b in itertools.combinations(boxes, 2))


def hysteresis_png(
    h: xr.Dataset, *, fixed: Mapping[str, Any] | None = None, fmt: Format = "png"
) -> bytes:
    """:func:`hysteresis_figure` as PNG (or SVG with ``fmt="svg"``) bytes."""
    _check_format(fmt)
    return _png(hysteresis_figure(h, fixed=fixed), fmt)


def warm_up() -> None:
    """Draw a small labelled PNG once: the first figure of a process loads fonts and caches
    while holding the GIL for about a second, which the service does at start rather than
    while requests wait."""
    fig = Figure(figsize=(1, 1))
    FigureCanvasAgg(fig)
    fig.add_subplot().set_title("γ_r")
    fig.savefig(io.BytesIO(), format="png")
