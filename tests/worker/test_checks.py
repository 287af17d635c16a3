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
        (0.5, {"ge": 1.0, "lt": 2.0}, r"x must be in \[1, 2\), got 0.5"),
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
