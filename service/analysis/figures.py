"""One figure of a results dataset by kind, with every default filled in: what the service's
``/studies/{id}/plots/{kind}.{fmt}`` and ``impactcell plot`` both draw, so the two give the same
figure for the same options.

Pure numpy + xarray + matplotlib (no web framework); every problem is an
:class:`~service.analysis.selection.AnalysisError` naming the option, the value and what is
allowed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import xarray as xr

from service.analysis.bands import MAP_VARIABLES, bandgap_map
from service.analysis.hysteresis import fixed_of, hysteresis_map
from service.analysis.selection import AnalysisError, Selection, View, default_view

__all__ = ["KINDS", "Drawn", "describe", "figure", "map_variable"]

#: The figures there are: ``impact-effect`` is the bandgap map of Γ − Γ_lin (threshold −1 dB).
KINDS: tuple[str, ...] = (
    "transmittance",
    "bandgap",
    "impact-effect",
    "effective-mass",
    "hysteresis",
)


class Drawn(NamedTuple):
    """A figure: its ``image`` (PNG or SVG bytes), the ``view`` it shows, and the ``data``
    drawn when it is a map (:func:`~service.analysis.bands.bandgap_map` or
    :func:`~service.analysis.hysteresis.hysteresis_map`; None for curves)."""

    image: bytes
    view: View
    data: xr.Dataset | None = None


def map_variable(variable: str, reference: str = "none") -> str:
    """The variable a map shows: ``reference="linear"`` is the impact effect Γ − Γ_lin.

    Raises
    ------
    AnalysisError
        An unknown reference, or ``reference="linear"`` with a variable other than Γ.
    """
    if reference == "none":
        return variable
    if reference != "linear":
        raise AnalysisError(f"reference={reference!r} is not known; references are none, linear")
    if variable not in ("transmittance_db", "impact_effect_db"):
        raise AnalysisError(
            f"reference=linear maps Γ − Γ_lin (impact_effect_db); it cannot be combined "
            f"with variable={variable}"
        )
    return "impact_effect_db"


def figure(
    ds: xr.Dataset,
    kind: str,
    fmt: str = "png",
    sel: Selection | None = None,
    *,
    x: str | None = None,
    y: str | None = None,
    hue: str | None = None,
    threshold_db: float | None = None,
    nearest: bool = False,
    variable: str = "transmittance_db",
    jump_db: float = 1.0,
    tol_db: float = 0.05,
    check: Callable[[xr.Dataset], None] | None = None,
) -> Drawn:
    """A figure of ``ds`` as PNG or SVG bytes, the view it shows and the map it draws.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset.
    kind : str
        One of :data:`KINDS`: ``transmittance`` (Γ and Γ_lin over x, one curve per ``hue``),
        ``bandgap`` (the map of ``variable`` over x × y), ``impact-effect`` (the bandgap map
        of ``impact_effect_db``), ``effective-mass`` (θ_eff over x), ``hysteresis`` (the
        branches of a sweep or multi-start study).
    fmt : str
        ``png`` or ``svg``.
    sel : mapping, optional
        Coordinate values of other axes; every varying axis not given and not drawn is fixed
        at its first value (``View.fixed``, named in the title).
    x, y, hue
        The axes; left out, the defaults of :func:`service.analysis.selection.default_view`
        (x the frequency axis, or the swept one for ``hysteresis``; y and hue the first other
        varying axis with few values).
    threshold_db, nearest, variable, jump_db, tol_db
        As the service's ``/bandgap`` and ``/hysteresis`` take them; ``variable`` is one of
        :data:`~service.analysis.bands.MAP_VARIABLES` for a map, any numeric variable for
        ``hysteresis``.
    check : callable, optional
        Called with a hysteresis map before it is drawn (the service refuses one over its
        size limit there).

    Raises
    ------
    AnalysisError
        An unknown kind, axis, value or variable, or a study the kind does not fit.
    """
    if kind not in KINDS:
        raise AnalysisError(f"kind={kind!r} is not a figure; figures are {', '.join(KINDS)}")
    from service.analysis import plots  # matplotlib: loaded only when a figure is drawn

    if kind == "hysteresis":
        h = hysteresis_map(ds, x, sel, nearest=nearest, variable=variable, jump_db=jump_db,
                           tol_db=tol_db)  # fmt: skip
        if check is not None:
            check(h)
        view = View(str(h.attrs["x"]), None, {}, fixed_of(h))
        return Drawn(plots.hysteresis_png(h, fmt=fmt), view, h)
    if kind == "transmittance":
        v = default_view(ds, "transmittance_db", x, hue, sel)
        image = plots.transmittance_png(ds, v.sel, x=v.x, hue=v.y, nearest=nearest,
                                        fixed=v.fixed, fmt=fmt)  # fmt: skip
        return Drawn(image, v)
    if kind == "effective-mass":
        v = default_view(ds, "theta_eff", x, None, sel, auto_y=False)
        image = plots.effective_mass_png(ds, v.sel, x=v.x, nearest=nearest, fixed=v.fixed,
                                         fmt=fmt)  # fmt: skip
        return Drawn(image, v)
    if kind == "impact-effect":
        if variable not in ("transmittance_db", "impact_effect_db"):
            raise AnalysisError(
                f"the impact-effect map shows impact_effect_db; variable={variable} is for "
                "the bandgap map"
            )
        variable = "impact_effect_db"
    elif variable not in MAP_VARIABLES:
        raise AnalysisError(
            f"variable={variable!r} cannot be mapped; a bandgap map shows "
            f"{', '.join(MAP_VARIABLES)}"
        )
    v = default_view(ds, "transmittance_db", x, y, sel)
    m = bandgap_map(ds, v.x, v.y, threshold_db=threshold_db, sel=v.sel, nearest=nearest,
                    variable=variable)  # fmt: skip
    return Drawn(plots.bandgap_png(m, fixed=v.fixed, fmt=fmt), v, m)


def describe(view: View) -> dict[str, Any]:
    """The view as JSON-ready data: ``x``, ``y`` and the axes fixed by default."""
    from service.studies.dataset import jsonable

    return {"x": view.x, "y": view.y, "fixed": {k: jsonable(f) for k, f in view.fixed.items()}}
