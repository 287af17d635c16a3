"""service.analysis.hysteresis and its figure: branches, jumps at known x, differing intervals.

The datasets follow the contract of sweep and multi-start studies (dims ``initial``?,
``direction``?, grid dims; ``responses`` over the grid dims only) and are built here directly.
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
import xarray as xr
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from service.analysis.hysteresis import (
    NO_HYSTERESIS,
    hysteresis_csv,
    hysteresis_json,
    hysteresis_map,
)
from service.analysis.plots import hysteresis_figure, hysteresis_png
from service.analysis.selection import AnalysisError, default_view
from service.studies.variables import outcome_attrs

GR = np.round(np.arange(0.5, 2.01, 0.1), 10)  # 16 frequencies
GAP = np.array([0.1, 0.3])
LOW, HIGH = 0.0, -5.0  # the two coexisting responses (dB)


def up_down_curves() -> tuple[np.ndarray, np.ndarray]:
    """Up: LOW up to γ_r = 1.2, then HIGH (jump between 1.2 and 1.3). Down: HIGH down to 0.9,
    then LOW (jump between 0.9 and 0.8). They differ at 0.9, 1.0, 1.1, 1.2."""
    up = np.where(GR <= 1.2 + 1e-9, LOW, HIGH)
    down = np.where(GR >= 0.9 - 1e-9, HIGH, LOW)
    return up, down


def sweep_ds(
    directions: tuple[str, ...] = ("up", "down"), sweep_axis: str | None = "gamma_r"
) -> xr.Dataset:
    """A gap × γ_r sweep study's results: the curves above at gap 0.1, shifted by −1 dB at
    gap 0.3 (a different response there: no jump of the curves at gap 0.1 is affected)."""
    up, down = up_down_curves()
    by = {"up": up, "down": down}
    base = np.stack([by[d] for d in directions])  # direction × γ_r
    gamma = np.stack([base, base - 1.0], axis=1)  # direction × gap × γ_r
    dims = ("direction", "gap", "gamma_r")
    codes = np.zeros(gamma.shape, dtype=np.int8)
    codes[..., GR > 1.25] = 1  # periodic: the impacting response
    responses = np.where((GR > 0.85) & (GR < 1.25), 2, 1)[None, :].repeat(2, axis=0)
    ds = xr.Dataset(
        {
            "transmittance_db": (dims, gamma, {"units": "dB", "long_name": "transmittance"}),
            "amplitude": (dims, 10 ** (gamma / 20), {"units": "1"}),
            "outcome": (dims, codes, outcome_attrs()),
            "responses": (("gap", "gamma_r"), responses, {"units": "1"}),
            "reason": (dims, np.full(gamma.shape, "", dtype=object)),
        },
        coords={
            "direction": ("direction", np.array(directions)),
            "gap": ("gap", GAP, {"units": "1", "long_name": "clearance"}),
            "gamma_r": ("gamma_r", GR, {"units": "1", "long_name": "frequency ratio"}),
            "theta": ((), 0.3, {"units": "1"}),
        },
    )
    if sweep_axis:
        ds.attrs["sweep_axis"] = sweep_axis
    return ds


def test_up_and_down_jumps_and_the_differing_interval_are_found_exactly() -> None:
    h = hysteresis_map(sweep_ds())
    assert h.attrs["x"] == "gamma_r" and h.attrs["fixed"] == "gap" and float(h["gap"]) == 0.1
    assert list(h["branch"].values) == ["up", "down"]
    up, down = up_down_curves()
    np.testing.assert_array_equal(h["transmittance_db"].values, [up, down])
    assert h.sizes["jump"] == 2
    assert list(h["jump_label"].values) == ["J1", "J2"]
    assert list(h["jump_branch"].values) == [0, 1]
    np.testing.assert_allclose(h["jump_from"].values, [1.2, 0.9])
    np.testing.assert_allclose(h["jump_to"].values, [1.3, 0.8])  # down: computed downwards
    np.testing.assert_allclose(h["jump_size_db"].values, [HIGH - LOW, LOW - HIGH])
    assert not h["jump_across_missing"].values.any()
    assert h.sizes["region"] == 1
    assert float(h["region_start"][0]) == pytest.approx(0.9)
    assert float(h["region_stop"][0]) == pytest.approx(1.2)
    assert int(h["region_points"][0]) == 4
    np.testing.assert_array_equal(h["differs"].values, (GR > 0.85) & (GR < 1.25))
    np.testing.assert_array_equal(h["responses"].values, ((GR > 0.85) & (GR < 1.25)) + 1)

    doc = hysteresis_json(h)
    json.dumps(doc, allow_nan=False)
    assert doc["x"] == "gamma_r" and doc["sweep_axis"] == "gamma_r" and doc["along_sweep"]
    assert doc["slice"]["gap"]["default"] and not doc["slice"]["theta"]["default"]
    assert [b["label"] for b in doc["branches"]] == ["up", "down"]
    assert [b["order"] for b in doc["branches"]] == ["increasing", "decreasing"]
    assert doc["branches"][1]["jumps"] == ["J2"]
    j2 = doc["jumps"][1]
    assert (j2["branch"], j2["direction"], j2["initial"]) == ("down", "down", None)
    assert j2["from"] == pytest.approx(0.9) and j2["to"] == pytest.approx(0.8)
    assert j2["interval"] == pytest.approx([0.8, 0.9]) and j2["size_db"] == pytest.approx(5.0)
    assert doc["differing"] == [
        {"start": pytest.approx(0.9), "stop": pytest.approx(1.2), "points": 4,
         "max_spread_db": pytest.approx(5.0)}
    ]  # fmt: skip
    assert doc["counts"] == {"branches": 2, "jumps": 2, "differing_points": 4,
                             "coexisting_points": 4}  # fmt: skip
    assert doc["branches"][0]["outcomes"][-1] == "periodic"


def test_thresholds_and_selection() -> None:
    ds = sweep_ds()
    # a jump of 5 dB is not over 5 dB; differences of 5 dB are not over 5 dB either
    h = hysteresis_map(ds, jump_db=5.0, tol_db=5.0)
    assert h.sizes["jump"] == 0 and h.sizes["region"] == 0 and not h["differs"].any()
    # the other gap: the same shape 1 dB lower
    h3 = hysteresis_map(ds, sel={"gap": 0.3})
    assert h3.attrs["fixed"] == "" and float(h3["gap"]) == 0.3
    np.testing.assert_allclose(h3["jump_from_value"].values, [LOW - 1.0, HIGH - 1.0])
    # a small step inside one branch: under jump_db it is not a jump, over tol_db it differs
    small = ds.copy(deep=True)
    small["transmittance_db"].loc[{"direction": "down", "gap": 0.1, "gamma_r": 1.8}] -= 0.5
    hs = hysteresis_map(small)
    assert hs.sizes["jump"] == 2 and hs.sizes["region"] == 2
    assert float(hs["region_start"][1]) == float(hs["region_stop"][1]) == pytest.approx(1.8)
    # x along another axis, with γ_r selected
    hg = hysteresis_map(ds, x="gap", sel={"gamma_r": 1.0})
    assert hg.attrs["x"] == "gap" and hg.sizes["jump"] == 0
    np.testing.assert_allclose(hg["spread_db"].values, [5.0, 5.0])
    # not along the sweep: a down branch is not reversed (each gap is a line of its own)
    hg = hysteresis_map(ds, x="gap", sel={"gamma_r": 1.0}, jump_db=0.5)
    assert list(hg["branch_order"].values) == ["increasing", "increasing"]
    np.testing.assert_allclose(hg["jump_from"].values, [0.1, 0.1])
    doc = hysteresis_json(hg)
    assert doc["along_sweep"] is False and "not the swept axis" in doc["jump_db"]["meaning"]
    # only one direction selected: one branch, still labelled
    hu = hysteresis_map(ds, sel={"direction": "up"})
    assert list(hu["branch"].values) == ["up"] and hu.sizes["jump"] == 1
    assert not hu["differs"].any()


def test_the_sweep_axis_is_the_default_x() -> None:
    ds = sweep_ds(sweep_axis="gap")
    h = hysteresis_map(ds)
    assert h.attrs["x"] == "gap" and h.attrs["fixed"] == "gamma_r"
    assert float(h["gamma_r"]) == 0.5
    assert h.attrs["along_sweep"] == 1 and list(h["branch_order"].values)[1] == "decreasing"
    # without the attribute: the frequency axis, taken as the swept one
    plain_attr = hysteresis_map(sweep_ds(sweep_axis=None))
    assert plain_attr.attrs["x"] == "gamma_r" and plain_attr.attrs["along_sweep"] == 1
    np.testing.assert_allclose(plain_attr["jump_to"].values, [1.3, 0.8])
    # the default view keeps branch dims out of hue and y: fixed at their first value
    v = default_view(ds, "transmittance_db", "gamma_r", None, {})
    assert v.y == "gap" and v.fixed == {"direction": "up"}


def test_single_direction_study() -> None:
    h = hysteresis_map(sweep_ds(directions=("down",)))
    assert list(h["branch"].values) == ["down"] and list(h["branch_direction"].values) == ["down"]
    assert h.sizes["jump"] == 1 and float(h["jump_from"][0]) == pytest.approx(0.9)
    assert h.sizes["region"] == 0 and np.isnan(h["spread_db"].values).all()


def multistart_ds(with_direction: bool) -> xr.Dataset:
    """Three starts over γ_r: rest stays LOW, linear is HIGH from 1.0 on, random-0 is HIGH
    between 1.0 and 1.4 only; with a direction, down is the same as up."""
    rest = np.full(GR.size, LOW)
    lin = np.where(GR >= 1.0 - 1e-9, HIGH, LOW)
    rnd = np.where((GR >= 1.0 - 1e-9) & (GR <= 1.4 + 1e-9), HIGH, LOW)
    rnd[3] = np.nan  # a failed point at γ_r = 0.8, far from any jump
    gamma = np.stack([rest, lin, rnd])
    dims: tuple[str, ...] = ("initial", "gamma_r")
    if with_direction:
        gamma = np.stack([gamma, gamma], axis=1)
        dims = ("initial", "direction", "gamma_r")
    codes = np.where(np.isnan(gamma), 4, 0).astype(np.int8)
    coords = {
        "initial": ("initial", np.array(["rest", "linear", "random-0"])),
        "gamma_r": ("gamma_r", GR, {"units": "1"}),
    }
    if with_direction:
        coords["direction"] = ("direction", np.array(["up", "down"]))
    return xr.Dataset(
        {
            "transmittance_db": (dims, gamma, {"units": "dB"}),
            "outcome": (dims, codes, outcome_attrs()),
        },
        coords=coords,
    )


def test_initial_states_are_branches_never_mixed() -> None:
    h = hysteresis_map(multistart_ds(False))
    assert list(h["branch"].values) == ["rest", "linear", "random-0"]
    assert list(h["branch_direction"].values) == ["", "", ""]
    assert list(h["jump_label"].values) == ["J1", "J2", "J3"]
    assert list(h["jump_branch"].values) == [1, 2, 2]
    np.testing.assert_allclose(h["jump_to"].values, [1.0, 1.0, 1.5])
    assert h.sizes["region"] == 1
    assert float(h["region_start"][0]) == pytest.approx(1.0)
    assert float(h["region_stop"][0]) == pytest.approx(2.0)
    assert "responses" not in h and hysteresis_json(h)["responses"] is None
    assert hysteresis_json(h)["sweep_axis"] is None and not hysteresis_json(h)["along_sweep"]
    # the failed point is known to the outcomes, missing in its branch only
    assert np.isnan(h["transmittance_db"].values[2, 3])
    assert hysteresis_json(h)["branches"][2]["outcomes"][3] == "failed"

    both = hysteresis_map(multistart_ds(True))
    assert list(both["branch"].values) == [
        "rest/up", "rest/down", "linear/up", "linear/down", "random-0/up", "random-0/down"
    ]  # fmt: skip
    assert list(both["branch_initial"].values)[:2] == ["rest", "rest"]
    down = both["jump_branch"].values == 3  # linear/down: from 1.0 to 0.9
    np.testing.assert_allclose(both["jump_from"].values[down], [1.0])
    np.testing.assert_allclose(both["jump_to"].values[down], [0.9])
    one = hysteresis_map(multistart_ds(True), sel={"initial": "linear"})
    assert list(one["branch"].values) == ["linear/up", "linear/down"]


def test_jumps_across_a_missing_point_say_so() -> None:
    ds = sweep_ds()
    ds["transmittance_db"].loc[{"direction": "up", "gamma_r": 1.3}] = np.nan
    h = hysteresis_map(ds)
    j = hysteresis_json(h)["jumps"][0]
    assert j["from"] == pytest.approx(1.2) and j["to"] == pytest.approx(1.4)
    assert j["across_missing"] is True


def test_plain_studies_and_bad_requests_are_analysis_errors() -> None:
    plain = sweep_ds().isel(direction=0, drop=True)
    with pytest.raises(AnalysisError, match=NO_HYSTERESIS):
        hysteresis_map(plain)
    ds = sweep_ds()
    with pytest.raises(AnalysisError, match="does not vary with direction"):
        hysteresis_map(ds, variable="responses")
    with pytest.raises(AnalysisError, match="not numeric"):
        hysteresis_map(ds, variable="reason")
    with pytest.raises(AnalysisError, match="variable='nope' is not in the results"):
        hysteresis_map(ds, variable="nope")
    with pytest.raises(AnalysisError, match="jump_db=0 must be positive"):
        hysteresis_map(ds, jump_db=0)
    with pytest.raises(AnalysisError, match="tol_db=-1 must not be negative"):
        hysteresis_map(ds, tol_db=-1)
    with pytest.raises(AnalysisError, match="labels branches"):
        hysteresis_map(ds, x="direction")
    with pytest.raises(AnalysisError, match="gap=0.2 is not a coordinate value"):
        hysteresis_map(ds, sel={"gap": 0.2})
    # another numeric variable has branches too (thresholds in its units)
    assert hysteresis_map(ds, variable="amplitude", jump_db=0.1).sizes["jump"] == 2


def test_csv_has_one_row_per_branch_and_x_with_jumps_where_they_land() -> None:
    rows = list(csv.DictReader(io.StringIO(hysteresis_csv(hysteresis_map(sweep_ds())))))
    assert len(rows) == 2 * GR.size
    assert set(rows[0]) >= {"branch", "direction", "gamma_r", "transmittance_db", "jump",
                            "differs", "responses", "gap", "theta"}  # fmt: skip
    landed = [(r["branch"], r["gamma_r"], r["jump"]) for r in rows if r["jump"]]
    assert landed == [("up", repr(float(GR[8])), "J1"), ("down", repr(float(GR[3])), "J2")]
    assert rows[5]["differs"] == "true" and rows[0]["initial"] == "" and rows[0]["gap"] == "0.1"


def test_json_and_csv_carry_the_may_be_transient_flag_per_branch_and_point() -> None:
    ds = sweep_ds()
    assert hysteresis_json(hysteresis_map(ds))["branches"][0]["may_be_transient"] is None
    flag = np.zeros(ds["transmittance_db"].shape, dtype=bool)
    flag[1, 0, 4] = True  # down, gap 0.1 (the slice shown), γ_r 0.9
    ds["may_be_transient"] = (ds["transmittance_db"].dims, flag, {"long_name": "may be transient"})
    h = hysteresis_map(ds)
    doc = hysteresis_json(h)
    down = next(b for b in doc["branches"] if b["label"] == "down")
    up = next(b for b in doc["branches"] if b["label"] == "up")
    assert [i for i, f in enumerate(down["may_be_transient"]) if f] == [4]
    assert not any(up["may_be_transient"])
    rows = list(csv.DictReader(io.StringIO(hysteresis_csv(h))))
    marked = [(r["branch"], r["gamma_r"]) for r in rows if r["may_be_transient"] == "true"]
    assert marked == [("down", repr(float(GR[4])))]
    assert sum(r["may_be_transient"] == "false" for r in rows) == 2 * GR.size - 1


# --------------------------------------------------------------------------- the figure


def _lines(fig: Figure, gid: str) -> list[Line2D]:
    return [ln for ln in fig.axes[0].get_lines() if ln.get_gid() == gid]


def test_figure_shows_branches_jumps_region_and_counts() -> None:
    ds = sweep_ds()
    ds["outcome"].loc[{"direction": "down", "gap": 0.1, "gamma_r": 1.9}] = 2  # irregular
    ds["transmittance_db"].loc[{"direction": "up", "gap": 0.1, "gamma_r": 0.5}] = np.nan
    ds["outcome"].loc[{"direction": "up", "gap": 0.1, "gamma_r": 0.5}] = 4  # failed
    h = hysteresis_map(ds)
    fig = hysteresis_figure(h)
    ax = fig.axes[0]
    up, down = _lines(fig, "branch-up"), _lines(fig, "branch-down")
    assert len(up) == 2 and len(down) == 2  # each broken at its jump
    assert to_rgba(up[0].get_color()) != to_rgba(down[0].get_color())
    assert up[0].get_marker() == ">" and down[0].get_marker() == "<"
    np.testing.assert_allclose(up[0].get_xdata(), GR[:8])  # up to 1.2, then from 1.3
    np.testing.assert_allclose(up[1].get_xdata(), GR[8:])
    jumps = _lines(fig, "jump")
    assert len(jumps) == 2 and all(j.get_linestyle() == "--" for j in jumps)
    np.testing.assert_allclose(jumps[0].get_xdata(), [1.3, 1.3])
    np.testing.assert_allclose(jumps[0].get_ydata(), [LOW, HIGH])
    np.testing.assert_allclose(jumps[1].get_xdata(), [0.8, 0.8])
    assert to_rgba(jumps[1].get_color()) == to_rgba(down[0].get_color())
    spans = [p for p in ax.patches if p.get_gid() == "differs"]
    assert len(spans) == 1
    x0, x1 = spans[0].get_x(), spans[0].get_x() + spans[0].get_width()
    assert (x0, x1) == pytest.approx((0.85, 1.25))  # the cells of 0.9 … 1.2
    labels = ax.get_legend().get_texts()
    text = [t.get_text() for t in labels]
    assert "up (15 points)" in text and "down (16 points)" in text
    assert "jump > 1 dB (2)" in text
    assert "up and down differ by > 0.05 dB (4 points)" in text
    assert "2 or more responses (4 points)" in text
    assert "irregular (1)" in text and "failed (1)" in text
    assert "J1" in [t.get_text() for t in ax.texts]
    # the axis fixed by default is named once, without an API hint
    assert ax.get_title().count("g̃ = 0.1") == 1 and "choose with" not in ax.get_title()
    assert ax.get_title().endswith("by default at the first value: g̃ = 0.1")


def test_figure_of_initial_states_and_formats() -> None:
    fig = hysteresis_figure(hysteresis_map(multistart_ds(False)))
    colours = {to_rgba(_lines(fig, f"branch-{b}")[0].get_color())
               for b in ("rest", "linear", "random-0")}  # fmt: skip
    assert len(colours) == 3
    text = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "branches differ by > 0.05 dB (11 points)" in text and "failed (1)" in text
    png = hysteresis_png(hysteresis_map(sweep_ds()))
    assert png[:4] == b"\x89PNG"
    svg = hysteresis_png(hysteresis_map(sweep_ds()), fmt="svg")
    assert b"<svg" in svg[:500]
    with pytest.raises(AnalysisError, match="format='gif'"):
        hysteresis_png(hysteresis_map(sweep_ds()), fmt="gif")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- what a jump is

R = np.round(np.arange(0.5, 2.001, 0.05), 10)  # 31 frequencies: coarse for a resonance


def resonance_db(r: np.ndarray, xi: float = 0.05) -> np.ndarray:
    """A 1-DOF resonance in dB: 20 dB at r = 1, flanks up to 4 dB a grid step on ``R``."""
    return -10 * np.log10((1 - r**2) ** 2 + (2 * xi * r) ** 2)


def leaning_db(r: np.ndarray) -> np.ndarray:
    """The upper sheet of a hardening resonance: equal to the resonance up to r = 0.95, then
    its peak follows the drive (about 19 dB at r = 1.3, 13.5 dB at 2)."""
    return resonance_db(r / (1 + 0.8 * np.clip(r - 0.95, 0, None)))


def branches_ds(up: np.ndarray, down: np.ndarray, x: np.ndarray = R) -> xr.Dataset:
    """A γ_r sweep study's results with these two branches."""
    return xr.Dataset(
        {"transmittance_db": (("direction", "gamma_r"), np.stack([up, down]), {"units": "dB"})},
        coords={"direction": ["up", "down"], "gamma_r": ("gamma_r", x, {"units": "1"})},
        attrs={"sweep_axis": "gamma_r"},
    )


@pytest.mark.parametrize("x", [R, np.linspace(0.5, 3.0, 12)], ids=["31 points", "12 points"])
def test_a_smooth_steep_resonance_on_a_coarse_grid_has_no_jump(x: np.ndarray) -> None:
    curve = resonance_db(x)
    assert np.sum(np.abs(np.diff(curve)) > 1.0) >= 10  # steps over jump_db all along
    h = hysteresis_map(branches_ds(curve, curve, x))
    assert h.sizes["jump"] == 0 and h.sizes["region"] == 0
    # nor when it is the only branch (nothing to compare with), or along a gentler grid
    assert hysteresis_map(branches_ds(curve, curve, x), sel={"direction": "up"}).sizes["jump"] == 0
    fig = hysteresis_figure(h)
    assert _lines(fig, "jump") == [] and len(fig.axes[0].texts) == 0


def test_a_fold_is_one_jump_per_branch_where_the_sheets_part() -> None:
    lower, upper = resonance_db(R), leaning_db(R)
    up = np.where(R <= 1.3 + 1e-9, upper, lower)  # rides the upper sheet, falls off at 1.3
    down = np.where(R >= 1.15 - 1e-9, lower, upper)  # climbs onto it below 1.15
    h = hysteresis_map(branches_ds(up, down))
    doc = hysteresis_json(h)
    assert [(j["branch"], j["kind"]) for j in doc["jumps"]] == [
        ("up", "discontinuity"), ("down", "discontinuity")
    ]  # fmt: skip
    assert doc["jumps"][0]["interval"] == pytest.approx([1.3, 1.35])
    assert doc["jumps"][0]["size_db"] < -15  # from the upper sheet to the lower one
    assert doc["jumps"][1]["from"] == pytest.approx(1.15)
    assert doc["jumps"][1]["to"] == pytest.approx(1.1)
    assert [(r["start"], r["stop"]) for r in doc["differing"]] == [pytest.approx((1.15, 1.3))]
    assert "neighbouring step" in doc["jump_db"]["meaning"]


def test_a_step_onto_another_branch_along_a_steep_slope_is_a_jump() -> None:
    # Both fall 4 dB a step; "up" runs 6 dB above "down" and joins it between 1.0 and 1.05:
    # a 10 dB step that the neighbouring slopes (4 dB a step) explain within a factor 3, but
    # it leaves one response for another.
    down = -80.0 * R
    up = np.where(R <= 1.0 + 1e-9, down + 6.0, down)
    h = hysteresis_map(branches_ds(up, down))
    doc = hysteresis_json(h)
    assert [(j["branch"], j["kind"]) for j in doc["jumps"]] == [("up", "branch change")]
    assert doc["jumps"][0]["interval"] == pytest.approx([1.0, 1.05])
    assert doc["jumps"][0]["size_db"] == pytest.approx(-10.0)
    # the same step with no other branch to join: the slope explains it
    assert hysteresis_map(branches_ds(up, down), sel={"direction": "up"}).sizes["jump"] == 0


def _boxes(fig: Figure) -> list:
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    return [t.get_window_extent(renderer) for t in fig.axes[0].texts]


def test_jump_labels_never_overlap_crowded_jumps_are_listed_in_the_legend() -> None:
    # the sweep: two labels far apart, drawn on the figure
    fig = hysteresis_figure(hysteresis_map(sweep_ds()))
    assert sorted(t.get_text() for t in fig.axes[0].texts) == ["J1", "J2"]
    # twelve starts on a fine grid, each jumping by 5 dB one grid point after the previous
    # one: the labels would pile up, so none is drawn and the legend lists the jumps
    fine = np.round(np.linspace(0.5, 2.0, 151), 10)
    starts = [f"random-{k}" for k in range(12)]
    gamma = np.stack([np.where(fine >= 1.0 + 0.01 * k - 1e-9, -5.0, 0.0) for k in range(12)])
    ds = xr.Dataset(
        {"transmittance_db": (("initial", "gamma_r"), gamma, {"units": "dB"})},
        coords={"initial": starts, "gamma_r": ("gamma_r", fine, {"units": "1"})},
    )
    h = hysteresis_map(ds)
    assert h.sizes["jump"] == 12
    fig = hysteresis_figure(h)
    assert len(fig.axes[0].texts) == 0 and len(_lines(fig, "jump")) == 12
    text = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "J1 random-0: γ_r 0.99 → 1, -5 dB" in text
    assert sum(t.startswith("J") for t in text) == 8 and "… 4 more jumps (JSON, CSV)" in text
    # wherever labels are drawn, no two overlap
    for h_ in (hysteresis_map(sweep_ds()), hysteresis_map(multistart_ds(True))):
        boxes = _boxes(hysteresis_figure(h_))
        assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
