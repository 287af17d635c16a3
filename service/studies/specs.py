"""The blocks of a study file, derived from the worker's types: one place per parameter.

``model:`` is :class:`worker.model.CellParams` without its grid axes, ``solver:`` is
:class:`worker.simulate.SolverSettings`, ``physical:`` is :class:`worker.physical.PhysicalCell`
and ``grid:`` has one axis per varying parameter of either. Each field's type, default,
allowed values and description are read from the dataclass (its field metadata, see
:mod:`worker.checks`, and its numpy-style docstring), and values are checked by the worker's own
:func:`worker.checks.check_field`, so a study file and a direct call give the same message. A
new parameter is added to the worker's type and appears here.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from functools import partial
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    Field,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)

from service.studies.grid import Axis, Integer, Real, StrictModel, axis_values
from service.studies.variables import AXES, AXIS_PARAMETER, MODEL_AXES, PHYSICAL_AXES
from worker.checks import bounds_text, check_field, out_of_bounds
from worker.model import CellParams
from worker.physical import FREQUENCY_HZ, PhysicalCell
from worker.simulate import SolverSettings

__all__ = [
    "AXIS_BOUNDS",
    "Grid",
    "ModelSpec",
    "PhysicalSpec",
    "SolverSpec",
    "field_docs",
    "spec_model",
]


# --------------------------------------------------------------------------- from a dataclass


def field_docs(cls: type) -> dict[str, str]:
    """Each parameter's description from a numpy-style ``Parameters`` docstring section."""
    doc = cls.__doc__ or ""
    match = re.search(r"Parameters\n\s*-+\n(.*?)(?:\n\s*\n\s*[A-Z][a-z]+\n\s*-+\n|\Z)", doc, re.S)
    if match is None:
        return {}
    out: dict[str, str] = {}
    names: list[str] = []
    text: list[str] = []
    indent = None

    def flush() -> None:
        for n in names:
            out[n] = " ".join(text).strip()

    for line in match.group(1).splitlines():
        if not line.strip():
            continue
        depth = len(line) - len(line.lstrip())
        if indent is None:
            indent = depth
        if depth == indent and " : " in line:
            flush()
            names = [n.strip() for n in line.split(" : ")[0].split(",")]
            text = []
        else:
            text.append(line.strip())
    flush()
    return out


def _schema_bounds(meta: Mapping[str, Any]) -> dict[str, Any]:
    """The bounds as JSON Schema keywords (for the OpenAPI document; checks are the worker's)."""
    keys = {"gt": "exclusiveMinimum", "ge": "minimum", "lt": "exclusiveMaximum", "le": "maximum"}
    return {keys[k]: meta[k] for k in keys if k in meta}


def _spec_field(f: dataclasses.Field[Any], doc: str) -> tuple[Any, Any]:
    """A dataclass field as a pydantic field: type, default, check and description."""
    meta = dict(f.metadata)
    if "choices" in meta:
        kind: Any = Literal[tuple(meta["choices"])]  # type: ignore[valid-type]
    elif meta.get("boolean"):
        kind = bool
    elif meta.get("integer"):
        kind = Integer
    else:
        kind = Real
    if not meta.get("choices") and not meta.get("boolean"):
        # The worker's check, so the message is the one a direct call gives.
        kind = Annotated[kind, AfterValidator(partial(check_field, f.name, meta=meta))]
    if meta.get("optional"):
        kind = kind | None
    default = None if f.default is dataclasses.MISSING else f.default
    return kind, Field(default, description=doc or None, json_schema_extra=_schema_bounds(meta))


def spec_model(
    name: str,
    cls: type,
    doc: str,
    names: tuple[str, ...] | None = None,
    *,
    base: type[StrictModel] = StrictModel,
    optional: bool = False,
) -> Any:
    """A study-file block (a pydantic model) with the fields ``names`` of dataclass ``cls``.

    ``optional``: every field may be left out (None), whatever the dataclass's default.
    """
    docs = field_docs(cls)
    by_name = {f.name: f for f in dataclasses.fields(cls)}
    fields = {}
    for n in by_name if names is None else names:
        kind, info = _spec_field(by_name[n], docs.get(n, ""))
        if optional:
            extra = info.json_schema_extra
            kind, info = (
                kind | None,
                Field(None, description=info.description, json_schema_extra=extra),
            )
        fields[n] = (kind, info)
    return create_model(name, __base__=base, __doc__=doc, **fields)


# --------------------------------------------------------------------------- the blocks

ModelSpec = spec_model(
    "ModelSpec",
    CellParams,
    "The cell model: coupling, number of modes, damping (docs/model.md §3).",
    # CellParams without its grid axes, and ξ (the default for every point unless the grid
    # varies it)
    tuple(
        f.name for f in dataclasses.fields(CellParams) if f.name not in MODEL_AXES or f.name == "xi"
    ),  # noqa: E501
)


class _SolverBase(StrictModel):
    @model_validator(mode="after")
    def _check(self) -> Any:
        self.settings()  # cross-field rules (window < max_periods) are SolverSettings' own
        return self

    def settings(self) -> SolverSettings:
        """The worker's solver settings."""
        return SolverSettings(**self.model_dump())


SolverSpec = spec_model(
    "SolverSpec",
    SolverSettings,
    "How every point is integrated and how it ends (worker.simulate.SolverSettings).",
    base=_SolverBase,
)

# Every PhysicalCell field, optional: a grid axis may give it instead.
PhysicalSpec = spec_model(
    "PhysicalSpec",
    PhysicalCell,
    "A cell in SI units (worker.physical.PhysicalCell); grid axes override fields.",
    optional=True,
)


# --------------------------------------------------------------------------- the grid


def _axis_bounds() -> dict[str, dict[str, Any]]:
    cell = {f.name: dict(f.metadata) for f in dataclasses.fields(CellParams)}
    physical = {f.name: dict(f.metadata) for f in dataclasses.fields(PhysicalCell)}
    out: dict[str, dict[str, Any]] = {}
    for axis in MODEL_AXES:
        out[axis] = cell[AXIS_PARAMETER.get(axis, axis)]
    for axis in PHYSICAL_AXES:
        out[axis] = FREQUENCY_HZ if axis == "frequency_hz" else physical[axis]
    return {k: {b: v[b] for b in ("gt", "ge", "lt", "le") if b in v} for k, v in out.items()}


#: Every grid axis's allowed values, from the parameter it sets.
AXIS_BOUNDS: dict[str, dict[str, Any]] = _axis_bounds()


class _GridBase(StrictModel):
    @field_validator("*", mode="after")
    @classmethod
    def _domain(cls, value: Any, info: ValidationInfo) -> Any:
        if value is None:
            return value
        name = info.field_name
        assert name is not None
        values = axis_values(value)
        if values.size == 0:
            raise ValueError("must not be empty")
        bad = out_of_bounds(values, AXIS_BOUNDS[name])
        if np.any(bad):
            i = int(np.argmax(bad))
            where = f" (value {i})" if values.size > 1 else ""
            raise ValueError(f"must be {bounds_text(AXIS_BOUNDS[name])}, got {values[i]:g}{where}")
        if np.unique(values).size != values.size:
            raise ValueError("values must be distinct")
        return value

    def given(self) -> dict[str, Any]:
        """The axes that are set, by name."""
        names = type(self).model_fields
        return {k: getattr(self, k) for k in names if getattr(self, k) is not None}


def _axis_doc(axis: str) -> str:
    info = AXES[axis]  # the one registry of axes: long name and units
    return info.long_name if info.units == "1" else f"{info.long_name} ({info.units})"


Grid = create_model(
    "Grid",
    __base__=_GridBase,
    __doc__="Every axis a study may vary; which ones are allowed depends on the kind of study.",
    **{
        axis: (
            Axis | None,
            Field(None, description=_axis_doc(axis),
                  json_schema_extra=_schema_bounds(AXIS_BOUNDS[axis])),
        )
        for axis in (*MODEL_AXES, *PHYSICAL_AXES)
    },
)  # fmt: skip
