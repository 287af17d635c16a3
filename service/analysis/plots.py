"""PNG and SVG figures of results datasets (the only module that imports matplotlib).

Every function builds its own :class:`matplotlib.figure.Figure` with a
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg` (no pyplot state), so figures can
be drawn from several threads of a web server at once. Each returns the bytes of a figure of a
fixed size (``figsize × dpi``; no tight bounding box): PNG, or SVG with ``fmt="svg"``. Axes
that a request left open and that were fixed at a default (``fixed``, from
:func:`service.analysis.selection.default_view`) are named in the title.

Selections go through :mod:`service.analysis.selection`, so a bad selection raises
:class:`~service.analysis.selection.AnalysisError` with the same message as everywhere else.
Symbols and units of the axes come from :mod:`service.studies.variables`.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import matplotlib
import numpy as np
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from service.analysis.bands import EDGE_KINDS, band_edges
from service.analysis.selection import AnalysisError, Selection, slice_axes
from service.studies.variables import AXES, axis_symbol, default_x

# Select the non-interactive backend before pyplot is loaded anywhere (this module never
# does: figures are drawn with the object API).
matplotlib.use("Agg")

__all__ = [
    "DPI",
    "FIGSIZE",
    "FORMATS",
    "bandgap_png",
    "effective_mass_png",
    "transmittance_png",
]

FIGSIZE: tuple[float, float] = (8.0, 5.0)  # inches
DPI = 120  # FIGSIZE × DPI = 960 × 600 pixels
Format = Literal["png", "svg"]
FORMATS: dict[str, str] = {"png": "image/png", "svg": "image/svg+xml"}  # format -> media type


def _units(da: xr.DataArray) -> str:
    u = str(da.attrs.get("units", "") or "")
    return "–" if u in ("", "1") else u


def _axis_label(name: str, coord: xr.DataArray) -> str:
    """``γ_r = Ω/ω_b (–)``, ``frequency (Hz)``, ``gap_m (m)``."""
    units = _units(coord)
    info = AXES.get(name)
    if info is not None and info.label:
        return f"{info.label} ({units})"
    symbol, definition = axis_symbol(name), info.definition if info is not None else ""
    text = f"{symbol} = {definition}" if definition and definition != symbol else symbol
    return f"{text} ({units})"


def _value(v: Any) -> str:
    v = np.asarray(v).item()
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _subtitle(da: xr.DataArray, skip: Sequence[str] = ()) -> str:
    """The fixed parameters of a slice (its 0-d coordinates), e.g. ``θ = 0.3, σ = 0.05``."""
    parts = []
    for name, c in da.coords.items():
        if c.ndim == 0 and name not in skip and c.dtype.kind in "iuf":
            units = _units(c)
            parts.append(
                f"{axis_symbol(str(name))} = {_value(c.values)}"
                + ("" if units == "–" else f" {units}")
            )
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


def _png(fig: Figure, fmt: Format = "png") -> bytes:
    if fmt not in FORMATS:
        raise AnalysisError(f"format={fmt!r} is not a figure format; formats are png, svg")
    buf = io.BytesIO()
    # A fixed hash salt and no date: the same figure gives the same SVG bytes (cacheable).
    metadata = {"Date": None} if fmt == "svg" else None
    with matplotlib.rc_context({"svg.hashsalt": "impactcell"}):
        fig.savefig(buf, format=fmt, dpi=DPI, metadata=metadata)
    return buf.getvalue()


def _fixed_text(fixed: Mapping[str, Any] | None) -> str:
    """``fixed at their first value (select others): θ = 0.1`` for defaulted axes."""
    if not fixed:
        return ""
    parts = ", ".join(f"{axis_symbol(k)} = {_value(v)}" for k, v in fixed.items())
    names = ", ".join(fixed)
    return f"by default at the first value (choose with {names}=…): {parts}"


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
    """Transmittance Γ (dB) against ``x``, one line per value of ``hue`` (paper Fig. 5(a)).

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
    fmt : {"png", "svg"}
        Image format.

    Returns
    -------
    bytes
        A PNG (or SVG) image.
    """
    x = x or _default_x(ds, "transmittance_db")
    da = slice_axes(ds, "transmittance_db", [hue, x], sel, nearest).sortby(x)
    fig, ax = _figure()
    xv = da[x].values
    if hue is None:
        ax.plot(xv, da.values, marker=".", ms=3, lw=1.2, label="Γ")
    else:
        cmap = matplotlib.colormaps["viridis"]
        n = da.sizes[hue]
        for k in range(n):
            row = da.isel({hue: k})
            color = cmap(k / max(n - 1, 1) * 0.9)
            label = f"{axis_symbol(hue)} = {_value(row[hue].values)}"
            ax.plot(xv, row.values, marker=".", ms=3, lw=1.2, color=color, label=label)
    ax.axhline(0.0, color="k", lw=0.8, ls="--", label="0 dB")
    missing = int(np.isnan(da.values).sum())
    if missing:
        ax.plot([], [], " ", label=f"{missing} missing point{'s' if missing != 1 else ''}")
    ax.set_xlabel(_axis_label(x, da[x]))
    ax.set_ylabel("transmittance Γ (dB)")
    sub = _subtitle(da, skip=(x,) if hue is None else (x, hue))
    ax.set_title(_title(sub, _fixed_text(fixed)), fontsize=9)
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize=8, loc="best", title=None if hue is None else axis_symbol(hue))
    return _png(fig, fmt)


def bandgap_png(
    map_ds: xr.Dataset, *, fixed: Mapping[str, Any] | None = None, fmt: Format = "png"
) -> bytes:
    """A :func:`service.analysis.bands.bandgap_map` as an image.

    Two-dimensional maps: Γ as a pcolormesh with a diverging colormap centred on the
    threshold, the attenuating region hatched and outlined (the threshold contour), band
    edges marked (``|`` at interpolated edges, ``>``/``<`` where the edge is the grid end or a
    missing point). One-dimensional maps: Γ against x with the bands shaded. ``fixed`` axes
    are named in the title; ``fmt`` is ``png`` or ``svg``.

    Returns
    -------
    bytes
        A PNG (or SVG) image.
    """
    x = str(map_ds.attrs["x"])
    y = str(map_ds.attrs.get("y") or "") or None
    thr = float(map_ds.attrs["threshold_db"])
    gamma = map_ds["transmittance_db"]
    xv = map_ds[x].values.astype(np.float64)
    fig, ax = _figure()
    counts = np.atleast_1d(map_ds["band_count"].values)
    starts = np.atleast_2d(map_ds["band_start"].values)
    stops = np.atleast_2d(map_ds["band_stop"].values)
    s_edge = np.atleast_2d(map_ds["band_start_edge"].values)
    e_edge = np.atleast_2d(map_ds["band_stop_edge"].values)
    title = f"attenuation bands (Γ < {thr:g} dB)"
    sub = _subtitle(gamma, skip=(x, y or "", "band"))
    ax.set_title(_title(title, sub, _fixed_text(fixed)), fontsize=9)
    ax.set_xlabel(_axis_label(x, map_ds[x]))

    if y is None:
        g = gamma.values.astype(np.float64)
        ax.plot(xv, g, marker=".", ms=3, lw=1.2, color="C0", label="Γ")
        ax.axhline(thr, color="k", lw=0.8, ls="--", label=f"threshold {thr:g} dB")
        for k in range(int(counts[0])):
            ax.axvspan(
                starts[0, k],
                stops[0, k],
                color="C1",
                alpha=0.25,
                lw=0,
                label="attenuation band" if k == 0 else None,
            )
        ax.set_ylabel("transmittance Γ (dB)")
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.legend(fontsize=8, loc="best")
        return _png(fig, fmt)

    yv = map_ds[y].values.astype(np.float64)
    g = np.ma.masked_invalid(gamma.transpose(y, x).values.astype(np.float64))
    finite = g.compressed()
    lo = float(finite.min()) if finite.size else thr - 1.0
    hi = float(finite.max()) if finite.size else thr + 1.0
    span = max(abs(lo - thr), abs(hi - thr), 1e-6)
    norm = TwoSlopeNorm(vcenter=thr, vmin=thr - span, vmax=thr + span)
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad="0.75")
    mesh = ax.pcolormesh(xv, yv, g, cmap=cmap, norm=norm, shading="nearest")
    cbar = fig.colorbar(mesh, ax=ax)
    cbar.set_label("Γ (dB)")
    cbar.ax.axhline(thr, color="k", lw=1.0)
    handles: list[Any] = []
    if xv.size > 1 and yv.size > 1 and finite.size and lo < thr < hi:
        ax.contourf(
            xv, yv, g, levels=[lo - 1.0, thr], colors="none", hatches=["//"], antialiased=False
        )
        ax.contour(xv, yv, g, levels=[thr], colors="k", linewidths=1.0)
        handles.append(Patch(facecolor="none", edgecolor="k", hatch="//", label="Γ < threshold"))
    elif finite.size and hi < thr:
        handles.append(Patch(facecolor="none", edgecolor="k", label="everywhere Γ < threshold"))
    open_kinds = (EDGE_KINDS.index("grid_end"), EDGE_KINDS.index("missing"))
    for r, yy in enumerate(yv):
        for k in range(int(counts[r])):
            for val, kind, sym in (
                (starts[r, k], s_edge[r, k], "<"),
                (stops[r, k], e_edge[r, k], ">"),
            ):
                is_open = kind in open_kinds
                ax.plot(
                    [val],
                    [yy],
                    marker=sym if is_open else "|",
                    ms=7 if is_open else 11,
                    mew=1.8,
                    color="k",
                    mfc="none" if is_open else "k",
                    ls="none",
                )
    if counts.sum():
        handles.append(Line2D([], [], marker="|", ms=11, mew=1.8, color="k", ls="none",
                              label="band edge (interpolated)"))  # fmt: skip
    if any(
        (s_edge[r, k] in open_kinds) or (e_edge[r, k] in open_kinds)
        for r in range(len(yv))
        for k in range(int(counts[r]))
    ):
        handles.append(Line2D([], [], marker=">", ms=7, mew=1.5, color="k", mfc="none",
                              ls="none", label="edge at grid end / missing point"))  # fmt: skip
    if np.ma.count_masked(g):
        handles.append(Patch(facecolor="0.75", label="missing (failed point)"))
    ax.set_ylabel(_axis_label(y, map_ds[y]))
    if handles:
        fig.legend(handles=handles, fontsize=7, loc="outside lower center", ncols=len(handles))
    return _png(fig, fmt)


def effective_mass_png(
    ds: xr.Dataset,
    sel: Selection | None = None,
    x: str | None = None,
    nearest: bool = False,
    *,
    fixed: Mapping[str, Any] | None = None,
    fmt: Format = "png",
) -> bytes:
    """Effective mass ratio θ_eff against ``x`` (paper Fig. 6): from first harmonics (Eq. 35)
    and, as a second estimator, from the slope of the velocity phase portrait.

    Negative effective mass (θ_eff < 0) is shaded, with the shaded intervals' edges
    interpolated like band edges. When |θ_eff| spans more than two decades the y axis is
    symmetric-logarithmic (linear within ±1), so resonance peaks do not flatten the rest.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset with ``theta_eff`` (``theta_eff_slope`` is drawn when present).
    sel : mapping, optional
        Values of every dimension other than ``x``.
    x : str, optional
        Horizontal axis; default ``gamma_r``, else ``frequency_hz``.
    nearest : bool
        Take the closest coordinate values of ``sel``.
    fixed : mapping, optional
        Axes fixed by default (named in the title).
    fmt : {"png", "svg"}
        Image format.

    Returns
    -------
    bytes
        A PNG (or SVG) image.
    """
    x = x or _default_x(ds, "theta_eff")
    harmonic = slice_axes(ds, "theta_eff", [x], sel, nearest).sortby(x)
    slope = (
        slice_axes(ds, "theta_eff_slope", [x], sel, nearest).sortby(x)
        if "theta_eff_slope" in ds.data_vars
        else None
    )
    xv = harmonic[x].values.astype(np.float64)
    h = harmonic.values.astype(np.float64)
    fig, ax = _figure()
    for k, band in enumerate(band_edges(xv, h, 0.0)):
        ax.axvspan(
            band.start,
            band.stop,
            color="C3",
            alpha=0.15,
            lw=0,
            label="θ_eff < 0 (negative effective mass)" if k == 0 else None,
        )
    ax.plot(xv, h, marker=".", ms=3, lw=1.2, color="C0", label="θ_eff, first harmonics (Eq. 35)")
    if slope is not None and np.isfinite(slope.values).any():
        ax.plot(
            xv,
            slope.values,
            marker="o",
            ms=3,
            lw=1.0,
            ls="--",
            mfc="none",
            color="C1",
            label="θ_eff, phase-portrait slope",
        )
    ax.axhline(0.0, color="k", lw=0.8)
    both = np.concatenate([h, slope.values if slope is not None else []])
    both = np.abs(both[np.isfinite(both)])
    if both.size and both.max() > 100 * max(np.median(both), 1.0):
        ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel(_axis_label(x, harmonic[x]))
    ax.set_ylabel("effective mass ratio θ_eff (–)")
    ax.set_title(_title(_subtitle(harmonic, skip=(x,)), _fixed_text(fixed)), fontsize=9)
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize=8, loc="best")
    return _png(fig, fmt)
