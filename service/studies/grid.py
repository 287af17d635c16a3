"""Grid axes of a study file: numbers, ranges, lists and scalars, and their values.

An axis is a scalar, a list of numbers, or a range (``{start, stop, num}``, an inclusive
linspace; ``{start, stop, step}``; ``{start, stop, num, scale: log}``). :data:`Real` and
:data:`Integer` are the number types of every study-file field: YAML 1.1 reads ``1e-3`` (no
dot) as a string, so numeric strings are accepted; booleans never are.

An axis's size is known without building it (:func:`axis_size`): a range has at most
:data:`MAX_AXIS_VALUES` values, and the study's point limit is checked on sizes alone, so a
definition that asks for 10⁹ values is refused before any array exists.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    field_validator,
    model_validator,
)

from worker.checks import shown

__all__ = [
    "AXIS_TAGS",
    "MAX_AXIS_VALUES",
    "Axis",
    "Integer",
    "Range",
    "Real",
    "StrictModel",
    "axis_size",
    "axis_values",
    "number",
]

#: The most values one range may have (``num``, or what ``step`` gives). Far above any real
#: study axis (the shipped ones have at most 291), low enough to be built in about a second.
MAX_AXIS_VALUES = 1_000_000


# --------------------------------------------------------------------------- numbers


def number(value: Any) -> Any:
    """A study-file number as given; a boolean or a string refused (``"1"`` is text, not a
    number; the YAML reader reads ``1e-3`` as a number); whether it is finite is left to the
    caller."""
    if isinstance(value, bool):
        raise ValueError(f"must be a number, got {value!r}")
    if isinstance(value, str):
        raise ValueError(f"must be a number, got the text {shown(value)} (write it unquoted)")
    return value


def _real(value: Any) -> Any:
    value = number(value)
    if isinstance(value, (int, float)) and not math.isfinite(_as_float(value)):
        raise ValueError(f"must be finite, got {shown(value)}")
    return value


def _as_float(value: float) -> float:
    try:
        return float(value)
    except OverflowError:  # an integer beyond the float range (10**400)
        return math.inf


Real = Annotated[float, BeforeValidator(_real)]


def _integer(value: Any) -> Any:
    if isinstance(value, bool):
        raise ValueError(f"must be an integer, got {value!r}")
    if isinstance(value, str):
        raise ValueError(f"must be an integer, got the text {shown(value)} (write it unquoted)")
    if isinstance(value, float) and not math.isfinite(value):
        # inf, nan, or an integer literal too long to read (files.HugeInteger)
        raise ValueError(f"must be an integer, got {shown(value)}")
    return value


Integer = Annotated[int, BeforeValidator(_integer)]


class StrictModel(BaseModel):
    """A block of a study file: unknown keys are errors, values are frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# --------------------------------------------------------------------------- axes


def _count(start: float, stop: float, step: float) -> int:
    """How many values ``{start, stop, step}`` has, without building them; a count beyond
    :data:`MAX_AXIS_VALUES` (or one a float cannot hold: a step of 1e-320) is returned as
    ``MAX_AXIS_VALUES + 1``."""
    # Include ``stop`` when it is reached up to rounding (0.2 + 29·0.2 == 6.0).
    n = (stop - start) / step * (1 + 1e-12) + 1e-9
    if not math.isfinite(n) or n >= MAX_AXIS_VALUES:
        return MAX_AXIS_VALUES + 1
    return math.floor(n) + 1


class Range(StrictModel):
    """``{start, stop, num}`` (inclusive linspace), ``{start, stop, step}`` or log-spaced.

    ``num`` is at most :data:`MAX_AXIS_VALUES`, and so is the count a ``step`` gives.
    """

    start: Real
    stop: Real
    num: Integer | None = Field(None, json_schema_extra={"minimum": 1, "maximum": MAX_AXIS_VALUES})
    step: Real | None = Field(None, json_schema_extra={"exclusiveMinimum": 0})
    scale: Literal["linear", "log"] = "linear"

    @field_validator("num")
    @classmethod
    def _num(cls, num: int | None) -> int | None:
        if num is not None and not 1 <= num <= MAX_AXIS_VALUES:
            got = num if abs(num) < 10**20 else shown(num)
            raise ValueError(f"num must be an integer in 1…{MAX_AXIS_VALUES:,}, got {got}")
        return num

    @model_validator(mode="after")
    def _check(self) -> Range:
        if (self.num is None) == (self.step is None):
            raise ValueError("give exactly one of num and step")
        if self.step is not None:
            if self.scale == "log":
                raise ValueError("scale log needs num, not step")
            if self.step <= 0:
                raise ValueError(f"step must be > 0, got {self.step}")
            if self.stop < self.start:
                raise ValueError(
                    f"stop must be >= start with a step, got {self.stop} < {self.start}"
                )
            if _count(self.start, self.stop, self.step) > MAX_AXIS_VALUES:
                span = (self.stop - self.start) / self.step
                raise ValueError(
                    f"range has {span:.4g} values (from {self.start:g} to {self.stop:g} by "
                    f"{self.step:g}), more than {MAX_AXIS_VALUES:,}"
                )
        if self.scale == "log" and (self.start <= 0 or self.stop <= 0):
            raise ValueError(
                f"scale log needs start > 0 and stop > 0, got start={self.start}, stop={self.stop}"
            )
        return self

    @property
    def size(self) -> int:
        """How many values the range has (arithmetic: nothing is built)."""
        if self.num is not None:
            return self.num
        assert self.step is not None
        return _count(self.start, self.stop, self.step)

    @property
    def last(self) -> float:
        """The last value (``stop`` unless a step falls short of it)."""
        if self.step is not None:
            return self.start + self.step * (self.size - 1)
        return self.stop

    def values(self) -> np.ndarray:
        """The values of the range, float64."""
        if self.step is not None:
            count = _count(self.start, self.stop, self.step)
            raw = self.start + self.step * np.arange(count, dtype=np.float64)
        else:
            assert self.num is not None
            if self.scale == "log":
                return np.geomspace(self.start, self.stop, self.num)
            raw = np.linspace(self.start, self.stop, self.num)
        # Round away the last-bit noise of decimal steps (0.2·3 = 0.6000000000000001), so that
        # coordinates read as written and ``sel(gamma_r=0.6)`` works.
        return np.array([float(f"{v:.12g}") for v in raw], dtype=np.float64)


def _axis_kind(value: Any) -> str:
    if isinstance(value, (Mapping, Range)):
        return "range"
    if isinstance(value, (list, tuple)):
        return "list"
    return "scalar"


#: Tags of the shapes an axis may take (validation errors name them; they are not file paths).
AXIS_TAGS = ("range", "list", "scalar")

Axis = Annotated[
    Annotated[Range, Tag("range")]
    | Annotated[list[Real], Tag("list")]
    | Annotated[Real, Tag("scalar")],
    Discriminator(_axis_kind),
]


def axis_size(axis: Range | list[float] | float) -> int:
    """How many values an axis has, without building them."""
    if isinstance(axis, Range):
        return axis.size
    if isinstance(axis, list):
        return len(axis)
    return 1


def axis_values(axis: Range | list[float] | float) -> np.ndarray:
    """An axis's values as a 1-d float64 array."""
    if isinstance(axis, Range):
        return axis.values()
    if isinstance(axis, list):
        return np.asarray(axis, dtype=np.float64)
    return np.asarray([axis], dtype=np.float64)
