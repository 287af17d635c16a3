"""service.studies.variables: one registry for every axis and result variable."""

from __future__ import annotations

import numpy as np

from service.studies.schema import Grid
from service.studies.variables import (
    AXES,
    MISSING_INT,
    MODEL_AXES,
    PHYSICAL_AXES,
    VARIABLES,
    axis_symbol,
    default_x,
    result_values,
    stop_coordinate,
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
    assert axis_symbol("gamma_r") == "γ_r" and axis_symbol("gap_m") == "gap"
    assert axis_symbol("initial") == "initial" and axis_symbol("nope") == "nope"
    assert default_x(["gap", "gamma_r"]) == "gamma_r"
    assert default_x(["length_m", "frequency_hz"]) == "frequency_hz"
    assert default_x(["gap"]) is None


def test_result_values_are_stored_alike_everywhere() -> None:
    failed = np.array([False, True, False])
    period, attrs = result_values("response_period", [1, 3, MISSING_INT], failed)
    assert period.dtype == np.float64 and np.isnan(period[2]) and np.isnan(period[1])
    assert period[0] == 1 and attrs["units"] == "1" and attrs["long_name"]
    gamma, _ = result_values("transmittance_db", [-3.0, 7.0, 1.0], failed)
    assert np.isnan(gamma[1]) and gamma[0] == -3.0  # masked where the point failed
    lin, _ = result_values("transmittance_linear_db", [-3.0, 7.0, 1.0], failed)
    assert lin[1] == 7.0  # a property of the cell: kept at failed points
    codes, flags = result_values("outcome", [0, 4, 2])
    assert codes.dtype == np.int8 and flags["flag_meanings"].split() == list(OUTCOMES)
    name, values, stop_attrs = stop_coordinate()
    assert name == "stop" and values.tolist() == [1, 2] and stop_attrs["long_name"]
