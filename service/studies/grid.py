"""Grid axes of a study file: numbers, ranges, lists and scalars, and their values.

An axis is a scalar, a list of numbers, or a range (``{start, stop, num}``, an inclusive
linspace; ``{start, stop, step}``; ``{start, stop, num, scale: log}``). :data:`Real` and
:data:`Integer` are the number types of every study-file field: YAML 1.1 reads ``1e-3`` (no
dot) as a string, so numeric strings are accepted; booleans never are.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Discriminator, Tag, model_validator

__all__ = [
    "AXIS_TAGS",
    "Axis",
    "Integer",
    "Range",
    "Real",
    "StrictModel",
    "axis_values",
]


# --------------------------------------------------------------------------- numbers


def _real(value: Any) -> Any:
    # YAML 1.1 reads ``1e-3`` (no dot) as a string; accept numeric strings, refuse booleans.
    if isinstance(value, bool):
        raise ValueError(f"must be a number, got {value!r}")
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ValueError(f"must be a number, got {value!r}") from None
    if isinstance(value, (int, float)) and not math.isfinite(float(value)):
        raise ValueError(f"must be finite, got {value!r}")
    return value


Real = Annotated[float, BeforeValidator(_real)]


def _integer(value: Any) -> Any:
    if isinstance(value, bool):
        raise ValueError(f"must be an integer, got {value!r}")
    return value


Integer = Annotated[int, BeforeValidator(_integer)]


class StrictModel(BaseModel):
    """A block of a study file: unknown keys are errors, values are frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# --------------------------------------------------------------------------- axes


def _count(start: float, stop: float, step: float) -> int:
    # Include ``stop`` when it is reached up to rounding (0.2 + 29·0.2 == 6.0).
    return math.floor((stop - start) / step * (1 + 1e-12) + 1e-9) + 1


class Range(StrictModel):
    """``{start, stop, num}`` (inclusive linspace), ``{start, stop, step}`` or log-spaced."""

    start: Real
    stop: Real
    num: Integer | None = None
    step: Real | None = None
    scale: Literal["linear", "log"] = "linear"

    @model_validator(mode="after")
    def _check(self) -> Range:
        if (self.num is None) == (self.step is None):
            raise ValueError("give exactly one of num and step")
        if self.num is not None and self.num < 1:
            raise ValueError(f"num must be >= 1, got {self.num}")
        if self.step is not None:
            if self.scale == "log":
                raise ValueError("scale log needs num, not step")
            if self.step <= 0:
                raise ValueError(f"step must be > 0, got {self.step}")
            if self.stop < self.start:
                raise ValueError(
                    f"stop must be >= start with a step, got {self.stop} < {self.start}"
                )
            count = _count(self.start, self.stop, self.step)
            if count > 100_000_000:
                raise ValueError(f"range has {count} values, more than 100,000,000")
        if self.scale == "log" and (self.start <= 0 or self.stop <= 0):
            raise ValueError(
                f"scale log needs start > 0 and stop > 0, got start={self.start}, stop={self.stop}"
            )
        return self

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


def axis_values(axis: Range | list[float] | float) -> np.ndarray:
    """An axis's values as a 1-d float64 array."""
    if isinstance(axis, Range):
        return axis.values()
    if isinstance(axis, list):
        return np.asarray(axis, dtype=np.float64)
    return np.asarray([axis], dtype=np.float64)
