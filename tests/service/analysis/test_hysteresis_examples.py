"""The shipped hysteresis examples show what their files say: two coexisting responses, the
jumps, and where up and down differ (studies/hysteresis-*.yaml)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from service.analysis.hysteresis import hysteresis_json, hysteresis_map
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import load_study
from service.studies.shipped import shipped_studies
from service.studies.variables import outcome_names

pytestmark = pytest.mark.slow  # whole studies (about a second each, serial)


def _run(name: str, tmp_path: Path):
    study = load_study(shipped_studies()[name])
    return open_results(run_study(study, tmp_path, serial=True).path)


def test_the_frequency_sweep_jumps_where_its_file_says(tmp_path: Path) -> None:
    ds = _run("hysteresis-frequency-sweep", tmp_path)
    doc = hysteresis_json(hysteresis_map(ds))
    jumps = {j["direction"]: j for j in doc["jumps"]}
    # down jumps from the linear response onto the orbit between 1.85 and 1.80
    assert jumps["down"]["interval"] == pytest.approx([1.8, 1.85])
    assert abs(jumps["down"]["size_db"]) > 1.0
    # up leaves the orbit for irregular impacting motion at 2.0 and falls onto the linear
    # response at 2.1: the irregular motion's cycle-by-cycle Γ is within 1 dB of both sides,
    # so no jump of more than 1 dB is drawn there
    up_outcome = ds["outcome"].sel(direction="up", gamma_r=[1.95, 2.0, 2.05, 2.1])
    assert list(outcome_names(up_outcome)) == ["periodic", "irregular", "irregular", "linear"]
    assert "up" not in jumps
    (region,) = doc["differing"]
    assert (region["start"], region["stop"]) == pytest.approx((1.85, 2.0))
    up = ds["transmittance_db"].sel(direction="up")
    down = ds["transmittance_db"].sel(direction="down")
    for g, u, d in ((1.85, -9.763, -7.564), (1.9, -9.737, -8.202), (1.95, -10.142, -8.810)):
        assert float(up.sel(gamma_r=g)) == pytest.approx(u, abs=0.01)
        assert float(down.sel(gamma_r=g)) == pytest.approx(d, abs=0.01)
        assert int(ds["responses"].sel(gamma_r=g)) == 2  # two coexisting responses
    # the down branch there is the cell's linear response, exactly (the closed form)
    lin = ds["transmittance_linear_db"].sel(direction="down", gamma_r=1.85)
    assert float(down.sel(gamma_r=1.85)) == float(lin)


def test_the_gap_sweep_keeps_the_linear_response_down_to_0_3(tmp_path: Path) -> None:
    ds = _run("hysteresis-gap-sweep", tmp_path)
    gaps = ds["gap"].values
    up = ds["transmittance_db"].sel(direction="up").values.ravel()
    down = ds["transmittance_db"].sel(direction="down").values.ravel()
    both = (gaps >= 0.3 - 1e-9) & (gaps <= 0.425 + 1e-9)
    assert both.sum() == 6
    assert np.all(down[both] - up[both] > 1.0)  # 1.3-2.3 dB apart
    assert np.all(ds["responses"].values.ravel()[both] == 2)
    doc = hysteresis_json(hysteresis_map(ds))
    down_jump = next(j for j in doc["jumps"] if j["direction"] == "down")
    assert down_jump["interval"] == pytest.approx([0.275, 0.3])
