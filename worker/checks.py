"""Validation of numbers, one family for the whole worker: every error names the field, the
value and what is allowed (``theta must be > 0, got -1.0``).

Dataclass fields declare their range in their metadata (``gt``, ``ge``, ``lt``, ``le``,
``choices``, ``integer``); :func:`check_fields` applies it, so the types are the one place
where a parameter's allowed values are written (the study schema reads the same metadata).

A field may give both ``gt`` and ``ge`` (or ``lt`` and ``le``): the looser one is where the
model is defined (θ > 0), the tighter one the range this project supports and tests
(θ >= 1e-6). A message names the loosest bound the value breaks, and a field bounded on both
sides adds its allowed range (``theta must be <= 10000, got 1e+308; allowed range [1e-06,
10000]``). Huge integers (beyond a float) are refused like any value out of range and shown by
their size, never in full.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from typing import Any

import numpy as np

__all__ = [
    "bounds_text",
    "shown",
    "check_field",
    "check_fields",
    "finite",
    "integer",
    "nonnegative",
    "out_of_bounds",
    "positive",
    "violation",
]


def shown(value: Any) -> str:
    """``value`` as messages print it: numbers as floats, integers too large for a float by
    their size (a 400-digit number in full helps nobody), other values by ``repr``."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        try:
            return repr(float(value))
        except OverflowError:
            # bit_length, not str(): str() of a huge int is slow and refused past 4300 digits
            digits = int(int(value).bit_length() * math.log10(2)) + 1
            return f"{'a negative' if value < 0 else 'an'} integer of about {digits} digits"
    if type(value) is not float and isinstance(value, float):
        return repr(value)  # a float subclass that knows how to show itself
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return repr(float(value))
    text = repr(value)
    return text if len(text) <= 80 else f"{text[:60]}… ({len(text)} characters)"


def _float(name: str, value: Any) -> float:
    """``value`` as a float, possibly non-finite; a huge integer becomes ±inf."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {shown(value)}")
    try:
        return float(value)
    except OverflowError:  # an int beyond the float range: as out of range as inf
        return -math.inf if value < 0 else math.inf


def finite(name: str, value: Any) -> float:
    """``value`` as a finite float (bool refused: a True length is almost surely a bug)."""
    v = _float(name, value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {shown(value)}")
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
        raise ValueError(f"{name} must be an integer in {lo}…{hi}, got {shown(value)}")
    if not lo <= int(value) <= hi:
        got = value if abs(int(value)) < 10**20 else shown(value)
        raise ValueError(f"{name} must be an integer in {lo}…{hi}, got {got}")
    return int(value)


def _tightest(meta: dict[str, Any], keys: tuple[str, str], pick: Any) -> str | None:
    # Of ``gt``/``ge`` (or ``lt``/``le``) the one that allows less; ties go to the strict one.
    given = [k for k in keys if k in meta]
    if not given:
        return None
    best = pick(meta[k] for k in given)
    return next(k for k in given if meta[k] == best)


def bounds_text(meta: dict[str, Any]) -> str:
    """What a field's bounds allow, as error messages say it: ``> 0``, ``in [4, 1e+07]``."""
    lo = _tightest(meta, ("gt", "ge"), max)
    hi = _tightest(meta, ("lt", "le"), min)
    sign = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    if lo and not hi:
        return f"{sign[lo]} {meta[lo]:g}"
    if hi and not lo:
        return f"{sign[hi]} {meta[hi]:g}"
    if not lo and not hi:
        return "finite"
    assert lo is not None and hi is not None
    left = f"({meta[lo]:g}" if lo == "gt" else f"[{meta[lo]:g}"
    right = f"{meta[hi]:g})" if hi == "lt" else f"{meta[hi]:g}]"
    return f"in {left}, {right}"


def violation(name: str, value: Any, meta: dict[str, Any]) -> str | None:
    """Why ``value`` is outside a field's bounds (``None`` if it is inside): the field, the
    bound it breaks, the value, and for a field bounded on both sides the allowed range
    (``theta must be > 0, got 0.0; allowed range [1e-06, 10000]``)."""
    v = _float(name, value)
    if not out_of_bounds(v, meta):
        return None
    two_sided = any(k in meta for k in ("gt", "ge")) and any(k in meta for k in ("lt", "le"))
    suffix = f"; allowed range {bounds_text(meta).removeprefix('in ')}" if two_sided else ""
    if not math.isfinite(v):
        return f"{name} must be finite, got {shown(value)}{suffix}"
    # The loosest broken bound first: θ = 0 breaks "> 0" (where the model is defined) before
    # ">= 1e-6" (the supported range), and the message says the former.
    sign = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    lower = sorted((k for k in ("gt", "ge") if k in meta), key=lambda k: meta[k])
    upper = sorted((k for k in ("lt", "le") if k in meta), key=lambda k: -meta[k])
    for k in (*lower, *upper):
        if out_of_bounds(v, {k: meta[k]}):
            return f"{name} must be {sign[k]} {meta[k]:g}, got {shown(value)}{suffix}"
    return None  # not reached: out of bounds means one bound is broken


def out_of_bounds(values: Any, meta: dict[str, Any]) -> Any:
    """Where ``values`` (a number or a numpy array) violate a field's bounds (True = bad)."""
    v: Any
    if type(values) is float:
        # one number stays a Python float (every point's parameters pass here; numpy's scalar
        # round trip cost ~10 µs a field); the tests below are the same for both
        v, bad = values, not math.isfinite(values)
    else:
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
    problem = violation(name, value, meta)
    if problem is not None:
        raise ValueError(problem)
    return float(value)


def check_fields(obj: Any) -> None:
    """Check and normalise every field of a frozen dataclass that declares metadata."""
    for name, meta in _declared(type(obj)):
        object.__setattr__(obj, name, check_field(name, getattr(obj, name), meta))


@functools.cache
def _declared(cls: type) -> tuple[tuple[str, dict[str, Any]], ...]:
    # per class, once: the fields with metadata (every point builds its parameters)
    return tuple((f.name, dict(f.metadata)) for f in dataclasses.fields(cls) if f.metadata)
