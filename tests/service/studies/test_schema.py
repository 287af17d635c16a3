"""Study definitions: validation (every problem, with its path), grid expansion, ids."""

from __future__ import annotations

import copy
import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.studies.schema import StudyError, load_study, parse_study
from service.studies.variables import MODEL_AXES
from worker.physical import PhysicalCell

STUDIES = sorted((Path(__file__).resolve().parents[3] / "studies").glob("*.yaml"))


def _base() -> dict[str, Any]:
    return {
        "name": "t",
        "grid": {"gamma_r": [0.5, 1.0], "gap": 0.1, "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0},
    }


def _paths(exc: StudyError) -> set[str]:
    return {p for p, _ in exc.problems}


# --------------------------------------------------------------------------- shipped studies


def test_shipped_studies_exist() -> None:
    names = {p.name for p in STUDIES}
    assert {
        "paper-fig5-gaps.yaml",
        "paper-fig6-effective-mass.yaml",
        "experiment-table1.yaml",
        "quick.yaml",
    } <= names


@pytest.mark.parametrize("path", STUDIES, ids=lambda p: p.name)
def test_shipped_study_validates(path: Path) -> None:
    study = load_study(path)
    assert study.size >= 1
    assert len(study.points(0, min(3, study.size))) == min(3, study.size)
    assert path.read_text().lstrip().startswith("#")  # each says what it shows


def test_fig5_axes() -> None:
    s = load_study(STUDIES[0].parent / "paper-fig5-gaps.yaml")
    axes = s.axes()
    assert list(axes["gap"]) == [0.1, 0.3, 0.5, 0.7, 1.0]
    assert axes["gamma_r"][0] == 0.2 and axes["gamma_r"][-1] == 6.0
    assert axes["theta"].size > 1


def test_table1_study_maps_like_physical_cell() -> None:
    s = load_study(STUDIES[0].parent / "experiment-table1.yaml")
    pts = list(s.iter_points())
    cell = PhysicalCell.table1(damping_ratio=0.03, base_amplitude_m=0.0005)
    coords = s.coords_at(0, s.size)
    i = next(
        i
        for i in range(s.size)
        if coords["base_amplitude_m"][i] == 0.0005 and coords["frequency_hz"][i] == 25.0
    )
    ref = cell.to_model(25.0)
    for k, v in ref.items():
        assert pts[i][k] == pytest.approx(v, rel=1e-12)


# --------------------------------------------------------------------------- ranges


def test_ranges() -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 0.2, "stop": 6.0, "step": 0.2}
    d["grid"]["theta"] = {"start": 0.1, "stop": 1.0, "num": 4}
    d["grid"]["sigma"] = {"start": 0.01, "stop": 1.0, "num": 3, "scale": "log"}
    s = parse_study(d)
    ax = s.axes()
    assert ax["gamma_r"].size == 30 and ax["gamma_r"][-1] == 6.0 and ax["gamma_r"][2] == 0.6
    np.testing.assert_allclose(ax["theta"], [0.1, 0.4, 0.7, 1.0])
    np.testing.assert_allclose(ax["sigma"], [0.01, 0.1, 1.0])
    assert s.shape == (4, 3, 30) and s.size == 360
    assert set(s.scalars()) == {"gap", "gamma_s"}


def test_yaml_exponent_without_dot(tmp_path: Path) -> None:
    # YAML 1.1 reads 1e-3 as a string; the study accepts it as the number the user meant.
    p = tmp_path / "s.yaml"
    p.write_text("name: t\ngrid: {gamma_r: 1, gap: 1e-3, theta: 0.3, sigma: 5e-2, gamma_s: 1}\n")
    assert load_study(p).scalars()["gap"] == 1e-3


def test_json_file(tmp_path: Path) -> None:
    p = tmp_path / "s.json"
    p.write_text(json.dumps(_base()))
    assert load_study(p).size == 2


# --------------------------------------------------------------------------- errors


def test_every_problem_reported_with_path() -> None:
    d = _base()
    d["colour"] = "red"
    d["solver"] = {"method": "rk4", "window": 5000}
    d["grid"]["gamma_r"] = {"start": 1.0, "stop": 2.0, "num": 0}
    d["grid"]["theta"] = [0.3, -1.0]
    d["grid"]["sigma"] = []
    d["grid"]["frequency"] = 3
    d["model"] = {"modes": 31}
    with pytest.raises(StudyError) as info:
        parse_study(d)
    paths = _paths(info.value)
    assert {
        "colour",
        "solver.method",
        "grid.gamma_r",
        "grid.theta",
        "grid.sigma",
        "grid.frequency",
        "model.modes",
    } <= paths
    text = str(info.value)
    assert "num must be >= 1, got 0" in text and "unknown key" in text


def test_cross_field_problems() -> None:
    d = _base()
    del d["grid"]["theta"]
    d["grid"]["g1"] = 0.2
    d["grid"]["frequency_hz"] = 20.0
    with pytest.raises(StudyError) as info:
        parse_study(d)
    assert {"grid.theta", "grid.gap", "grid.frequency_hz"} <= _paths(info.value)


def test_grid_limit() -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 0.1, "stop": 6.0, "num": 1000}
    d["grid"]["theta"] = {"start": 0.1, "stop": 1.0, "num": 1000}
    with pytest.raises(StudyError, match="1,000,000 points, more than the limit of 999,999"):
        parse_study(d, max_points=999_999)
    assert parse_study(d, max_points=1_000_000).size == 1_000_000


def test_grid_limit_reported_with_other_problems() -> None:
    d = _base()
    d["extra"] = 1
    d["grid"]["gamma_r"] = {"start": 0.1, "stop": 6.0, "num": 3000}
    with pytest.raises(StudyError) as info:
        parse_study(d, max_points=100)
    assert {"extra", "grid"} <= _paths(info.value)


def test_physical_problems() -> None:
    d = {
        "name": "p",
        "physical": {"length_m": 0.15, "width_m": -1.0, "gap_m": 0.001},
        "grid": {"frequency_hz": [10, 20], "gamma_r": 1.0},
    }
    with pytest.raises(StudyError) as info:
        parse_study(d)
    paths = _paths(info.value)
    assert "grid.gamma_r" in paths
    assert "physical.base_amplitude_m" in paths
    assert "physical.outer_mass_kg" in paths


# --------------------------------------------------------------------------- ids


def test_id_is_canonical() -> None:
    a = _base()
    b = copy.deepcopy(a)
    b["grid"] = dict(reversed(list(b["grid"].items())))
    b["model"] = {"coupling": "paper", "modes": 5}  # explicit defaults
    b["solver"] = {"method": "event", "periodicity_tol": 1e-9, "lcp": "closed"}
    assert parse_study(a).id == parse_study(b).id
    c = copy.deepcopy(a)
    c["grid"]["gamma_r"] = [0.5, 1.1]
    assert parse_study(c).id != parse_study(a).id
    d = copy.deepcopy(a)
    d["solver"] = {"max_periods": 500}
    assert parse_study(d).id != parse_study(a).id


def test_solver_defaults_are_the_workers() -> None:
    from dataclasses import asdict

    from worker.simulate import SolverSettings

    s = parse_study(_base())
    worker = asdict(SolverSettings())
    assert s.solver.method == worker["method"] == "event"
    assert s.solver.periodicity_tol == worker["periodicity_tol"]
    # Every setting a study may give defaults to the worker's value, and reaches the worker.
    assert {k: worker[k] for k in s.solver.model_dump()} == s.solver.model_dump()
    assert asdict(s.solver.settings()) == worker
    canon = s.canonical()["solver"]
    assert {"stat_tol_db", "extrapolate", "early_stop", "lcp"} <= set(canon)


def test_new_solver_settings_are_settable_and_validated() -> None:
    d = _base()
    d["solver"] = {"stat_tol_db": 0.05, "extrapolate": False, "early_stop": False,
                   "lcp": "lemke", "method": "euler"}  # fmt: skip
    got = parse_study(d).solver.settings()
    assert (got.stat_tol_db, got.extrapolate, got.early_stop, got.lcp) == (
        0.05, False, False, "lemke",
    )  # fmt: skip
    assert parse_study(d).id != parse_study(_base()).id
    for solver, path, text in [
        ({"stat_tol_db": -1}, "solver.stat_tol_db", "stat_tol_db must be in (0, 100), got -1"),
        ({"lcp": "pivot"}, "solver.lcp", "'closed' or 'lemke'"),
        ({"early_stop": "sometimes"}, "solver.early_stop", "boolean"),
        ({"method": "rk4"}, "solver.method", "'event', 'exponential' or 'euler'"),
    ]:
        bad = _base()
        bad["solver"] = solver
        with pytest.raises(StudyError) as info:
            parse_study(bad)
        assert path in _paths(info.value), info.value.problems
        assert text in str(info.value)


# --------------------------------------------------------------------------- properties

_values = st.floats(min_value=0.01, max_value=10.0, allow_nan=False).map(lambda v: round(v, 6))
_axis = st.one_of(
    _values,
    st.lists(_values, min_size=1, max_size=4, unique=True),
    st.builds(
        lambda a, span, n: {"start": a, "stop": round(a + span, 6), "num": n},
        _values,
        st.floats(min_value=0.5, max_value=5.0).map(lambda v: round(v, 3)),
        st.integers(1, 4),
    ),
)


@settings(max_examples=60, deadline=None)
@given(axes=st.fixed_dictionaries({k: _axis for k in ("gamma_r", "gap", "theta", "sigma")}))
def test_grid_expansion_is_the_cartesian_product(axes: dict[str, Any]) -> None:
    d = {"name": "h", "grid": {**axes, "gamma_s": 1.0}}
    s = parse_study(d)
    expected = {k: s.axes()[k] for k in MODEL_AXES if k in s.axes()}
    combos = list(itertools.product(*expected.values()))
    assert s.size == len(combos)
    assert s.shape == tuple(v.size for v in expected.values() if v.size > 1)
    pts = s.points(0, s.size)
    for combo, p in zip(combos, pts, strict=True):
        row = dict(zip(expected, combo, strict=True))
        assert p["g1"] == p["g2"] == row["gap"]
        for k in ("gamma_r", "theta", "sigma", "gamma_s"):
            assert p[k] == row[k]
    # Points by chunks equal points all at once, whatever the chunking.
    cut = s.size // 2
    assert s.points(0, cut) + s.points(cut, s.size) == pts


_BREAKAGES: dict[str, tuple[str, Any]] = {
    # name: (path reported, mutation of a valid definition)
    "unknown_top": ("bogus", lambda d: d.__setitem__("bogus", 1)),
    "unknown_axis": ("grid.omega", lambda d: d["grid"].__setitem__("omega", 1.0)),
    "negative": ("grid.theta", lambda d: d["grid"].__setitem__("theta", [0.2, -0.1])),
    "zero_num": (
        "grid.gamma_r",
        lambda d: d["grid"].__setitem__("gamma_r", {"start": 1, "stop": 2, "num": 0}),
    ),  # noqa: E501
    "bad_step": (
        "grid.sigma",
        lambda d: d["grid"].__setitem__("sigma", {"start": 1, "stop": 2, "step": -1}),
    ),  # noqa: E501
    "log_zero": (
        "grid.gamma_s",
        lambda d: d["grid"].__setitem__(
            "gamma_s", {"start": 0, "stop": 2, "num": 3, "scale": "log"}
        ),
    ),  # noqa: E501
    "empty": ("grid.xi", lambda d: d["grid"].__setitem__("xi", [])),
    "bool": ("grid.gap", lambda d: d["grid"].__setitem__("gap", True)),
    "modes": ("model.modes", lambda d: d.setdefault("model", {}).__setitem__("modes", 0)),
    "method": ("solver.method", lambda d: d.setdefault("solver", {}).__setitem__("method", "x")),
    "name": ("name", lambda d: d.__setitem__("name", "")),
}


@settings(max_examples=60, deadline=None)
@given(st.sets(st.sampled_from(sorted(_BREAKAGES)), min_size=1))
def test_validation_reports_every_injected_problem(broken: set[str]) -> None:
    d = _base()
    for name in broken:
        _BREAKAGES[name][1](d)
    with pytest.raises(StudyError) as info:
        parse_study(d)
    assert {_BREAKAGES[n][0] for n in broken} <= _paths(info.value)
    assert isinstance(info.value, ValueError)
