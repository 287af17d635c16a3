"""The study blocks are the worker's types: one place per parameter, the same messages."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest
from pydantic import ValidationError

from service.studies.schema import StudyError, parse_study
from service.studies.specs import (
    AXIS_BOUNDS,
    PER_FREQUENCY_FIELDS,
    Grid,
    ModelSpec,
    PhysicalSpec,
    SolverSpec,
    field_docs,
    spec_model,
)
from service.studies.variables import MODEL_AXES, PHYSICAL_AXES
from worker.model import CellParams
from worker.physical import PhysicalCell
from worker.simulate import SolverSettings


def _base(**blocks: Any) -> dict[str, Any]:
    grid = {"gamma_r": [0.5, 1.0], "gap": 0.1, "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0}
    return {"name": "t", "grid": grid, **blocks}


def test_every_worker_parameter_is_in_exactly_one_block_or_the_grid() -> None:
    cell = {f.name for f in dataclasses.fields(CellParams)}
    # xi is both: the model's default and an axis a grid may vary instead; a chain's fields
    # (cells, and its per-cell gaps and sigmas) are not CellParams'
    chain = {"cells", "gaps", "sigmas"}
    both = {"gap", "restitution"}  # axes that set both stops' parameter
    assert (set(ModelSpec.model_fields) - chain) | (set(MODEL_AXES) - both - {"cells"}) == cell
    assert set(ModelSpec.model_fields) & set(MODEL_AXES) == {"xi", "cells"}
    assert set(SolverSpec.model_fields) == {f.name for f in dataclasses.fields(SolverSettings)}
    # PhysicalCell's fields, plus the per-frequency base amplitude (set point by point as
    # base_amplitude_m, so it is not a cell field)
    physical = {f.name for f in dataclasses.fields(PhysicalCell)}
    assert set(PhysicalSpec.model_fields) == physical | set(PER_FREQUENCY_FIELDS)
    assert not physical & set(PER_FREQUENCY_FIELDS)
    assert set(Grid.model_fields) == set(MODEL_AXES) | set(PHYSICAL_AXES)


def test_defaults_and_bounds_are_the_workers() -> None:
    for spec, cls in ((ModelSpec, CellParams), (SolverSpec, SolverSettings)):
        for f in dataclasses.fields(cls):
            if f.name in spec.model_fields:
                assert spec.model_fields[f.name].default == f.default, f.name
    for f in dataclasses.fields(CellParams):
        if f.name in AXIS_BOUNDS:
            assert AXIS_BOUNDS[f.name].items() <= dict(f.metadata).items(), f.name
    assert AXIS_BOUNDS["gap"] == AXIS_BOUNDS["g1"] == {"ge": 0.0, "le": 1e12}
    assert AXIS_BOUNDS["frequency_hz"] == {"gt": 0.0, "ge": 1e-6, "le": 1e9}


@pytest.mark.parametrize(
    ("block", "values", "worker"),
    [
        ("solver", {"stat_tol_db": 200}, lambda: SolverSettings(stat_tol_db=200)),
        ("model", {"xi": 11}, lambda: CellParams(1, 1, 1, 1, xi=11)),
        ("solver", {"periodicity_tol": 0.5}, lambda: SolverSettings(periodicity_tol=0.5)),
        ("solver", {"window": 30, "max_periods": 20},
         lambda: SolverSettings(window=30, max_periods=20)),
        ("model", {"modes": 31}, lambda: CellParams(1, 1, 1, 1, modes=31)),
        ("model", {"xi_b": -0.5}, lambda: CellParams(1, 1, 1, 1, xi_b=-0.5)),
    ],
)  # fmt: skip
def test_a_study_file_gives_the_message_a_direct_call_gives(block, values, worker) -> None:
    with pytest.raises(ValueError) as direct:
        worker()
    with pytest.raises(StudyError) as study:
        parse_study(_base(**{block: values}))
    assert [m for _, m in study.value.problems] == [str(direct.value)]


def test_the_openapi_schema_carries_the_bounds_and_the_docs() -> None:
    props = SolverSpec.model_json_schema()["properties"]
    assert props["max_periods"]["minimum"] == 2 and props["max_periods"]["maximum"] == 100_000
    assert props["stat_tol_db"]["exclusiveMinimum"] == 0.0
    assert "Period budget" in props["max_periods"]["description"]
    assert set(props["method"]["enum"]) == {"event", "exponential", "euler"}
    grid = Grid.model_json_schema()["properties"]
    assert "Hz" in grid["frequency_hz"]["description"]


def test_a_new_worker_field_appears_with_its_type_default_rule_and_doc() -> None:
    @dataclasses.dataclass(frozen=True)
    class Toy:
        """A toy.

        Parameters
        ----------
        rate : float
            How fast, > 0.
        count, other : int
            How many.

        Raises
        ------
        ValueError
        """

        rate: float = dataclasses.field(default=1.5, metadata={"gt": 0.0})
        count: int = dataclasses.field(default=3, metadata={"integer": True, "ge": 1, "le": 9})
        kind: str = dataclasses.field(default="a", metadata={"choices": ("a", "b")})

    assert field_docs(Toy) == {"rate": "How fast, > 0.", "count": "How many.", "other": "How many."}
    spec = spec_model("ToySpec", Toy, "Toy block.", ("rate", "count", "kind"))
    assert spec().model_dump() == {"rate": 1.5, "count": 3, "kind": "a"}
    assert spec(rate=2e-3).rate == 0.002
    for bad, text in [
        ({"rate": 0}, "rate must be > 0, got 0.0"),
        ({"count": 10}, "count must be an integer in 1…9, got 10"),
        ({"rate": "2e-3"}, "must be a number, got the text '2e-3'"),
        ({"count": "3"}, "must be a number, got the text '3'"),
        ({"kind": "c"}, "Input should be 'a' or 'b'"),
        ({"speed": 1}, "Extra inputs are not permitted"),
    ]:
        with pytest.raises(ValidationError, match=text):
            spec(**bad)


def test_the_schema_says_every_bound_and_why() -> None:
    from service.studies.grid import MAX_AXIS_VALUES, Range
    from service.studies.specs import STUDY_SOLVER_CAPS

    grid = Grid.model_json_schema()["properties"]
    gamma_r = grid["gamma_r"]
    assert gamma_r["exclusiveMinimum"] == 0.0 and gamma_r["minimum"] == 1e-6
    assert gamma_r["maximum"] == 1e3
    assert "Allowed: in [1e-06, 1000]" in gamma_r["description"]
    assert "frequency" in gamma_r["description"].split("Allowed:")[1]  # the why
    for axis in (*MODEL_AXES, *PHYSICAL_AXES):
        assert "maximum" in grid[axis] and "Allowed:" in grid[axis]["description"], axis
    model = ModelSpec.model_json_schema()["properties"]
    assert model["xi"]["maximum"] == 10.0 and "critical" in model["xi"]["description"]
    physical = PhysicalSpec.model_json_schema()["properties"]
    for name in physical:
        assert "Allowed:" in physical[name]["description"], name
    solver = SolverSpec.model_json_schema()["properties"]
    for name, cap in STUDY_SOLVER_CAPS.items():
        assert solver[name]["maximum"] == cap["le"], name
    num = Range.model_json_schema()["properties"]["num"]
    assert num["maximum"] == MAX_AXIS_VALUES and num["minimum"] == 1


def test_study_caps_are_tighter_than_the_workers_and_bound_one_points_work() -> None:
    from service.studies.specs import MAX_STEPS_PER_POINT, STUDY_SOLVER_CAPS

    worker = {f.name: f.metadata for f in dataclasses.fields(SolverSettings)}
    for name, cap in STUDY_SOLVER_CAPS.items():
        assert cap["le"] < worker[name]["le"], name
        # the worker still takes what a study may not
        SolverSettings(**{name: cap["le"] + 1, "max_periods": 10**6})
        with pytest.raises(StudyError, match=rf"{name} must be an integer in \d+…{cap['le']}"):
            parse_study(_base(solver={name: cap["le"] + 1}))
    caps = STUDY_SOLVER_CAPS
    assert caps["max_periods"]["le"] * 1024 <= MAX_STEPS_PER_POINT  # defaults stay in budget
    ok = {"max_periods": 10_000, "steps_per_period": 65_536}  # 6.6e8 steps
    assert parse_study(_base(solver=ok)).solver.max_periods == 10_000
