"""Chains of N cells in study files (docs/chains.md): ``model.cells``, per-cell ``gaps`` and
``sigmas``, ``cells`` as a grid axis, the ``cell`` dimension of the dataset, and N = 1 as the
unit cell (points, keys and results)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.local import run
from service.studies.points import study_keys
from service.studies.schema import StudyError, parse_study
from worker.model import CellParams
from worker.model.chain import ChainParams
from worker.simulate import simulate_chain_point
from worker.solvers.settings import SolverSettings


def chain_study(**model: Any) -> dict[str, Any]:
    """A small chain study: N over ``cells``, three frequencies, the paper's gap and θ."""
    return {
        "name": "chain",
        "model": {"coupling": "paper", "modes": 2, "xi": 0.05, **model},
        "solver": {"method": "euler", "max_periods": 400},
        "grid": {"cells": [1, 2], "gamma_r": [0.8, 1.6, 2.5], "gap": 0.1, "theta": 0.3,
                 "sigma": 0.05, "gamma_s": 1.0},
    }  # fmt: skip


def problems(d: dict[str, Any]) -> str:
    with pytest.raises(StudyError) as err:
        parse_study(d)
    return str(err.value)


def test_a_unit_cell_study_has_no_chain_fields_and_keeps_its_id() -> None:
    d = chain_study()
    del d["grid"]["cells"]
    s = parse_study(d)
    assert "cells" not in s.canonical()["model"] and "cells" not in s.canonical()["grid"]
    assert s.max_cells() == 1
    assert all(set(p) & {"cells", "cell_g1", "cell_g2", "cell_sigma"} == set()
               for p in s.iter_points())  # fmt: skip


def test_n_equal_1_points_and_keys_are_the_unit_cells() -> None:
    chain = parse_study(chain_study())
    d = chain_study()
    del d["grid"]["cells"]
    unit = parse_study(d)
    pts = list(chain.iter_points())
    assert [p for p in pts if "cells" not in p] == list(unit.iter_points())
    assert [p["cells"] for p in pts if "cells" in p] == [2, 2, 2]
    keys = study_keys(chain)
    assert keys[:3] == study_keys(unit)  # N = 1 first: the unit cell's keys
    assert len(set(keys)) == 6  # a chain's key is not its first cell's


def test_graded_lists_make_chain_points() -> None:
    d = chain_study(cells=3, gaps=[0.1, 0.2, 0.3], sigmas=[0.05, 0.06, 0.07])
    del d["grid"]["cells"], d["grid"]["gap"], d["grid"]["sigma"]
    s = parse_study(d)
    p = next(s.iter_points())
    assert p["cells"] == 3 and p["cell_g1"] == p["cell_g2"] == [0.1, 0.2, 0.3]
    assert p["cell_sigma"] == [0.05, 0.06, 0.07] and p["g1"] == 0.1 and p["sigma"] == 0.05


@pytest.mark.parametrize(
    ("change", "where", "says"),
    [
        (lambda d: d["solver"].update(method="event"), "solver.method", "does not run chains"),
        (lambda d: d["grid"].update(cells=[1, 2.5]), "grid.cells", "whole numbers"),
        (lambda d: d["grid"].update(cells=[1, 101]), "grid.cells", "allowed range [1, 100]"),
        (lambda d: d["model"].update(cells=2), "grid.cells", "also given as model.cells"),
        (lambda d: d.update(sweep={"axis": "gamma_r", "directions": ["up"]}), "sweep",
         "not available for chains"),
        (lambda d: d.update(initial="linear"), "initial", "start from rest"),
        (lambda d: d["solver"].update(steps_per_period=65536, max_periods=10000),
         "solver.steps_per_period", "× cells"),
    ],
)  # fmt: skip
def test_bad_chain_studies_name_the_field(change: Any, where: str, says: str) -> None:
    d = copy.deepcopy(chain_study())
    change(d)
    text = problems(d)
    assert where in text and says in text, text


def test_per_cell_lists_are_checked() -> None:
    d = chain_study(cells=2, gaps=[0.1])
    del d["grid"]["cells"], d["grid"]["gap"]
    assert "gaps has 1 values but model.cells is 2" in problems(d)
    d = chain_study(cells=2, gaps=[0.1, -0.2])
    del d["grid"]["cells"], d["grid"]["gap"]
    assert "gaps[1] must be >= 0, got -0.2" in problems(d)  # cell 2
    d = chain_study(cells=2, gaps=[0.1, 0.2])
    del d["grid"]["cells"]  # grid.gap stays: given twice
    assert "grid.gap" in problems(d) and "model.gaps" in problems(d)


def test_the_point_budget_counts_cells() -> None:
    d = chain_study()
    d["grid"]["cells"] = [50, 100]
    d["grid"]["gamma_r"] = {"start": 0.5, "stop": 3.0, "num": 10}
    with pytest.raises(StudyError) as err:
        parse_study(d, max_points=1000)
    assert "1,500 cell-points" in str(err.value)
    parse_study(d, max_points=1500)


@pytest.mark.slow  # runs two small studies (a chain of 2 with euler)
def test_a_chain_study_runs_into_a_cell_dimension(tmp_path: Path) -> None:
    ds = run(chain_study(), data_dir=tmp_path, serial=True)
    assert ds.sizes["cells"] == 2 and ds.sizes["cell"] == 2
    cell = ds["cell_transmittance_db"]
    assert cell.dims == ("cells", "gamma_r", "cell") and cell.attrs["units"] == "dB"
    # N = 1: cell 1 is the point's own Γ, cell 2 missing
    one = ds.sel(cells=1)
    assert np.all(np.isnan(one["cell_transmittance_db"].sel(cell=2)))
    proven = np.isin(one["outcome"].values, [0, 1])
    np.testing.assert_array_equal(one["cell_transmittance_db"].sel(cell=1).values[proven],
                                  one["transmittance_db"].values[proven])  # fmt: skip
    # N = 2: the last cell's Γ is the point's Γ_N (the orbit run again), the linear lists end
    # in Γ_N,lin
    two = ds.sel(cells=2)
    proven = np.isin(two["outcome"].values, [0, 1])
    assert proven.any()
    np.testing.assert_allclose(two["cell_transmittance_db"].sel(cell=2).values[proven],
                               two["transmittance_db"].values[proven], atol=1e-6)  # fmt: skip
    np.testing.assert_array_equal(two["cell_transmittance_linear_db"].sel(cell=2).values,
                                  two["transmittance_linear_db"].values)  # fmt: skip
    # each chain point is simulate_chain_point's result
    for g in (0.8, 2.5):
        cp = ChainParams(CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=g, xi=0.05,
                                    g1=0.1, g2=0.1, modes=2), 2)  # fmt: skip
        r = simulate_chain_point(cp, SolverSettings(method="euler", max_periods=400))
        assert float(two["transmittance_db"].sel(gamma_r=g)) == r.transmittance_db
    # N = 1 is the unit cell's study, bit for bit
    d = chain_study()
    del d["grid"]["cells"]
    unit = run(d, data_dir=tmp_path, serial=True)
    for name in ("transmittance_db", "outcome", "periods", "transmittance_linear_db"):
        np.testing.assert_array_equal(one[name].values, unit[name].values)


@pytest.mark.slow  # runs a small study into a point store
def test_the_point_store_keeps_n_and_a_rerun_reuses_every_point(
    catalogue_url: str, tmp_path: Path
) -> None:
    from service.api.catalogue import Catalogue
    from service.api.points import PointQuery, SqlPointStore, points_csv, points_dataset
    from service.studies.runner import run_study

    cat = Catalogue(catalogue_url)
    try:
        store = SqlPointStore(cat.engine)
        s = parse_study(chain_study())
        first = run_study(s, tmp_path / "a", serial=True, points=store)
        again = run_study(s, tmp_path / "b", serial=True, points=store)
        assert first.computed == 6 and again.computed == 0  # every point from the store
        chains, _ = store.query(PointQuery(cells=2))
        units, _ = store.query(PointQuery(cells=1))
        assert len(chains) == len(units) == 3
        assert {r["cells"] for r in chains} == {2} and {r["cells"] for r in units} == {1}
        assert all(len(r["cell_transmittance_linear_db"]) == 2 for r in chains)
        assert "cell_transmittance_db" not in units[0]
        head = points_csv(chains).splitlines()[0].split(",")
        assert head.index("cells") == head.index("e2") + 1  # the parameters, then N
        assert sorted(points_dataset(chains + units)["cells"].values.tolist()) == [1] * 3 + [2] * 3
    finally:
        cat.close()


def test_a_chain_study_takes_either_chain_method(tmp_path: Path) -> None:
    d = chain_study()
    d["solver"]["method"] = "exponential"
    assert parse_study(d).solver.method == "exponential"
    d["grid"]["cells"] = [2]
    d["grid"]["gamma_r"] = [2.5]
    ds = run(d, data_dir=tmp_path, serial=True)
    cp = ChainParams(CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=2.5, xi=0.05,
                                g1=0.1, g2=0.1, modes=2), 2)  # fmt: skip
    r = simulate_chain_point(cp, SolverSettings(method="exponential", max_periods=400))
    assert float(ds["transmittance_db"].squeeze()) == r.transmittance_db
