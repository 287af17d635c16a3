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
        "grid.gamma_r.num",
        "grid.theta",
        "grid.sigma",
        "grid.frequency",
        "model.modes",
    } <= paths
    text = str(info.value)
    assert "num must be an integer in 1…1,000,000, got 0" in text and "unknown key" in text


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
        (
            {"stat_tol_db": -1},
            "solver.stat_tol_db",
            "stat_tol_db must be > 0, got -1.0; allowed range (0, 100)",
        ),
        ({"lcp": "pivot"}, "solver.lcp", "'closed' or 'lemke'"),
        ({"early_stop": "sometimes"}, "solver.early_stop", "boolean"),
        ({"method": "rk4"}, "solver.method", "'event', 'exponential' or 'euler'"),
        ({"max_events_per_period": 2_000_000}, "solver.max_events_per_period", "1000000"),
        (
            {"max_events_per_period": 100, "method": "euler"},
            "solver",
            "max_events_per_period applies to method 'event' only, got method 'euler'",
        ),
        ({"transient_guard": -5}, "solver.transient_guard", "integer in 0"),
        (
            {"transient_guard": 2000, "max_periods": 1000},
            "solver",
            "transient_guard must be <= max_periods (1000): a claim cannot wait past the budget; "
            "got 2000",
        ),
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
        "grid.gamma_r.num",
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


# --------------------------------------------------------------------------- sizes, caps, bounds

from unittest import mock  # noqa: E402

from service.studies.files import parse_study_text  # noqa: E402
from service.studies.grid import MAX_AXIS_VALUES, Range  # noqa: E402


def _never_built() -> Any:
    """Patches that fail the test if any axis is expanded into an array."""
    boom = AssertionError("an axis was built")
    return (
        mock.patch.object(Range, "values", side_effect=boom),
        mock.patch("numpy.linspace", side_effect=boom),
        mock.patch("numpy.arange", side_effect=boom),
    )


@pytest.mark.parametrize("num", [10_000_000, 10**9, 10**400])
def test_num_over_the_cap_is_refused_without_building(num: int) -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 0.1, "stop": 6, "num": num}
    a, b, c = _never_built()
    with a as values, b, c, pytest.raises(StudyError) as info:
        parse_study(d)
    assert values.call_count == 0
    (path, msg), *_ = info.value.problems
    assert path == "grid.gamma_r.num"
    assert msg.startswith(f"num must be an integer in 1…{MAX_AXIS_VALUES:,}, got ")
    assert len(msg) < 120  # 10**400 is shown by its size


@pytest.mark.parametrize("step", [1e-9, 1e-320])
def test_a_step_count_over_the_cap_is_refused_without_building(step: float) -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 0.1, "stop": 6, "step": step}
    a, b, c = _never_built()
    with a as values, b, c, pytest.raises(StudyError, match="more than 1,000,000"):
        parse_study(d)
    assert values.call_count == 0


def test_the_point_limit_is_checked_on_sizes_naming_the_axes() -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 0.1, "stop": 6, "num": MAX_AXIS_VALUES}
    d["grid"]["theta"] = {"start": 0.1, "stop": 1.0, "step": 0.001}
    d["grid"]["gap"] = [0.1, 0.2, 0.3]
    a, b, c = _never_built()
    with a as values, b, c, pytest.raises(StudyError) as info:
        parse_study(d, max_points=2_000_000)
    assert values.call_count == 0
    assert info.value.problems == [
        ("grid", "has 2,703,000,000 points, more than the limit of 2,000,000 "
                 "(gap 3 × theta 901 × gamma_r 1,000,000)"),
    ]  # fmt: skip


def test_size_and_shape_are_arithmetic() -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 0.2, "stop": 6.0, "step": 0.2}
    d["grid"]["theta"] = {"start": 0.1, "stop": 1.0, "num": 1000}
    s = parse_study(d)
    a, b, c = _never_built()
    with a, b, c:
        assert (s.size, s.shape) == (30_000, (1000, 30))
        assert s.sizes() == {"gamma_r": 30, "gap": 1, "theta": 1000, "sigma": 1, "gamma_s": 1}
    assert s.shape == tuple(v.size for v in s.dims().values())


@pytest.mark.parametrize(
    ("axis", "value", "text"),
    [
        ("gamma_r", 1e308, "gamma_r must be <= 1000, got 1e+308; allowed range [1e-06, 1000]"),
        ("gamma_r", float("nan"), "gamma_r must be finite, got nan; allowed range [1e-06, 1000]"),
        ("gamma_r", [0.5, float("inf")], "gamma_r must be finite, got inf; allowed range"),
        ("gamma_r", 0.0, "gamma_r must be > 0, got 0.0; allowed range [1e-06, 1000]"),
        ("theta", 1e-9, "theta must be >= 1e-06, got 1e-09; allowed range [1e-06, 10000]"),
        ("sigma", 1e7, "sigma must be <= 1e+06, got 10000000.0; allowed range [1e-06, 1e+06]"),
        ("gamma_s", 1e-4, "gamma_s must be >= 0.001, got 0.0001"),
        ("gap", -0.1, "gap must be >= 0, got -0.1; allowed range [0, 1e+12]"),
        ("gap", 1e13, "gap must be <= 1e+12, got 10000000000000.0"),
        ("xi", 11, "xi must be <= 10, got 11.0; allowed range [0, 10]"),
        ("gamma_r", {"start": 0.5, "stop": 2000, "num": 5}, "got 2000.0; allowed range [1e-06, 1000] (range end)"),  # noqa: E501
        ("gamma_r", {"start": 0.0, "stop": 2, "step": 0.5}, "got 0.0; allowed range [1e-06, 1000] (range start)"),  # noqa: E501
        ("gamma_r", {"start": 1e308, "stop": 2, "num": 3}, "gamma_r must be <= 1000, got 1e+308"),
        ("gamma_r", {"start": 1, "stop": 10**400, "num": 3}, "got an integer of about 401 digits"),
        ("gamma_r", 10**400, "gamma_r must be finite, got an integer of about 401 digits; allowed"),  # noqa: E501
        ("gamma_r", [1.0, 10**400], "an integer of about 401 digits; allowed range [1e-06, 1000] (value 1)"),  # noqa: E501
    ],
)  # fmt: skip
def test_out_of_range_axes_name_the_axis_the_value_and_the_range(axis, value, text) -> None:
    d = _base()
    d["grid"][axis] = value
    with pytest.raises(StudyError) as info:
        parse_study(d)
    assert any(p.startswith(f"grid.{axis}") and text in m for p, m in info.value.problems), (
        info.value.problems
    )


@pytest.mark.parametrize(
    ("block", "values", "path", "text"),
    [
        ("model", {"modes": 10**400}, "model.modes", "modes must be an integer in 1…30, got an integer of about 401"),  # noqa: E501
        ("model", {"xi_b": float("inf")}, "model.xi_b", "xi_b must be finite, got inf; allowed range [0, 10]"),  # noqa: E501
        ("model", {"xi": 1e308}, "model.xi", "xi must be <= 10, got 1e+308"),
        ("solver", {"max_periods": 10**7}, "solver.max_periods", "max_periods must be an integer in 2…100000, got 10000000"),  # noqa: E501
        ("solver", {"max_periods": 10**400}, "solver.max_periods", "an integer of about 401 digits"),  # noqa: E501
        ("solver", {"steps_per_period": 100_000}, "solver.steps_per_period", "in 4…65536"),
        ("solver", {"coarse_steps": 10**6}, "solver.coarse_steps", "in 4…65536"),
        ("solver", {"window": 50_000, "max_periods": 60_000}, "solver.window", "in 1…10000"),
        ("solver", {"periodicity_tol": float("nan")}, "solver.periodicity_tol", "finite, got nan"),
        ("solver", {"max_periods": 100_000, "steps_per_period": 65_536}, "solver", "max_periods × steps_per_period must be <= 1e+09"),  # noqa: E501
    ],
)  # fmt: skip
def test_blocks_refuse_huge_and_out_of_range_values_naming_the_field(block, values, path, text):
    d = _base(**{})
    d[block] = values
    with pytest.raises(StudyError) as info:
        parse_study(d)
    assert any(p == path and text in m for p, m in info.value.problems), info.value.problems


def test_huge_integers_from_json_and_yaml_are_refused_naming_the_field() -> None:
    long = "1" + "0" * 5000  # past Python's int-from-text limit
    json_text = (
        f'{{"name": "x", "model": {{"modes": {long}}}, "grid": {{"gamma_r": [1, {long}], '
        '"gap": 0.1, "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0}}'
    )
    yaml_text = f"name: x\nmodel: {{modes: {long}}}\ngrid: {{gamma_r: [1, {long}], gap: 0.1, " \
        "theta: 0.3, sigma: 0.05, gamma_s: 1.0}\n"  # fmt: skip
    for text, fmt in ((json_text, "json"), (yaml_text, "yaml")):
        with pytest.raises(StudyError) as info:
            parse_study(parse_study_text(text, fmt))
        got = dict(info.value.problems)
        assert "an integer of 5,001 digits" in got["model.modes"], fmt
        assert "got an integer of 5,001 digits; allowed range" in got["grid.gamma_r"], fmt


def test_a_physical_grid_is_refused_where_its_model_parameters_leave_their_range() -> None:
    d = {
        "name": "p",
        "physical": {"length_m": 0.15, "width_m": 0.01, "thickness_m": 0.0025,
                     "density_kg_m3": 1250.0, "youngs_modulus_pa": 4.583e7,
                     "outer_mass_kg": 0.01667, "spring_n_m": 350.0, "damping_ratio": 0.03,
                     "gap_m": 0.001},
        "grid": {"base_amplitude_m": [0.00025, 0.001], "frequency_hz": [12.0, 1e7]},
    }  # fmt: skip
    with pytest.raises(StudyError) as info:
        parse_study(d)
    ((path, msg),) = info.value.problems
    assert path == "physical"
    assert msg.startswith("at ") and "frequency_hz=1e+07" in msg
    assert "the model's gamma_r must be <= 1000, got 433624.3" in msg
    d["grid"]["frequency_hz"] = [12.0, 42.0]
    assert parse_study(d).size == 4


def test_range_values_must_stay_distinct_at_twelve_digits() -> None:
    d = _base()
    d["grid"]["gamma_r"] = {"start": 1.0, "stop": 1.0 + 1e-12, "num": 3}
    with pytest.raises(StudyError, match="values must be distinct"):
        parse_study(d)
    d["grid"]["gamma_r"] = {"start": 1.0, "stop": 1.0 + 1e-6, "num": 3}
    assert parse_study(d).axes()["gamma_r"].size == 3
