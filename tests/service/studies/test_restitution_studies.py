"""Restitution in study files: ``restitution`` (both stops), ``e1`` and ``e2`` as grid axes;
e = 0 points keep the keys and results of a study without them (docs/model.md §5)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.local import run
from service.studies.points import point_key, study_keys
from service.studies.schema import StudyError, parse_study


def study(**grid: Any) -> dict[str, Any]:
    return {
        "name": "bouncy",
        "model": {"modes": 3},
        "solver": {"method": "euler", "max_periods": 300},
        "grid": {"gamma_r": [0.8, 1.3, 2.0], "gap": 0.1, "theta": 0.3, "sigma": 0.05,
                 "gamma_s": 1.0, **grid},
    }  # fmt: skip


def test_a_zero_restitution_keeps_every_key() -> None:
    cell = {"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, "gamma_r": 1.3, "g1": 0.1, "g2": 0.1}
    solver = {"method": "euler"}
    plain = point_key(cell, solver)
    assert point_key({**cell, "e1": 0.0, "e2": 0.0}, solver) == plain
    assert point_key({**cell, "e1": 0.5, "e2": 0.5}, solver) != plain
    assert point_key({**cell, "e1": 0.5}, solver) != point_key({**cell, "e2": 0.5}, solver)
    s = parse_study(study(restitution=[0.0, 0.5]))
    keys = study_keys(s)
    assert keys[:3] == study_keys(parse_study(study()))  # e = 0 first: the plain study's
    assert [p["e1"] for p in s.iter_points()] == [0.0] * 3 + [0.5] * 3


@pytest.mark.parametrize(
    ("change", "where", "says"),
    [
        (lambda d: d["grid"].update(e1=0.3), "grid.restitution", "not both"),
        (lambda d: d["grid"].update(restitution=[0.5, 1.2]), "grid.restitution",
         "restitution must be <= 1"),
        (lambda d: d["grid"].update(cells=[1, 2]), "grid.restitution",
         "chains of N > 1 cells run plastic impacts only"),
    ],
)  # fmt: skip
def test_bad_restitution_studies_name_the_field(change: Any, where: str, says: str) -> None:
    d = copy.deepcopy(study(restitution=[0.0, 0.5]))
    change(d)
    with pytest.raises(StudyError) as err:
        parse_study(d)
    assert where in str(err.value) and says in str(err.value), str(err.value)


def test_an_event_study_with_restitution_is_allowed() -> None:
    d = study(restitution=[0.0, 0.5])
    d["solver"]["method"] = "event"
    assert parse_study(d).solver.method == "event"


@pytest.mark.slow  # runs two small studies
def test_a_restitution_axis_runs_and_its_zero_is_the_plain_study(tmp_path: Path) -> None:
    ds = run(study(restitution=[0.0, 0.6]), data_dir=tmp_path, serial=True)
    plain = run(study(), data_dir=tmp_path, serial=True)
    assert ds["transmittance_db"].dims == ("restitution", "gamma_r")
    for name in ("transmittance_db", "outcome", "periods", "impacts_per_period"):
        np.testing.assert_array_equal(ds[name].sel(restitution=0.0).values, plain[name].values)
    bouncy = ds.sel(restitution=0.6)
    assert not bool(bouncy["failed"].any())
    assert (bouncy["impacts_per_period"].sum("stop") >= plain["impacts_per_period"].sum("stop")
            ).all()  # fmt: skip
