"""The worker's one validation family: field metadata to checks and messages."""

import numpy as np
import pytest

from worker.checks import bounds_text, check_field, out_of_bounds


@pytest.mark.parametrize(
    ("meta", "text"),
    [
        ({"gt": 0.0}, "> 0"),
        ({"ge": 0.0}, ">= 0"),
        ({"lt": 1.0}, "< 1"),
        ({"gt": 0.0, "lt": 100.0}, "in (0, 100)"),
        ({"ge": 4, "le": 10**7}, "in [4, 1e+07]"),
    ],
)
def test_bounds_text(meta, text):
    assert bounds_text(meta) == text


def test_out_of_bounds_marks_each_violation_and_non_finite_values():
    meta = {"gt": 0.0, "le": 2.0}
    v = np.array([-1.0, 0.0, 1e-300, 2.0, 2.0000001, np.nan, np.inf])
    assert out_of_bounds(v, meta).tolist() == [True, True, False, False, True, True, True]
    assert not out_of_bounds(1.0, meta)


@pytest.mark.parametrize(
    ("value", "meta", "message"),
    [
        (-1, {"gt": 0.0}, "x must be > 0, got -1.0"),
        (0.5, {"ge": 1.0, "lt": 2.0}, r"x must be >= 1, got 0.5; allowed range \[1, 2\)"),
        ("a", {"gt": 0.0}, "x must be a real number, got 'a'"),
        (float("nan"), {"ge": 0.0}, "x must be finite, got nan"),
        (True, {"gt": 0.0}, "x must be a real number, got True"),
        (2.5, {"integer": True, "ge": 1, "le": 5}, r"x must be an integer in 1…5, got 2.5"),
        ("yes", {"boolean": True}, "x must be true or false, got 'yes'"),
        ("c", {"choices": ("a", "b")}, "x must be one of a, b, got 'c'"),
        (None, {"gt": 0.0}, "x must be a real number, got None"),
    ],
)
def test_check_field_names_the_field_the_value_and_what_is_allowed(value, meta, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        check_field("x", value, meta)


def test_check_field_normalises_and_lets_optional_none_through():
    assert type(check_field("x", np.float32(0.5), {"gt": 0.0})) is float
    assert check_field("x", None, {"gt": 0.0, "optional": True}) is None
    assert check_field("x", 3, {"integer": True, "ge": 1, "le": 5}) == 3


# --------------------------------------------------------------------------- every bound

import dataclasses  # noqa: E402
import math  # noqa: E402

from worker.checks import shown, violation  # noqa: E402
from worker.model import CellParams  # noqa: E402
from worker.physical import FREQUENCY_HZ, PhysicalCell  # noqa: E402


def _bounded(cls: type) -> list[tuple[str, dict]]:
    return [
        (f.name, dict(f.metadata))
        for f in dataclasses.fields(cls)
        if not f.metadata.get("integer") and any(k in f.metadata for k in ("le", "lt"))
    ]


CELL_BOUNDED = _bounded(CellParams)
PHYSICAL_BOUNDED = _bounded(PhysicalCell)


def test_every_real_model_and_physical_field_is_bounded_on_both_sides_with_a_reason():
    cell = {f.name for f in dataclasses.fields(CellParams) if f.type in ("float", "float | None")}
    phys = {f.name for f in dataclasses.fields(PhysicalCell)}
    assert {n for n, _ in CELL_BOUNDED} == cell
    assert {n for n, _ in PHYSICAL_BOUNDED} == phys
    for _, meta in [*CELL_BOUNDED, *PHYSICAL_BOUNDED, ("frequency_hz", FREQUENCY_HZ)]:
        assert any(k in meta for k in ("gt", "ge")) and "le" in meta
        assert len(meta["why"]) > 20


def _outside(meta: dict) -> dict[str, float]:
    lo = max(meta[k] for k in ("gt", "ge") if k in meta)
    return {
        "below": lo - 1.0 if lo == 0 else lo / 10,
        "above": meta["le"] * 10,
        "nan": math.nan,
        "inf": math.inf,
        "-inf": -math.inf,
        "huge int": 10**400,
    }


def _cell_kwargs(**kw: float) -> dict:
    return {"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, "gamma_r": 1.0, **kw}


@pytest.mark.parametrize(("name", "meta"), CELL_BOUNDED, ids=[n for n, _ in CELL_BOUNDED])
def test_cell_params_refuse_each_bound_naming_field_value_and_range(name, meta):
    rng = bounds_text(meta).removeprefix("in ")
    for label, bad in _outside(meta).items():
        with pytest.raises(ValueError) as info:
            CellParams(**_cell_kwargs(**{name: bad}))
        text = str(info.value)
        assert text.startswith(f"{name} must be "), (label, text)
        assert text.endswith(f"; allowed range {rng}"), (label, text)
        assert shown(bad) in text, (label, text)
    # the ends of the range are accepted
    lo = max(meta[k] for k in ("gt", "ge") if k in meta)
    for good in (lo if "ge" in meta and meta["ge"] == lo else lo * 2 + 1e-300, meta["le"]):
        assert getattr(CellParams(**_cell_kwargs(**{name: good})), name) == good


def _physical(**kw: float) -> PhysicalCell:
    base = dict(length_m=0.15, width_m=0.01, thickness_m=0.0025, density_kg_m3=1250.0,
                youngs_modulus_pa=4.583e7, outer_mass_kg=0.01667, spring_n_m=350.0,
                gap_m=1e-3, damping_ratio=0.03, base_amplitude_m=1e-3)  # fmt: skip
    if "base_acceleration_m_s2" in kw:
        base["base_amplitude_m"] = None
    return PhysicalCell(**{**base, **kw})


@pytest.mark.parametrize(("name", "meta"), PHYSICAL_BOUNDED, ids=[n for n, _ in PHYSICAL_BOUNDED])
def test_physical_cell_refuses_each_bound_naming_field_value_and_range(name, meta):
    rng = bounds_text(meta).removeprefix("in ")
    for label, bad in _outside(meta).items():
        with pytest.raises(ValueError) as info:
            _physical(**{name: bad})
        text = str(info.value)
        assert text.startswith(f"{name} must be ") and text.endswith(f"range {rng}"), text
        assert shown(bad) in text, (label, text)
    assert getattr(_physical(**{name: meta["le"]}), name) == meta["le"]


def test_frequency_is_bounded_with_its_range():
    cell = _physical()
    for bad in (0.0, 1e-7, 2e9, math.nan):
        with pytest.raises(ValueError, match=r"^frequency_hz must be .*allowed range \[1e-06"):
            cell.to_model(bad)
    assert cell.to_model(1e9)["gamma_r"] > 0


def test_messages_say_the_loosest_broken_bound_then_the_range():
    meta = {"gt": 0.0, "ge": 1e-6, "le": 1e4}
    assert violation("t", 0.0, meta) == "t must be > 0, got 0.0; allowed range [1e-06, 10000]"
    assert (
        violation("t", 1e-9, meta) == "t must be >= 1e-06, got 1e-09; allowed range [1e-06, 10000]"
    )  # noqa: E501
    assert (
        violation("t", 1e308, meta)
        == "t must be <= 10000, got 1e+308; allowed range [1e-06, 10000]"
    )  # noqa: E501
    assert violation("t", 1.0, meta) is None
    assert bounds_text(meta) == "in [1e-06, 10000]"


def test_huge_integers_are_out_of_range_and_shown_by_their_size():
    assert shown(10**400) == "an integer of about 401 digits"
    assert shown(-(10**5000)) == "a negative integer of about 5001 digits"
    assert shown(-1) == "-1.0" and shown(2.5) == "2.5"
    with pytest.raises(ValueError, match=r"^x must be finite, got an integer of about 401 digits$"):
        check_field("x", 10**400, {"gt": 0.0})
    with pytest.raises(ValueError, match=r"^n must be an integer in 1…5, got an integer of about"):
        check_field("n", 10**400, {"integer": True, "ge": 1, "le": 5})
    assert (
        len(str(pytest.raises(ValueError, check_field, "x", "y" * 10_000, {"gt": 0}).value)) < 200
    )
