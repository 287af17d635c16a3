"""Validation of numbers, one family for the whole worker: every error names the field, the
value and what is allowed (``theta must be > 0, got -1.0``).

Dataclass fields declare their range in their metadata (``gt``, ``ge``, ``lt``, ``le``,
``choices``, ``integer``); :func:`check_fields` applies it, so the types are the one place
where a parameter's allowed values are written (the study schema reads the same metadata).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

import numpy as np

__all__ = [
    "bounds_text",
    "check_field",
    "check_fields",
    "finite",
    "integer",
    "nonnegative",
    "out_of_bounds",
    "positive",
]


def finite(name: str, value: Any) -> float:
    """``value`` as a finite float (bool refused: a True length is almost surely a bug)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v!r}")
    return v


def positive(name: str, value: Any) -> float:
    """``value`` as a finite float > 0."""
    v = finite(name, value)
    if v <= 0.0:
        raise ValueError(f"{name} must be > 0, got {v!r}")
    return v


def nonnegative(name: str, value: Any) -> float:
    """``value`` as a finite float >= 0."""
    v = finite(name, value)
    if v < 0.0:
        raise ValueError(f"{name} must be >= 0, got {v!r}")
    return v


def integer(name: str, value: Any, lo: int, hi: int) -> int:
    """``value`` as an int in ``lo…hi``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer in {lo}…{hi}, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name} must be an integer in {lo}…{hi}, got {value}")
    return int(value)


def bounds_text(meta: dict[str, Any]) -> str:
    """What a field's bounds allow, as error messages say it: ``> 0``, ``in [4, 1e+07]``."""
    lo = [k for k in ("gt", "ge") if k in meta]
    hi = [k for k in ("lt", "le") if k in meta]
    sign = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    if lo and not hi:
        return f"{sign[lo[0]]} {meta[lo[0]]:g}"
    if hi and not lo:
        return f"{sign[hi[0]]} {meta[hi[0]]:g}"
    left = f"({meta['gt']:g}" if "gt" in meta else (f"[{meta['ge']:g}" if "ge" in meta else "(-inf")
    right = f"{meta['lt']:g})" if "lt" in meta else (f"{meta['le']:g}]" if "le" in meta else "inf)")
    return f"in {left}, {right}"


def out_of_bounds(values: Any, meta: dict[str, Any]) -> Any:
    """Where ``values`` (a number or a numpy array) violate a field's bounds (True = bad)."""
    v = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(v)
    if "gt" in meta:
        bad |= v <= meta["gt"]
    if "ge" in meta:
        bad |= v < meta["ge"]
    if "lt" in meta:
        bad |= v >= meta["lt"]
    if "le" in meta:
        bad |= v > meta["le"]
    return bad


def check_field(name: str, value: Any, meta: dict[str, Any]) -> Any:
    """``value`` checked against a field's metadata; returns it normalised."""
    if value is None and meta.get("optional"):
        return None
    if "choices" in meta:
        if value not in meta["choices"]:
            raise ValueError(f"{name} must be one of {', '.join(meta['choices'])}, got {value!r}")
        return value
    if meta.get("boolean"):
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if meta.get("integer"):
        return integer(name, value, meta["ge"], meta["le"])
    v = finite(name, value)
    if out_of_bounds(v, meta):
        raise ValueError(f"{name} must be {bounds_text(meta)}, got {v!r}")
    return v


def check_fields(obj: Any) -> None:
    """Check and normalise every field of a frozen dataclass that declares metadata."""
    for f in dataclasses.fields(obj):
        if f.metadata:
            value = check_field(f.name, getattr(obj, f.name), dict(f.metadata))
            object.__setattr__(obj, f.name, value)
