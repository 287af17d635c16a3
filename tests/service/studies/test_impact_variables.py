"""The impact observables in records, chunk files, datasets and the point store's exports:
one value per stop, missing (NaN) where a record or an older chunk file lacks them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from service.api.points import points_csv
from service.local import run
from service.studies.chunks import _chunk_column, record_columns
from service.studies.variables import STOP_VARIABLES
from tests.service.helpers import tiny_study


def test_per_stop_columns_and_what_older_records_lack() -> None:
    new = {"outcome": "periodic", "contact_fraction": [0.2, 0.3], "impact_velocity": [0.5, None]}
    old = {"outcome": "periodic"}  # a record stored before the variables existed
    cols = record_columns([new, old], ("contact_fraction", "impact_velocity", "outcome"))
    np.testing.assert_array_equal(cols["contact_fraction"], [[0.2, 0.3], [np.nan, np.nan]])
    np.testing.assert_array_equal(cols["impact_velocity"], [[0.5, np.nan], [np.nan, np.nan]])
    # a chunk file written before them: missing, with the stop dimension
    assert _chunk_column({}, "contact_fraction_se", 3).shape == (3, 2)
    assert "impacts_per_period" in STOP_VARIABLES
    # the impacts' energy: per stop, and its share one value a point
    cols = record_columns([{"outcome": "periodic", "impact_energy": [0.1, 0.2],
                            "impact_energy_share": 0.3}, old],
                          ("impact_energy", "impact_energy_share"))  # fmt: skip
    np.testing.assert_array_equal(cols["impact_energy"], [[0.1, 0.2], [np.nan, np.nan]])
    np.testing.assert_array_equal(cols["impact_energy_share"], [0.3, np.nan])
    assert _chunk_column({}, "impact_energy_se", 3).shape == (3, 2)
    assert np.isnan(_chunk_column({}, "impact_energy_share", 3)).all()
    assert {"impact_energy", "impact_energy_se"} <= set(STOP_VARIABLES)
    assert "impact_energy_share" not in STOP_VARIABLES


@pytest.mark.slow  # runs a small study
def test_a_studys_dataset_and_csv_hold_them_per_stop(tmp_path: Path) -> None:
    ds = run(tiny_study(num=4, gaps=(0.1, 0.5)), data_dir=tmp_path, serial=True)
    for name in ("contact_fraction", "contact_fraction_se", "impact_velocity", "impact_energy",
                 "impact_energy_se"):  # fmt: skip
        assert ds[name].dims[-1] == "stop"
    assert "stop" not in ds["impact_energy_share"].dims
    ct = ds["contact_fraction"].values
    assert np.all((ct[np.isfinite(ct)] >= 0) & (ct[np.isfinite(ct)] <= 1))
    impacting = ds["impacts_per_period"].sum("stop").values > 0
    assert np.all(np.isfinite(ct.sum(-1)[impacting]) | ds["failed"].values[impacting])
    en = ds["impact_energy"].values.sum(-1)
    assert np.all((en[impacting] > 0) | ds["failed"].values[impacting])
    head = points_csv([{"contact_fraction": [0.1, 0.2]}]).splitlines()[0].split(",")
    assert {
        "impacts_stop1",
        "contact_fraction_stop1",
        "impact_velocity_stop2",
        "impact_energy_stop1",
        "impact_energy_se_stop2",
        "impact_energy_share",
    } <= set(head)
