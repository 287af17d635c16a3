"""service.analysis (selection, bands): selection by value, JSON slices, band edges, bandgap maps.

Band edges are checked against hand-computed cases (the arithmetic is in the comments): an edge
between grid points (x0, Γ0) and (x1, Γ1) that straddle the threshold T lies at
x0 + (T - Γ0) / (Γ1 - Γ0) · (x1 - x0).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

from service.analysis.bands import EDGE_KINDS, Band, band_edges, bandgap_json, bandgap_map
from service.analysis.selection import AnalysisError, select, slice_axes, slice_json
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study

NAN = math.nan


def _dataset(gamma: Any, x: Any, y: Any | None = None, **scalars: float) -> xr.Dataset:
    """A results-like dataset: Γ over (gap, gamma_r) or (gamma_r,), theta as a second dim."""
    g = np.asarray(gamma, dtype=np.float64)
    coords: dict[str, Any] = {
        "gamma_r": ("gamma_r", np.asarray(x, dtype=np.float64), {"units": "1"}),
        **{k: ((), v, {"units": "1"}) for k, v in scalars.items()},
    }
    dims: tuple[str, ...] = ("gamma_r",)
    if y is not None:
        coords["gap"] = ("gap", np.asarray(y, dtype=np.float64), {"units": "1"})
        dims = ("gap", "gamma_r")
    attrs = {"units": "dB", "long_name": "transmittance"}
    return xr.Dataset({"transmittance_db": (dims, g, attrs)}, coords=coords)


def _grid_ds() -> xr.Dataset:
    """Γ over gap × theta × gamma_r (3 × 3 × 5), with one failed point."""
    rng = np.random.default_rng(1)
    g = rng.normal(size=(3, 3, 5))
    g[1, 2, 3] = NAN
    return xr.Dataset(
        {
            "transmittance_db": (("gap", "theta", "gamma_r"), g, {"units": "dB"}),
            "theta_eff": (("gap", "theta", "gamma_r"), -g, {"units": "1"}),
            "failed": (("gap", "theta", "gamma_r"), np.isnan(g)),
        },
        coords={
            "gap": ("gap", [0.1, 0.3, 0.6], {"units": "1"}),
            "theta": ("theta", [0.1, 0.3, 1.0], {"units": "1"}),
            "gamma_r": ("gamma_r", [0.5, 1.0, 1.5, 2.0, 2.5], {"units": "1"}),
            "sigma": ((), 0.05, {"units": "1"}),
        },
    )


# --------------------------------------------------------------------------- band edges


def test_hand_computed_band() -> None:
    # Γ = [1, -1, -3, 1, 2] on x = [0, 1, 2, 3, 4], threshold 0: points 1 and 2 are below.
    # start: between (0, 1) and (1, -1): 0 + (0 - 1) / (-1 - 1) · 1 = 0.5
    # stop:  between (2, -3) and (3, 1): 2 + (0 - -3) / (1 - -3) · 1 = 2 + 3/4 = 2.75
    assert band_edges([0, 1, 2, 3, 4], [1, -1, -3, 1, 2]) == [
        Band(0.5, 2.75, "crossing", "crossing")
    ]


def test_threshold_other_than_zero() -> None:
    # Same Γ, threshold -2: only point 2 (Γ = -3) is below.
    # start: between (1, -1) and (2, -3): 1 + (-2 - -1) / (-3 - -1) = 1 + 0.5 = 1.5
    # stop:  between (2, -3) and (3, 1): 2 + (-2 - -3) / (1 - -3) = 2 + 1/4 = 2.25
    assert band_edges([0, 1, 2, 3, 4], [1, -1, -3, 1, 2], threshold_db=-2.0) == [
        Band(1.5, 2.25, "crossing", "crossing")
    ]
    # Threshold 1.5: points 0, 1, 2, 3 (Γ = 1 < 1.5) are below; point 4 (Γ = 2) is not.
    # start: the grid end x = 0; stop: 3 + (1.5 - 1) / (2 - 1) = 3.5
    assert band_edges([0, 1, 2, 3, 4], [1, -1, -3, 1, 2], threshold_db=1.5) == [
        Band(0.0, 3.5, "grid_end", "crossing")
    ]


def test_multiple_bands_and_open_ends() -> None:
    # Γ = [-2, 2, -2, 2, -4] on x = [0, 2, 4, 6, 8]:
    # band 1 from the grid end 0 to 0 + (0 - -2) / (2 - -2) · 2 = 1
    # band 2 from 2 + (0 - 2) / (-2 - 2) · 2 = 3 to 4 + (0 - -2) / (2 - -2) · 2 = 5
    # band 3 from 6 + (0 - 2) / (-4 - 2) · 2 = 6 + 2/3 to the grid end 8
    bands = band_edges([0, 2, 4, 6, 8], [-2, 2, -2, 2, -4])
    assert [(b.start_edge, b.stop_edge) for b in bands] == [
        ("grid_end", "crossing"),
        ("crossing", "crossing"),
        ("crossing", "grid_end"),
    ]
    np.testing.assert_allclose(
        [(b.start, b.stop) for b in bands], [(0, 1), (3, 5), (6 + 2 / 3, 8)], rtol=1e-15
    )
    # All below: one band over the whole grid, open at both ends; none below: no band.
    assert band_edges([1, 2, 3], [-1, -1, -1]) == [Band(1.0, 3.0, "grid_end", "grid_end")]
    assert band_edges([1, 2, 3], [0, 1, 0]) == []  # Γ = threshold is not attenuating


def test_missing_values_break_bands() -> None:
    # Γ = [1, -1, NaN, -3, 1] on x = [0, 1, 2, 3, 4]: the NaN is unknown, so the band is not
    # carried across it. Band 1: 0 + (0 - 1) / (-1 - 1) = 0.5 to the last known point x = 1;
    # band 2: from the first known point after the gap, x = 3, to 3 + 3/4 = 3.75.
    assert band_edges([0, 1, 2, 3, 4], [1, -1, NAN, -3, 1]) == [
        Band(0.5, 1.0, "crossing", "missing"),
        Band(3.0, 3.75, "missing", "crossing"),
    ]
    # A missing point next to an above-threshold one changes nothing; all missing: no band.
    assert band_edges([0, 1, 2, 3], [NAN, 1, -1, 1]) == [Band(1.5, 2.5, "crossing", "crossing")]
    assert band_edges([0, 1], [NAN, NAN]) == []


def test_band_edges_rejects_bad_grids() -> None:
    with pytest.raises(AnalysisError, match="strictly increasing"):
        band_edges([0, 2, 1], [1, 1, 1])
    with pytest.raises(AnalysisError, match="one length"):
        band_edges([0, 1], [1, 1, 1])


_gamma = st.one_of(st.floats(-50, 50, allow_nan=False), st.just(NAN))


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(st.floats(0.01, 10), min_size=1, max_size=25),
    data=st.data(),
    threshold=st.floats(-5, 5),
)
def test_band_edges_property(steps: list[float], data: Any, threshold: float) -> None:
    x = np.cumsum([0.0, *steps])
    g = np.array(data.draw(st.lists(_gamma, min_size=x.size, max_size=x.size)))
    bands = band_edges(x, g, threshold)
    below = ~np.isnan(g) & (g < threshold)
    # Ordered, disjoint, within the grid, valid edge kinds.
    for a, b in zip(bands, bands[1:], strict=False):
        assert a.stop <= b.start
    for band in bands:
        assert x[0] <= band.start <= band.stop <= x[-1]
        assert band.start_edge in EDGE_KINDS and band.stop_edge in EDGE_KINDS
        # Every grid point strictly inside a band is below the threshold.
        inside = (x > band.start) & (x < band.stop)
        assert below[inside].all()
    # Every below-threshold point lies in exactly one band.
    for i in np.flatnonzero(below):
        assert sum(b.start <= x[i] <= b.stop for b in bands) == 1
    # One band per run of consecutive below-threshold points.
    runs = int(np.sum(np.diff(np.r_[0, below.astype(int)]) == 1))
    assert len(bands) == runs


# --------------------------------------------------------------------------- selection


def test_select_exact_nearest_and_strings() -> None:
    ds = _grid_ds()
    a = select(ds, "transmittance_db", {"theta": 0.3, "gap": "0.6"})
    assert a.dims == ("gamma_r",)
    np.testing.assert_array_equal(a.values, ds["transmittance_db"].values[2, 1])
    # Within the relative tolerance of 1e-9 counts as exact.
    b = select(ds, "transmittance_db", {"theta": 0.3 * (1 + 1e-12)})
    assert float(b["theta"]) == 0.3
    c = select(ds, "transmittance_db", {"theta": 0.35, "gamma_r": 2.2}, nearest=True)
    assert float(c["theta"]) == 0.3 and float(c["gamma_r"]) == 2.0
    # A scalar coordinate may be given when it matches; a dimension the variable lacks is
    # checked but ignored.
    assert select(ds, "transmittance_db", {"sigma": 0.05}).dims == ds["transmittance_db"].dims


@pytest.mark.parametrize(
    ("variable", "sel", "nearest", "pieces"),
    [
        (
            "transmittance_db",
            {"theta": 0.35},
            False,
            ["theta=0.35 is not a coordinate value", "values are 0.1, 0.3, 1", "nearest=true"],
        ),
        ("transmittance_db", {"theta": "abc"}, False, ["theta='abc' is not a number"]),
        ("transmittance_db", {"theta": "nan"}, True, ["theta='nan' is not a finite number"]),
        ("transmittance_db", {"theta": True}, False, ["theta=True is not a number"]),
        (
            "transmittance_db",
            {"omega": 1},
            False,
            ["omega is not a coordinate", "gap, theta, gamma_r", "sigma"],
        ),
        ("transmittance_db", {"sigma": 0.06}, False, ["sigma=0.06", "values are 0.05"]),
        ("gain", {}, False, ["variable='gain'", "failed, theta_eff, transmittance_db"]),
    ],
)
def test_select_errors(
    variable: str, sel: dict[str, Any], nearest: bool, pieces: list[str]
) -> None:
    with pytest.raises(AnalysisError) as info:
        select(_grid_ds(), variable, sel, nearest)
    for piece in pieces:
        assert piece in str(info.value)
    assert isinstance(info.value, ValueError)


def test_long_axes_are_abbreviated_in_errors() -> None:
    ds = _dataset(np.zeros(50), np.linspace(0.2, 5.1, 50))
    with pytest.raises(AnalysisError, match=r"0\.2, 0\.3, 0\.4, \.\.\., 5, 5\.1 \(50 values"):
        select(ds, "transmittance_db", {"gamma_r": 0.25})


def test_derived_coordinate_is_not_selectable() -> None:
    # Physical studies carry gamma_r as a coordinate along frequency_hz.
    f = np.array([10.0, 20.0, 30.0])
    ds = xr.Dataset(
        {"transmittance_db": (("frequency_hz",), [1.0, -1.0, 2.0], {"units": "dB"})},
        coords={
            "frequency_hz": ("frequency_hz", f, {"units": "Hz"}),
            "gamma_r": ("frequency_hz", f / 20.0, {"units": "1"}),
        },
    )
    with pytest.raises(AnalysisError, match="gamma_r is not a dimension.*frequency_hz"):
        select(ds, "transmittance_db", {"gamma_r": 0.5})
    with pytest.raises(AnalysisError, match="axis 'gamma_r' is not a dimension.*derived"):
        bandgap_map(ds, "gamma_r")
    m = bandgap_map(ds, "frequency_hz")  # frequency as x works, gamma_r rides along
    # 10 + (0 - 1) / (-1 - 1) · 10 = 15;  20 + (0 - -1) / (2 - -1) · 10 = 23.33...
    np.testing.assert_allclose(m["band_start"].values, [15.0])
    np.testing.assert_allclose(m["band_stop"].values, [20 + 10 / 3])
    assert m["band_start"].attrs["units"] == "Hz"
    assert "gamma_r" in m["transmittance_db"].coords


def test_slice_axes_requires_every_other_dim() -> None:
    ds = _grid_ds()
    with pytest.raises(AnalysisError) as info:
        slice_axes(ds, "transmittance_db", ["gamma_r"])
    msg = str(info.value)
    assert "missing: gap (values 0.1, 0.3, 0.6); theta (values 0.1, 0.3, 1)" in msg
    with pytest.raises(AnalysisError, match="gamma_r is a plot axis"):
        slice_axes(ds, "transmittance_db", ["gamma_r"], {"gamma_r": 1.0, "gap": 0.1})
    with pytest.raises(AnalysisError, match="axis 'sigma' is not a dimension.*single value"):
        slice_axes(ds, "transmittance_db", ["sigma"])
    out = slice_axes(ds, "transmittance_db", ["gamma_r", "gap"], {"theta": 1.0})
    assert out.dims == ("gamma_r", "gap")


# --------------------------------------------------------------------------- JSON


def test_slice_json_has_no_nan() -> None:
    ds = _grid_ds()
    da = select(ds, "transmittance_db", {"gap": 0.3})
    out = slice_json(da)
    text = json.dumps(out, allow_nan=False)
    assert json.loads(text) == out
    assert out["variable"] == "transmittance_db" and out["units"] == "dB"
    assert out["dims"] == ["theta", "gamma_r"]
    assert out["coords"]["theta"] == [0.1, 0.3, 1.0]
    assert out["scalars"] == {"gap": 0.3, "sigma": 0.05}
    assert out["values"][2][3] is None  # the failed point
    assert out["values"][0][0] == pytest.approx(ds["transmittance_db"].values[1, 0, 0])
    # inf is not valid JSON either; booleans stay booleans.
    inf = slice_json(xr.DataArray([1.0, np.inf, -np.inf], dims="x", name="v"))
    assert inf["values"] == [1.0, None, None]
    flags = slice_json(select(ds, "failed", {"gap": 0.3, "theta": 1.0}))
    assert flags["values"] == [False, False, False, True, False]


# --------------------------------------------------------------------------- bandgap maps


def test_bandgap_map_edges_per_row() -> None:
    x = [0, 1, 2, 3, 4]
    gamma = [
        [1, -1, -3, 1, 2],  # one band 0.5 .. 2.75 (see test_hand_computed_band)
        [-2, 2, -2, 2, -4],  # x spacing 1: 0 .. 0.5, 1.5 .. 2.5, 3 + 1/3 .. 4 (open)
        [1, -1, NAN, -3, 1],  # 0.5 .. 1 (missing), 3 (missing) .. 3.75
        [1, 2, 3, 4, 5],  # none
    ]
    ds = _dataset(gamma, x, y=[0.1, 0.3, 0.5, 0.7], theta=0.3)
    m = bandgap_map(ds, "gamma_r", "gap")
    assert m.attrs["threshold_db"] == 0.0 and m.attrs["x"] == "gamma_r"
    assert m["band_count"].values.tolist() == [1, 3, 2, 0]
    assert m["band_start"].dims == ("gap", "band") and m.sizes["band"] == 3
    np.testing.assert_allclose(
        m["band_start"].values,
        [[0.5, NAN, NAN], [0, 1.5, 3 + 1 / 3], [0.5, 3, NAN], [NAN, NAN, NAN]],
    )
    np.testing.assert_allclose(
        m["band_stop"].values,
        [[2.75, NAN, NAN], [0.5, 2.5, 4], [1, 3.75, NAN], [NAN, NAN, NAN]],
    )
    kinds = {k: i for i, k in enumerate(EDGE_KINDS)}
    assert m["band_start_edge"].values[1].tolist() == [kinds["grid_end"], 0, 0]
    assert m["band_stop_edge"].values[1].tolist() == [0, 0, kinds["grid_end"]]
    assert m["band_stop_edge"].values[2].tolist() == [kinds["missing"], 0, -1]
    att = m["attenuating"].values
    assert att.dtype == bool and not att[2, 2]  # missing is not attenuating
    np.testing.assert_array_equal(att[0], [False, True, True, False, False])

    out = bandgap_json(m)
    json.dumps(out, allow_nan=False)
    assert out["x"] == "gamma_r" and out["y"] == "gap"
    assert out["coords"] == {"gamma_r": [0, 1, 2, 3, 4], "gap": [0.1, 0.3, 0.5, 0.7]}
    assert out["transmittance_db"][2][2] is None
    assert out["scalars"] == {"theta": 0.3}
    assert out["edges"][0] == {"y": 0.1, "bands": [[0.5, 2.75]], "kinds": [["crossing"] * 2]}
    assert out["edges"][2]["kinds"] == [["crossing", "missing"], ["missing", "crossing"]]
    assert out["edges"][3] == {"y": 0.7, "bands": [], "kinds": []}


def test_bandgap_map_threshold_sorting_and_1d() -> None:
    # Coordinates in file order need not be sorted; the map is sorted by x (and y).
    x = [4, 0, 3, 1, 2]
    gamma = [2, 1, 1, -1, -3]  # sorted by x: [1, -1, -3, 1, 2]
    ds = _dataset(gamma, x)
    m = bandgap_map(ds, "gamma_r", threshold_db=-2)
    # See test_threshold_other_than_zero: 1.5 .. 2.25.
    assert m["gamma_r"].values.tolist() == [0, 1, 2, 3, 4]
    assert m["band_start"].dims == ("band",) and int(m["band_count"]) == 1
    np.testing.assert_allclose([m["band_start"].item(), m["band_stop"].item()], [1.5, 2.25])
    out = bandgap_json(m)
    json.dumps(out, allow_nan=False)
    assert out["y"] is None and out["threshold_db"] == -2.0
    assert out["edges"] == [{"y": None, "bands": [[1.5, 2.25]], "kinds": [["crossing"] * 2]}]
    # An empty map (no band anywhere) still has the variables, with a zero-length band dim.
    empty = bandgap_map(ds, "gamma_r", threshold_db=-10)
    assert empty.sizes["band"] == 0 and int(empty["band_count"]) == 0
    assert bandgap_json(empty)["edges"] == [{"y": None, "bands": [], "kinds": []}]


def test_bandgap_map_selection_and_errors() -> None:
    ds = _grid_ds()
    m = bandgap_map(ds, "gamma_r", "gap", sel={"theta": 0.3})
    assert m["transmittance_db"].dims == ("gap", "gamma_r")
    assert float(m["transmittance_db"]["theta"]) == 0.3
    with pytest.raises(AnalysisError, match=r"missing: theta \(values 0\.1, 0\.3, 1\)"):
        bandgap_map(ds, "gamma_r", "gap")
    with pytest.raises(AnalysisError, match="x and y must differ"):
        bandgap_map(ds, "gamma_r", "gamma_r", sel={"theta": 0.3})
    with pytest.raises(AnalysisError, match="threshold_db='x' is not a number"):
        bandgap_map(ds, "gamma_r", "gap", threshold_db="x", sel={"theta": 0.3})  # type: ignore[arg-type]
    with pytest.raises(AnalysisError, match="theta=0.2 is not a coordinate value"):
        bandgap_map(ds, "gamma_r", "gap", sel={"theta": 0.2})
    near = bandgap_map(ds, "gamma_r", "gap", sel={"theta": 0.2}, nearest=True)
    assert float(near["transmittance_db"]["theta"]) in (0.1, 0.3)
    no_gamma = ds.drop_vars("transmittance_db")
    with pytest.raises(AnalysisError, match="variable='transmittance_db' is not in the results"):
        bandgap_map(no_gamma, "gamma_r", "gap", sel={"theta": 0.3})


# --------------------------------------------------------------------------- a real study


@pytest.fixture(scope="module")
def real(tmp_path_factory: pytest.TempPathFactory) -> xr.Dataset:
    # Euler at 256 steps a period is unstable for small γ_r (Δτ·ω̃_max > 2): γ_r = 0.2 fails at
    # gap 0.1, so the dataset has real missing points, read back from NetCDF. (At gap 0.6 the
    # point is proven impact-free from rest and reported in closed form: no step is taken.)
    study = parse_study(
        {
            "name": "analysis",
            "solver": {"method": "euler", "steps_per_period": 256, "max_periods": 60, "window": 5},
            "grid": {
                "gamma_r": [0.2, 1.0, 1.5, 2.0, 3.0],
                "gap": [0.1, 0.6],
                "theta": 0.3,
                "sigma": 0.05,
                "gamma_s": 1.0,
            },
        }
    )
    summary = run_study(study, tmp_path_factory.mktemp("real"), serial=True)
    return open_results(Path(summary.path))


def test_real_study(real: xr.Dataset) -> None:
    assert bool(real["failed"].sel(gamma_r=0.2, gap=0.1))
    m = bandgap_map(real, "gamma_r", "gap")
    out = bandgap_json(m)
    json.dumps(out, allow_nan=False)
    assert out["transmittance_db"][0][0] is None
    g = real["transmittance_db"].sel(gap=0.1).values
    assert g[1] > 0 > g[2]  # the resonance near γ_r = 1, attenuation above it
    # The band starts where Γ crosses 0 between γ_r = 1 and 1.5 (linear interpolation).
    expected = 1.0 + (0 - g[1]) / (g[2] - g[1]) * 0.5
    assert out["edges"][0]["bands"][0][0] == pytest.approx(expected, rel=1e-12)
    # Without γ_r = 1, the band's lower neighbour is the failed point: a "missing" edge.
    m2 = bandgap_map(real.isel(gamma_r=[0, 2, 3, 4]), "gamma_r", "gap")
    assert int(m2["band_start_edge"].values[0, 0]) == EDGE_KINDS.index("missing")
    assert float(m2["band_start"].values[0, 0]) == 1.5
    s = slice_json(select(real, "impacts_per_period", {"gap": 0.1, "stop": 2}))
    json.dumps(s, allow_nan=False)
    assert s["dims"] == ["gamma_r"] and s["values"][0] is None
    # The outcome flag as JSON: codes, with what they mean.
    o = slice_json(select(real, "outcome", {"gap": 0.1}))
    json.dumps(o, allow_nan=False)
    assert o["flag_meanings"] == ["linear", "periodic", "irregular", "unsettled", "failed"]
    assert o["flag_values"] == [0, 1, 2, 3, 4]
    assert o["flag_meanings"][o["values"][0]] == "failed"
    assert "flag_meanings" not in s


def test_real_study_linear_reference_and_impact_effect_maps(real: xr.Dataset) -> None:
    from service.studies.variables import outcome_names

    for name, words in (
        ("transmittance_linear_db", "stops removed"),
        ("impact_effect_db", "Gamma - Gamma_lin"),
    ):
        assert real[name].attrs["units"] == "dB" and words in real[name].attrs["long_name"]
    outcomes = outcome_names(real["outcome"])
    effect = real["impact_effect_db"].values
    assert (effect[outcomes == "linear"] == 0.0).all()
    # the failed point keeps the cell's reference (a closed form), but has no effect
    failed = real.sel(gamma_r=0.2, gap=0.1)
    assert np.isfinite(float(failed["transmittance_linear_db"])) and np.isnan(
        float(failed["impact_effect_db"])
    )
    # Γ − Γ_lin where both exist
    both = ~np.isnan(effect)
    diff = real["transmittance_db"].values - real["transmittance_linear_db"].values
    np.testing.assert_allclose(effect[both], diff[both], atol=1e-12)

    m = bandgap_map(real, "gamma_r", "gap", variable="impact_effect_db")
    out = bandgap_json(m)
    json.dumps(out, allow_nan=False)
    assert out["variable"]["name"] == "impact_effect_db" and out["threshold_db"] == -1.0
    assert "impacts attenuate over 1 dB more" in out["threshold"]["meaning"]
    assert out["impact_effect_db"][0][0] is None and "transmittance_db" not in out
    np.testing.assert_array_equal(m["attenuating"].values, (m["impact_effect_db"] < -1.0).values)
    lin = bandgap_map(real, "gamma_r", "gap", variable="transmittance_linear_db", threshold_db=0)
    # the cell without stops does not depend on the gap (paper coupling): the same bands
    edges = bandgap_json(lin)["edges"]
    assert edges[0]["bands"] == edges[1]["bands"] and edges[0]["bands"]
    with pytest.raises(AnalysisError, match="cannot be mapped; variables are transmittance_db"):
        bandgap_map(real, "gamma_r", "gap", variable="theta_eff")
    old = real.drop_vars(["transmittance_linear_db", "impact_effect_db"])  # an older file
    with pytest.raises(AnalysisError, match="made before the linear reference"):
        bandgap_map(old, "gamma_r", "gap", variable="impact_effect_db")
    assert bandgap_json(bandgap_map(old, "gamma_r", "gap"))["variable"]["name"] == (
        "transmittance_db"
    )


def test_a_complete_dataset_has_nothing_pending(real: xr.Dataset) -> None:
    # A page that saw the study running asks for `pending` just as it finishes: the complete
    # dataset answers that no point is pending (not an unknown variable).
    assert "pending" not in real.data_vars
    got = select(real, "pending", {})
    assert got.dtype == bool and not got.values.any()
    assert got.shape == real["outcome"].shape and got.name == "pending"
    with pytest.raises(AnalysisError, match="variable='pendings' is not in the results"):
        select(real, "pendings", {})
