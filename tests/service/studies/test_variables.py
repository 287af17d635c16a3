"""service.studies.variables: one registry for every axis and result variable."""

from __future__ import annotations

from service.studies.schema import Grid
from service.studies.variables import (
    AXES,
    MODEL_AXES,
    PHYSICAL_AXES,
    VARIABLES,
    axis_symbol,
    default_x,
)
from worker.solvers.settings import OUTCOMES


def test_every_grid_axis_has_units_and_a_long_name() -> None:
    assert set(Grid.model_fields) == set(MODEL_AXES) | set(PHYSICAL_AXES)
    for name in (*MODEL_AXES, *PHYSICAL_AXES, "stop"):
        assert AXES[name].units and AXES[name].long_name, name


def test_every_variable_has_units_a_long_name_and_a_known_kind() -> None:
    kinds = {"float", "int", "maskint", "bool", "str", "flag"}
    groups = {"", "transmittance", "effective_mass", "response", "contact"}
    for name, var in VARIABLES.items():
        assert var.units and var.long_name and var.kind in kinds and var.group in groups, name
    assert [n for n, v in VARIABLES.items() if v.kind == "flag"] == ["outcome"]
    assert "linear" in OUTCOMES


def test_symbols_and_the_default_x() -> None:
    assert axis_symbol("gamma_r") == "γ_r" and axis_symbol("length_m") == "length_m"
    assert default_x(["gap", "gamma_r"]) == "gamma_r"
    assert default_x(["length_m", "frequency_hz"]) == "frequency_hz"
    assert default_x(["gap"]) is None
