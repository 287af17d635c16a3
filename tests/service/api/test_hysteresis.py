"""GET /studies/{id}/hysteresis and /plots/hysteresis.{png,svg} in process (TestClient, no
cluster), and the client's ``hysteresis``.

The served study is a plain one; its results file is written directly with a synthetic sweep
dataset (dims direction × gap × gamma_r, ``sweep_axis`` attribute, ``responses``), so no point
is simulated and the numbers are known.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from service.api.routes import results
from service.client import InvalidRequest
from service.studies.variables import outcome_attrs
from tests.service.api.test_results import QUICK, Served, record

GR = np.round(np.linspace(0.1, 6.0, 6), 12)  # the study's γ_r: 0.1, 1.28, 2.46, 3.64, 4.82, 6
GAP = np.array([0.1, 0.5, 2.0])


def sweep_results(sweep_axis: str = "gamma_r") -> xr.Dataset:
    """Up: 0 dB up to γ_r[2], −6 dB from γ_r[3]. Down: −6 dB down to γ_r[1], 0 dB at γ_r[0].
    They differ at γ_r[1] and γ_r[2]; the same at every gap, 1 dB lower per gap."""
    up = np.where(np.arange(6) <= 2, 0.0, -6.0)
    down = np.where(np.arange(6) >= 1, -6.0, 0.0)
    gamma = np.stack([up, down])[:, None, :] - np.arange(3)[None, :, None]
    dims = ("direction", "gap", "gamma_r")
    outcome = np.where(gamma < -3, 1, 0).astype(np.int8)
    outcome[0, 0, 5] = 3  # unsettled
    responses = np.tile(np.array([1, 2, 2, 1, 1, 1]), (3, 1))
    return xr.Dataset(
        {
            "transmittance_db": (dims, gamma, {"units": "dB", "long_name": "transmittance"}),
            "outcome": (dims, outcome, outcome_attrs()),
            "failed": (dims, np.zeros(gamma.shape, dtype=bool)),
            "responses": (("gap", "gamma_r"), responses, {"units": "1"}),
        },
        coords={
            "direction": ("direction", np.array(["up", "down"])),
            "gap": ("gap", GAP, {"units": "1", "long_name": "clearance"}),
            "gamma_r": ("gamma_r", GR, {"units": "1", "long_name": "frequency ratio"}),
            "theta": ((), 0.1, {"units": "1"}),
            "sigma": ((), 0.05, {"units": "1"}),
            "gamma_s": ((), 1.0, {"units": "1"}),
        },
        attrs={"sweep_axis": sweep_axis, "study_id": "synthetic"},
    )


def finish(app: Served, ds: xr.Dataset) -> None:
    """Serve ``ds`` as the study's finished results file."""
    app.store.write_results(ds)
    app.tc.app.state.catalogue.update_study(app.id, status="finished")


@pytest.fixture
def swept(tmp_path: Path) -> Iterator[Served]:
    definition = {**QUICK, "grid": {**QUICK["grid"], "theta": 0.1}}
    app = Served(tmp_path, definition)
    try:
        finish(app, sweep_results())
        yield app
    finally:
        app.close()


def test_the_map_describes_branches_jumps_and_where_they_differ(swept: Served) -> None:
    r = swept.get("/hysteresis")
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["study_id"] == swept.id and out["partial"] is False
    assert out["x"] == "gamma_r" == out["sweep_axis"] and out["branch_dims"] == ["direction"]
    assert out["axes"]["x"]["values"] == pytest.approx(list(GR))
    assert out["axes"]["x"]["units"] == "1" and out["variable"]["units"] == "dB"
    assert out["slice"]["gap"] == {"value": 0.1, "units": "1", "long_name": "clearance",
                                   "default": True}  # fmt: skip
    assert out["slice"]["theta"]["default"] is False
    assert out["jump_db"]["value"] == 1.0 and out["tol_db"]["value"] == 0.05
    assert "consecutive" in out["jump_db"]["meaning"]
    up, down = out["branches"]
    assert (up["label"], up["order"], down["label"], down["order"]) == (
        "up", "increasing", "down", "decreasing"
    )  # fmt: skip
    assert up["values"] == [0.0, 0.0, 0.0, -6.0, -6.0, -6.0]
    assert up["outcomes"][5] == "unsettled" and down["outcomes"][0] == "linear"
    assert [(j["label"], j["branch"]) for j in out["jumps"]] == [("J1", "up"), ("J2", "down")]
    j1, j2 = out["jumps"]
    assert (j1["from"], j1["to"], j1["size_db"]) == (pytest.approx(GR[2]), pytest.approx(GR[3]),
                                                     -6.0)  # fmt: skip
    assert (j2["from"], j2["to"], j2["size_db"]) == (pytest.approx(GR[1]), pytest.approx(GR[0]),
                                                     6.0)  # fmt: skip
    assert out["differing"] == [{"start": pytest.approx(GR[1]), "stop": pytest.approx(GR[2]),
                                 "points": 2, "max_spread_db": 6.0}]  # fmt: skip
    assert out["responses"] == [1, 2, 2, 1, 1, 1]
    assert out["counts"] == {"branches": 2, "jumps": 2, "differing_points": 2,
                             "coexisting_points": 2}  # fmt: skip
    assert swept.client.hysteresis(swept.id) == out


def test_selection_thresholds_and_csv(swept: Served) -> None:
    out = swept.client.hysteresis(swept.id, gap=2.0)
    assert out["slice"]["gap"]["value"] == 2.0 and not out["slice"]["gap"]["default"]
    assert out["branches"][0]["values"][0] == -2.0
    # jump_db and tol_db are thresholds, not coordinates to select
    quiet = swept.client.hysteresis(swept.id, jump_db=6.0, tol_db=6.0)
    assert quiet["jumps"] == [] and quiet["differing"] == []
    down = swept.client.hysteresis(swept.id, direction="down")
    assert [b["label"] for b in down["branches"]] == ["down"] and down["differing"] == []
    along_gap = swept.client.hysteresis(swept.id, x="gap", gamma_r=GR[1])
    assert along_gap["x"] == "gap" and along_gap["differs"] == [True, True, True]
    text = swept.client.hysteresis_csv(swept.id)
    assert text == swept.get("/hysteresis", format="csv").text
    rows = list(csv.DictReader(io.StringIO(text)))
    assert len(rows) == 12 and rows[0]["branch"] == "up" and rows[0]["gap"] == "0.1"
    assert [r["jump"] for r in rows if r["jump"]] == ["J1", "J2"]
    assert swept.get("/hysteresis", format="csv").headers["content-type"].startswith("text/csv")


def test_the_swept_axis_is_the_default_x(tmp_path: Path) -> None:
    app = Served(tmp_path, {**QUICK, "grid": {**QUICK["grid"], "theta": 0.1}})
    try:
        finish(app, sweep_results(sweep_axis="gap"))
        out = app.client.hysteresis(app.id)
        assert out["x"] == "gap" and out["slice"]["gamma_r"]["default"] is True
        r = app.get("/plots/hysteresis.png")
        fixed = json.loads(r.headers["x-impactcell-fixed"])
        assert fixed == {"x": "gap", "y": None, "fixed": {"gamma_r": 0.1}}
    finally:
        app.close()


@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_the_plot(swept: Served, fmt: str) -> None:
    r = swept.get(f"/plots/hysteresis.{fmt}")
    assert r.status_code == 200, r.text
    assert json.loads(r.headers["x-impactcell-fixed"]) == {"x": "gamma_r", "y": None,
                                                           "fixed": {"gap": 0.1}}  # fmt: skip
    if fmt == "png":
        assert r.content[:4] == b"\x89PNG"
    else:
        assert b"<svg" in r.content[:500]
    assert swept.client.plot(swept.id, "hysteresis", fmt=fmt) == r.content
    other = swept.client.plot(swept.id, "hysteresis", fmt=fmt, gap=0.5, tol_db=10)
    assert other != r.content


def test_bad_requests_are_422_with_a_clear_message(
    swept: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    r = swept.get("/hysteresis", gap=0.2)
    assert r.status_code == 422 and "gap=0.2 is not a coordinate value" in r.json()["detail"]
    r = swept.get("/hysteresis", direction="sideways")
    assert r.status_code == 422 and "direction=sideways" in r.json()["detail"]
    r = swept.get("/hysteresis", variable="responses")
    assert r.status_code == 422 and "does not vary with direction" in r.json()["detail"]
    assert swept.get("/hysteresis", jump_db=0).status_code == 422
    assert swept.get("/hysteresis", tol_db=-1).status_code == 422
    monkeypatch.setattr(results, "MAX_SLICE_VALUES", 10)
    r = swept.get("/hysteresis")
    assert r.status_code == 422 and "12 values (2 branches × 6" in r.json()["detail"]
    assert "direction=" in r.json()["detail"]
    assert swept.get("/hysteresis", direction="up").status_code == 200


def test_a_study_without_sweep_or_starts_has_no_hysteresis(served: Served) -> None:
    served.write(0, 36)
    for path in ("/hysteresis", "/plots/hysteresis.png"):
        r = served.get(path)
        assert r.status_code == 422
        assert "this study has no sweep or several starts: no hysteresis" in r.json()["detail"]
    with pytest.raises(InvalidRequest, match="no sweep or several starts"):
        served.client.hysteresis(served.id)


def test_a_partial_sweep_study_from_its_chunks(tmp_path: Path) -> None:
    """A sweep with two initial states, half of its lines done: served from the chunks."""
    definition = {
        "name": "sweep-like",
        "grid": {"gamma_r": [0.5, 1.0, 1.5, 2.0], "gap": [0.1, 0.3], "theta": 0.3,
                 "sigma": 0.05, "gamma_s": 1.0},
        "sweep": {"axis": "gamma_r", "directions": ["up", "down"]},
        "initial": ["rest", "linear"],
    }  # fmt: skip
    app = Served(tmp_path, definition)
    try:
        recs = [{**record(i), "started_from": "previous"} for i in range(16)]
        app.store.write_chunk(0, 16, recs)
        out = app.client.hysteresis(app.id)
        assert out["partial"] is True and out["x"] == "gamma_r" == out["sweep_axis"]
        assert out["branch_dims"] == ["initial", "direction"]
        labels = [b["label"] for b in out["branches"]]
        assert labels == ["rest/up", "rest/down", "linear/up", "linear/down"]
        outcomes = [o for b in out["branches"] for o in b["outcomes"]]
        assert "pending" in outcomes and "linear" in outcomes
        assert app.get("/plots/hysteresis.svg").status_code == 200
    finally:
        app.close()
