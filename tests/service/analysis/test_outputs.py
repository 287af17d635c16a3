"""Outputs of service.analysis that describe themselves: default views (what a request left open
and how it was filled in), CSV slices and band edges, the self-describing bandgap JSON, SVG."""

from __future__ import annotations

import csv
import io
import json
import math
from typing import Any

import numpy as np
import pytest
import xarray as xr

from service.analysis import plots
from service.analysis.bands import bandgap_csv, bandgap_json, bandgap_map
from service.analysis.selection import (
    FEW_VALUES,
    AnalysisError,
    default_view,
    default_y,
    select,
    slice_csv,
)

NAN = math.nan


def _ds(ntheta: int = 2, ngap: int = 3) -> xr.Dataset:
    """Γ over gap × theta × gamma_r: a band where gamma_r is 1 or 2, one failed point."""
    gr = np.array([0.5, 1.0, 2.0, 3.0])
    gap = np.round(np.linspace(0.1, 1.0, ngap), 6)
    theta = np.round(np.linspace(0.1, 0.9, ntheta), 6)
    g = np.tile(np.array([1.0, -1.0, -3.0, 1.0]), (ngap, ntheta, 1))
    g[0, 0, 3] = NAN
    dims = ("gap", "theta", "gamma_r")
    outcome = np.zeros(g.shape, dtype=np.int8)
    outcome[0, 0, 3] = 4
    return xr.Dataset(
        {
            "transmittance_db": (dims, g, {"units": "dB", "long_name": "transmittance"}),
            "theta_eff": (dims, -g, {"units": "1"}),
            "failed": (dims, np.isnan(g)),
            "reason": (dims, np.where(np.isnan(g), "diverged", "").astype(object)),
            "outcome": (
                dims,
                outcome,
                {
                    "flag_values": np.arange(5, dtype=np.int8),
                    "flag_meanings": "linear periodic irregular unsettled failed",
                },
            ),  # fmt: skip
        },
        coords={
            "gap": ("gap", gap, {"units": "1", "long_name": "clearance"}),
            "theta": ("theta", theta, {"units": "1", "long_name": "mass ratio"}),
            "gamma_r": ("gamma_r", gr, {"units": "1", "long_name": "frequency"}),
            "sigma": ((), 0.05, {"units": "1", "long_name": "stiffness"}),
        },
    )


# --------------------------------------------------------------------------- defaults


def test_default_view_fills_in_what_is_left_open() -> None:
    ds = _ds()
    v = default_view(ds)
    assert (v.x, v.y) == ("gamma_r", "gap")  # gap before theta in model order
    assert v.fixed == {"theta": 0.1} and float(v.sel["theta"]) == 0.1
    given = default_view(ds, sel={"gap": "0.55"})
    assert given.y == "theta" and given.fixed == {} and given.sel == {"gap": "0.55"}
    no_y = default_view(ds, "theta_eff", auto_y=False)
    assert no_y.y is None and no_y.fixed == {"gap": 0.1, "theta": 0.1}
    explicit = default_view(ds, x="gamma_r", y="theta")
    assert explicit.fixed == {"gap": 0.1}
    with pytest.raises(AnalysisError, match="variable='nope'"):
        default_view(ds, "nope")


def test_default_y_prefers_an_axis_with_few_values() -> None:
    many = _ds(ntheta=3, ngap=FEW_VALUES + 1)
    assert default_y(many, "gamma_r") == "theta"  # gap has too many values for a legend
    only_many = many.isel(theta=0)
    assert default_y(only_many, "gamma_r") == "gap"  # ... unless it is the only one left
    assert default_y(_ds().isel(gap=0, theta=0), "gamma_r") is None


def test_no_frequency_axis_needs_x() -> None:
    ds = _ds().isel(gamma_r=0)
    with pytest.raises(AnalysisError, match="x is required"):
        default_view(ds)
    assert default_view(ds, x="gap").y == "theta"


# --------------------------------------------------------------------------- CSV


def test_slice_csv_long_form_with_missing_and_flags() -> None:
    ds = _ds()
    rows = list(csv.DictReader(io.StringIO(slice_csv(select(ds, "transmittance_db",
                                                            {"theta": 0.1})))))  # fmt: skip
    assert list(rows[0]) == ["gap", "gamma_r", "transmittance_db", "theta", "sigma"]
    assert len(rows) == 12 and rows[3]["transmittance_db"] == ""  # the failed point
    assert [r["transmittance_db"] for r in rows[4:8]] == ["1.0", "-1.0", "-3.0", "1.0"]
    assert {r["theta"] for r in rows} == {"0.1"} and {r["sigma"] for r in rows} == {"0.05"}
    flags = slice_csv(select(ds, "outcome", {"theta": 0.1, "gap": 0.1}))
    expect = ["0.5,linear", "1.0,linear", "2.0,linear", "3.0,failed"]
    assert flags.splitlines()[1:] == [f"{e},0.1,0.1,0.05" for e in expect]
    text = slice_csv(select(ds, "reason", {"theta": 0.1, "gap": 0.1}))
    assert text.splitlines()[-1] == "3.0,diverged,0.1,0.1,0.05"
    booleans = slice_csv(select(ds, "failed", {"theta": 0.1, "gap": 0.1, "gamma_r": 3.0}))
    assert booleans.splitlines() == ["failed,gap,theta,gamma_r,sigma", "true,0.1,0.1,3.0,0.05"]


def test_bandgap_csv_one_row_per_band() -> None:
    m = bandgap_map(_ds(), "gamma_r", "gap", sel={"theta": 0.1})
    rows = list(csv.DictReader(io.StringIO(bandgap_csv(m))))
    assert list(rows[0]) == ["gap", "band", "start", "stop", "start_edge", "stop_edge",
                             "threshold_db", "theta", "sigma"]  # fmt: skip
    # Γ = 1, -1, -3, 1 at 0.5, 1, 2, 3: from 0.5 + 0.5·0.5 = 0.75 to 2 + 0.75·1 = 2.75;
    # the first gap's last point failed: its band ends at 2 (missing).
    assert [(r["gap"], r["start"], r["stop"], r["stop_edge"]) for r in rows] == [
        ("0.1", "0.75", "2.0", "missing"), ("0.55", "0.75", "2.75", "crossing"),
        ("1.0", "0.75", "2.75", "crossing"),
    ]  # fmt: skip
    none = bandgap_map(_ds(), "gamma_r", "gap", threshold_db=-10, sel={"theta": 0.1})
    lines = bandgap_csv(none).splitlines()
    assert len(lines) == 4 and lines[1] == "0.1,,,,,,-10.0,0.1,0.05"  # every gap, no band


# --------------------------------------------------------------------------- JSON, figures


def test_bandgap_json_describes_itself() -> None:
    m = bandgap_map(_ds(), "gamma_r", "gap", threshold_db=-0.5, sel={"theta": 0.1})
    out = bandgap_json(m, fixed={"theta": 0.1})
    assert out["variable"] == {"name": "transmittance_db", "units": "dB",
                               "long_name": "transmittance"}  # fmt: skip
    assert out["threshold"]["value"] == -0.5 and out["threshold"]["units"] == "dB"
    assert "< -0.5 dB" in out["threshold"]["meaning"]
    assert out["axes"]["x"] == {"name": "gamma_r", "units": "1", "long_name": "frequency",
                                "values": [0.5, 1.0, 2.0, 3.0]}  # fmt: skip
    assert out["axes"]["y"]["name"] == "gap" and out["axes"]["y"]["long_name"] == "clearance"
    assert out["slice"] == {
        "theta": {"value": 0.1, "units": "1", "long_name": "mass ratio", "default": True},
        "sigma": {"value": 0.05, "units": "1", "long_name": "stiffness", "default": False},
    }
    assert out["edge_units"] == "1" and set(out["edge_kinds"]) == {
        "crossing", "grid_end", "missing", "located", "uncertain"}  # fmt: skip
    json.dumps(out, allow_nan=False)
    one_d = bandgap_json(bandgap_map(_ds(), "gamma_r", sel={"theta": 0.1, "gap": 1.0}))
    assert one_d["axes"]["y"] is None and one_d["slice"]["gap"]["default"] is False


@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_figures_in_both_formats_name_the_fixed_axes(fmt: str) -> None:
    ds = _ds()
    v = default_view(ds)
    kw: dict[str, Any] = {"fixed": v.fixed, "fmt": fmt}
    images = [
        plots.transmittance_png(ds, v.sel, x=v.x, hue=v.y, **kw),
        plots.bandgap_png(bandgap_map(ds, v.x, v.y, sel=v.sel), **kw),
        plots.effective_mass_png(ds, {"gap": 0.1, "theta": 0.1}, **kw),
    ]
    for image in images:
        if fmt == "png":
            assert image[:8] == b"\x89PNG\r\n\x1a\n"
        else:
            text = image.decode("utf-8")
            assert text.lstrip().startswith("<?xml") and "<svg" in text
            # The title is text in the SVG: it names the axis fixed by default.
            assert "by default at the first value: θ = 0.1" in text
            assert "choose with" not in text  # API hints are in the header and JSON only
    again = plots.transmittance_png(ds, v.sel, x=v.x, hue=v.y, **kw)
    assert again == images[0]  # deterministic bytes (no date, fixed ids)
    with pytest.raises(AnalysisError, match="png, svg"):
        plots.transmittance_png(ds, v.sel, x=v.x, hue=v.y, fmt="pdf")  # type: ignore[arg-type]
