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
import math
import re
from collections.abc import Mapping
from functools import partial
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BeforeValidator,
    Field,
    ValidationError,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)

from service.studies.grid import (
    Axis,
    Integer,
    Range,
    Real,
    StrictModel,
    axis_values,
    number,
)
from service.studies.variables import AXES, AXIS_PARAMETER, MODEL_AXES, PHYSICAL_AXES
from worker.checks import bounds_text, check_field, out_of_bounds, shown, violation
from worker.model import CellParams
from worker.physical import BASE_AMPLITUDE_M, FREQUENCY_HZ, PhysicalCell
from worker.simulate import SolverSettings

__all__ = [
    "ADAPTIVE_TARGETS",
    "ADAPTIVE_VARIABLES",
    "AdaptiveSpec",
    "AXIS_BOUNDS",
    "DIRECTIONS",
    "INITIAL_KINDS",
    "MAX_RANDOM_INITIAL",
    "MAX_STEPS_PER_POINT",
    "PER_FREQUENCY_FIELDS",
    "STUDY_MAX_CELLS",
    "STUDY_SOLVER_CAPS",
    "AmplitudeTable",
    "Grid",
    "InitialSpec",
    "ModelSpec",
    "PhysicalSpec",
    "RandomInitial",
    "SolverSpec",
    "SweepSpec",
    "field_docs",
    "initial_labels",
    "initial_states",
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


def _described(doc: str, meta: Mapping[str, Any]) -> str | None:
    """A field's description with its allowed range and why (so the schema says them)."""
    bounded = any(k in meta for k in ("gt", "ge", "lt", "le"))
    if not bounded or meta.get("choices") or meta.get("boolean"):
        return doc or None
    rule = f"an integer in {meta['ge']}…{meta['le']}" if meta.get("integer") else bounds_text(meta)
    why = f": {meta['why']}" if meta.get("why") else ""
    return f"{doc} Allowed: {rule}{why}.".strip()


def _early_check(name: str, meta: Mapping[str, Any], value: Any) -> Any:
    """Refuse a non-finite or huge number with the field's range, before the number type's
    generic refusal (which knows no range, and cannot show a 10**400 by its size)."""
    value = number(value)
    if meta.get("integer"):
        if isinstance(value, float) and not math.isfinite(value):
            got = shown(value)
            raise ValueError(f"{name} must be an integer in {meta['ge']}…{meta['le']}, got {got}")
        return value
    if isinstance(value, (int, float)):
        return check_field(name, value, dict(meta))
    return value


def _spec_field(
    f: dataclasses.Field[Any], doc: str, caps: Mapping[str, Any] | None = None
) -> tuple[Any, Any]:
    """A dataclass field as a pydantic field: type, default, check and description.

    ``caps`` tightens the field's bounds for study files (see :data:`STUDY_SOLVER_CAPS`).
    """
    meta = {**f.metadata, **(caps or {})}
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
        kind = Annotated[
            kind,
            AfterValidator(partial(check_field, f.name, meta=meta)),
            BeforeValidator(partial(_early_check, f.name, meta)),
        ]
    if meta.get("optional"):
        kind = kind | None
    default = None if f.default is dataclasses.MISSING else f.default
    return kind, Field(
        default, description=_described(doc, meta), json_schema_extra=_schema_bounds(meta)
    )


def spec_model(
    name: str,
    cls: type,
    doc: str,
    names: tuple[str, ...] | None = None,
    *,
    base: type[StrictModel] = StrictModel,
    optional: bool = False,
    caps: Mapping[str, Mapping[str, Any]] | None = None,
) -> Any:
    """A study-file block (a pydantic model) with the fields ``names`` of dataclass ``cls``.

    ``optional``: every field may be left out (None), whatever the dataclass's default.
    ``caps``: tighter bounds for some fields, by name (a study's limits, not the worker's).
    """
    docs = field_docs(cls)
    by_name = {f.name: f for f in dataclasses.fields(cls)}
    fields = {}
    for n in by_name if names is None else names:
        kind, info = _spec_field(by_name[n], docs.get(n, ""), (caps or {}).get(n))
        if optional:
            extra = info.json_schema_extra
            kind, info = (
                kind | None,
                Field(None, description=info.description, json_schema_extra=extra),
            )
        fields[n] = (kind, info)
    return create_model(name, __base__=base, __doc__=doc, **fields)


# --------------------------------------------------------------------------- the blocks

#: The longest chain a study may ask for (``model.cells``, ``grid.cells``): a point's cost
#: grows with N (docs/chains.md), and a 100-cell point takes seconds to minutes.
STUDY_MAX_CELLS = 100
#: ``cells``' metadata, as a CellParams field's (bounds, why): the chain's length N.
CELLS_META: dict[str, Any] = {
    "ge": 1, "le": STUDY_MAX_CELLS, "integer": True,
    "why": "cells in series (1: the unit cell); a point costs about N (euler) to N² "
    "(exponential) times a cell's",
}  # fmt: skip


class _ChainFields(StrictModel):
    """A chain of N cells in series (docs/chains.md): absent, the unit cell."""

    cells: Integer | None = Field(
        None,
        description=_described("Cells in series N: a chain (docs/chains.md); absent: 1, the "
                               "unit cell. Or a grid axis.", CELLS_META),
        json_schema_extra=_schema_bounds(CELLS_META),
    )  # fmt: skip
    gaps: list[Real] | None = Field(
        None, min_length=1, max_length=STUDY_MAX_CELLS,
        description="The gap of each cell (both stops), cell 1 first: a graded chain; one "
        "value per cell (model.cells), instead of grid.gap.",
    )  # fmt: skip
    sigmas: list[Real] | None = Field(
        None, min_length=1, max_length=STUDY_MAX_CELLS,
        description="σ of each cell, cell 1 first: graded resonators; one value per cell "
        "(model.cells), instead of grid.sigma.",
    )  # fmt: skip

    @field_validator("cells")
    @classmethod
    def _cells(cls, n: int | None) -> int | None:
        if n is not None and not 1 <= n <= STUDY_MAX_CELLS:
            got = n if abs(n) < 10**20 else shown(n)
            raise ValueError(f"cells must be an integer in 1…{STUDY_MAX_CELLS}, got {got}")
        return n

    @field_validator("gaps")
    @classmethod
    def _gaps(cls, values: list[float] | None) -> list[float] | None:
        return None if values is None else _checked_values("gaps", _CELL_META["g1"], values)

    @field_validator("sigmas")
    @classmethod
    def _sigmas(cls, values: list[float] | None) -> list[float] | None:
        return None if values is None else _checked_values("sigmas", _CELL_META["sigma"], values)

    @model_validator(mode="after")
    def _lengths(self) -> _ChainFields:
        for name in ("gaps", "sigmas"):
            values = getattr(self, name)
            if values is not None and len(values) != (self.cells or 1):
                raise ValueError(
                    f"{name} has {len(values)} values but model.cells is {self.cells or 1}; "
                    "give one value per cell (and model.cells)"
                )
        return self

    def chain_length(self) -> int | None:
        """N when the model block gives it, else None (1, or a grid axis)."""
        return self.cells


_CELL_META = {f.name: dict(f.metadata) for f in dataclasses.fields(CellParams)}

ModelSpec = spec_model(
    "ModelSpec",
    CellParams,
    "The cell model: coupling, number of modes, damping (docs/model.md §3), and a chain of "
    "N cells (cells, gaps, sigmas: docs/chains.md).",
    # CellParams without its grid axes, and ξ (the default for every point unless the grid
    # varies it)
    tuple(
        f.name for f in dataclasses.fields(CellParams) if f.name not in MODEL_AXES or f.name == "xi"
    ),  # noqa: E501
    base=_ChainFields,
)


#: One point's step budget in a study: ``max_periods`` times the steps of a period. With the
#: caps below a point does at most about 1e9 steps (tens of seconds to minutes), whatever a
#: study file says; the worker's own limits are wider (direct calls, convergence tests).
MAX_STEPS_PER_POINT = 10**9

#: Tighter bounds of solver settings for study files (the worker accepts up to 1e7 for each).
STUDY_SOLVER_CAPS: dict[str, dict[str, Any]] = {
    "max_periods": {"le": 100_000, "why": (
        "the period budget of one point; shipped studies use up to 1000, a hundred times "
        "that is a point of minutes")},
    "window": {"le": 10_000, "why": "periods per window; less than max_periods"},
    "steps_per_period": {"le": 65_536, "why": (
        "the convergence tests need at most 16,384; max_periods × steps_per_period is at "
        "most 1e9")},
    "coarse_steps": {"le": 65_536, "why": "free-flight steps per period (default 64)"},
    "max_events_per_period": {"le": 1_000_000, "why": (
        "events in one period of one point (default 1000); a million are about 10 s a period")},
}  # fmt: skip


class _SolverBase(StrictModel):
    @model_validator(mode="after")
    def _check(self) -> Any:
        self.settings()  # cross-field rules (window < max_periods) are SolverSettings' own
        # One point's work is bounded: periods times the steps each takes.
        for steps in ("steps_per_period", "coarse_steps"):
            per = getattr(self, steps)
            if per is not None and self.max_periods * per > MAX_STEPS_PER_POINT:
                raise ValueError(
                    f"max_periods × {steps} must be <= {MAX_STEPS_PER_POINT:.0e} (one point's "
                    f"step budget), got {self.max_periods} × {per} = "
                    f"{self.max_periods * per:.3g}"
                )
        return self

    def settings(self) -> SolverSettings:
        """The worker's solver settings."""
        return SolverSettings(**self.model_dump())


SolverSpec = spec_model(
    "SolverSpec",
    SolverSettings,
    "How every point is integrated and how it ends (worker.simulate.SolverSettings).",
    base=_SolverBase,
    caps=STUDY_SOLVER_CAPS,
)

# --------------------------------------------------------------------------- physical


def _checked_values(name: str, meta: Mapping[str, Any], values: list[float]) -> list[float]:
    """Each value checked against ``meta``, the message naming it ``name[i]``."""
    return [check_field(f"{name}[{i}]", v, dict(meta)) for i, v in enumerate(values)]


#: How many rows an amplitude table may have (one per frequency; a grid axis has at most
#: 1,000,000 values, far beyond any measured plan).
MAX_TABLE_ROWS = 1_000_000

_TABLE_HINT = (
    "a table file is read only from a study file (impactcell run FILE, the nightly suite), "
    "relative to it; in a definition sent as text give the rows themselves: "
    "{frequency_hz: [...], base_amplitude_m: [...]}"
)


def _no_path(value: Any) -> Any:
    # A bare path here was not read by service.studies.files (a request body, a mapping):
    # the service never opens files a definition names.
    if isinstance(value, str):
        raise ValueError(f"got the file name {shown(value)}, but {_TABLE_HINT}")
    return value


class AmplitudeTable(StrictModel):
    """Base displacement amplitude by frequency, as rows (``frequency_hz[i]``,
    ``base_amplitude_m[i]``); every frequency of ``grid.frequency_hz`` has exactly one row.

    A study file may name a CSV file instead (``base_amplitude_table: amplitudes.csv``, columns
    ``frequency_hz`` and ``base_amplitude_m``, relative to the study file): reading the study
    puts the file's rows here, with its name in ``file``, so that the table's content, not
    only its name, is part of the definition and of the study id.
    """

    file: str | None = Field(
        None, min_length=1, max_length=1000, description="The CSV file the rows were read from."
    )
    frequency_hz: list[Real] = Field(
        min_length=1, max_length=MAX_TABLE_ROWS, description="Frequencies (Hz), distinct."
    )
    base_amplitude_m: list[Real] = Field(
        min_length=1,
        max_length=MAX_TABLE_ROWS,
        description=_described("Base displacement amplitude U_g (m) of each row.",
                               BASE_AMPLITUDE_M),
    )  # fmt: skip

    @field_validator("frequency_hz")
    @classmethod
    def _frequencies(cls, values: list[float]) -> list[float]:
        out = _checked_values("frequency_hz", FREQUENCY_HZ, values)
        seen: set[float] = set()
        for v in out:
            if v in seen:  # two amplitudes for one frequency: which one is meant?
                raise ValueError(f"frequencies must be distinct, got {v:g} Hz twice")
            seen.add(v)
        return out

    @field_validator("base_amplitude_m")
    @classmethod
    def _amplitudes(cls, values: list[float]) -> list[float]:
        return _checked_values("base_amplitude_m", BASE_AMPLITUDE_M, values)

    @model_validator(mode="after")
    def _rows(self) -> AmplitudeTable:
        nf, na = len(self.frequency_hz), len(self.base_amplitude_m)
        if nf != na:
            raise ValueError(
                f"frequency_hz has {nf} values and base_amplitude_m {na}; a table has one "
                "amplitude per frequency"
            )
        return self


class _PhysicalBase(StrictModel):
    """The per-frequency base amplitude, beside PhysicalCell's own (scalar) fields."""

    base_amplitude_per_frequency_m: list[Real] | None = Field(
        None,
        min_length=1,
        max_length=MAX_TABLE_ROWS,
        description=_described(
            "Base displacement amplitude U_g (m) at each frequency, one value per value of "
            "grid.frequency_hz and in its order (instead of base_amplitude_m).",
            BASE_AMPLITUDE_M,
        ),
    )
    base_amplitude_table: Annotated[AmplitudeTable, BeforeValidator(_no_path)] | None = Field(
        None,
        description=_described(
            "Base displacement amplitude U_g (m) by frequency, as rows {frequency_hz, "
            "base_amplitude_m} or, in a study file, a CSV file with those columns (instead of "
            "base_amplitude_m); its frequencies are those of grid.frequency_hz.",
            BASE_AMPLITUDE_M,
        ),
    )

    @field_validator("base_amplitude_per_frequency_m")
    @classmethod
    def _per_frequency(cls, values: list[float] | None) -> list[float] | None:
        if values is None:
            return None
        return _checked_values("base_amplitude_per_frequency_m", BASE_AMPLITUDE_M, values)

    def cell_fields(self) -> dict[str, Any]:
        """The fields given that are :class:`PhysicalCell`'s own (not the per-frequency ones)."""
        return self.model_dump(exclude_none=True, exclude=set(PER_FREQUENCY_FIELDS))


#: The physical block's per-frequency base amplitude fields (not PhysicalCell fields: a point
#: gets its frequency's value as ``base_amplitude_m``).
PER_FREQUENCY_FIELDS: tuple[str, ...] = tuple(_PhysicalBase.model_fields)

# Every PhysicalCell field, optional: a grid axis may give it instead.
PhysicalSpec = spec_model(
    "PhysicalSpec",
    PhysicalCell,
    "A cell in SI units (worker.physical.PhysicalCell); grid axes override fields. The base "
    "amplitude may also be given per frequency (base_amplitude_per_frequency_m, "
    "base_amplitude_table).",
    base=_PhysicalBase,
    optional=True,
)


# --------------------------------------------------------------------------- the grid


def _axis_meta() -> dict[str, dict[str, Any]]:
    cell = {f.name: dict(f.metadata) for f in dataclasses.fields(CellParams)}
    physical = {f.name: dict(f.metadata) for f in dataclasses.fields(PhysicalCell)}
    out: dict[str, dict[str, Any]] = {}
    for axis in MODEL_AXES:
        out[axis] = CELLS_META if axis == "cells" else cell[AXIS_PARAMETER.get(axis, axis)]
    for axis in PHYSICAL_AXES:
        out[axis] = FREQUENCY_HZ if axis == "frequency_hz" else physical[axis]
    return out


#: Every grid axis's field metadata (bounds and why), from the parameter it sets.
AXIS_META: dict[str, dict[str, Any]] = _axis_meta()

#: Every grid axis's allowed values, from the parameter it sets.
AXIS_BOUNDS: dict[str, dict[str, Any]] = {
    k: {b: v[b] for b in ("gt", "ge", "lt", "le") if b in v} for k, v in AXIS_META.items()
}


def _axis_items(value: Any) -> list[tuple[str, Any]]:
    """The numbers an axis gives as written, each with where it is (for messages)."""
    if isinstance(value, Mapping):
        return [(f" (range {k})", value[k]) for k in ("start", "stop") if k in value]
    if isinstance(value, (list, tuple)):
        return [(f" (value {i})", v) for i, v in enumerate(value)]
    return [("", value)]


class _GridBase(StrictModel):
    @field_validator("*", mode="before")
    @classmethod
    def _finite(cls, value: Any, info: ValidationInfo) -> Any:
        # Non-finite and huge numbers are refused here with the axis's range (the number
        # type's own refusal knows no range); finite ones are checked after parsing.
        name = info.field_name
        assert name is not None
        for where, v in _axis_items(value):
            try:
                v = number(v)
            except ValueError:
                continue  # the type says what is wrong
            if isinstance(v, (int, float)) and not math.isfinite(_float_or_inf(v)):
                raise ValueError(f"{violation(name, v, AXIS_BOUNDS[name])}{where}")
        return value

    @field_validator("*", mode="after")
    @classmethod
    def _domain(cls, value: Any, info: ValidationInfo) -> Any:
        if value is None:
            return value
        name = info.field_name
        assert name is not None
        if name == "cells":
            _whole_cells(value)
        meta = AXIS_BOUNDS[name]
        if isinstance(value, Range):
            # A range is checked by its ends, never built: its values lie between them.
            for where, v in ((" (range start)", value.start), (" (range end)", value.last)):
                problem = violation(name, v, meta)
                if problem is not None:
                    raise ValueError(problem + where)
            if value.size > 1 and not _distinct(value):
                raise ValueError(
                    f"values must be distinct: {value.size:,} values between {value.start:g} "
                    f"and {value.stop:g} are closer than the 12 digits coordinates keep"
                )
            return value
        values = axis_values(value)
        if values.size == 0:
            raise ValueError("must not be empty")
        bad = out_of_bounds(values, meta)
        if np.any(bad):
            i = int(np.argmax(bad))
            where = f" (value {i})" if values.size > 1 else ""
            raise ValueError(f"{violation(name, float(values[i]), meta)}{where}")
        if np.unique(values).size != values.size:
            raise ValueError("values must be distinct")
        return value

    def given(self) -> dict[str, Any]:
        """The axes that are set, by name."""
        names = type(self).model_fields
        return {k: getattr(self, k) for k in names if getattr(self, k) is not None}


def _whole_cells(value: Any) -> None:
    """A ``cells`` axis holds whole numbers of cells (at most ``STUDY_MAX_CELLS`` values)."""
    size = value.size if isinstance(value, Range) else len(value) if isinstance(value, list) else 1
    if size > STUDY_MAX_CELLS:
        raise ValueError(f"has {size:,} values; a chain has 1…{STUDY_MAX_CELLS} cells")
    values = axis_values(value)
    frac = values != np.round(values)
    if np.any(frac):
        i = int(np.argmax(frac))
        where = f" (value {i})" if values.size > 1 else ""
        raise ValueError(f"cells must be whole numbers of cells, got {values[i]:g}{where}")


def _float_or_inf(v: float) -> float:
    try:
        return float(v)
    except OverflowError:  # an integer beyond the float range
        return math.inf


def _distinct(r: Range) -> bool:
    """Whether a range's values stay distinct once rounded to the 12 significant digits that
    :meth:`Range.values` keeps: neighbours at least 1e-9 of the largest magnitude apart (a
    thousand times the rounding), decided without building the values."""
    n = r.size
    if r.scale == "log":
        return abs(math.log(r.stop / r.start)) / (n - 1) >= 1e-9
    step = r.step if r.step is not None else abs(r.stop - r.start) / (n - 1)
    return step >= 1e-9 * max(abs(r.start), abs(r.last))


def _axis_doc(axis: str) -> str:
    info = AXES[axis]  # the one registry of axes: long name and units
    base = info.long_name if info.units == "1" else f"{info.long_name} ({info.units})"
    return _described(base + ".", AXIS_META[axis]) or base


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


# --------------------------------------------------------------------------- sweeps, initial

#: The directions a sweep may run in (``up``: increasing values of the swept axis).
DIRECTIONS: tuple[str, ...] = ("up", "down")
#: The initial states a study may name (besides ``{random: N, seed: S}``).
INITIAL_KINDS: tuple[str, ...] = ("rest", "linear")
#: The most random initial states a study may ask for.
MAX_RANDOM_INITIAL = 64


class SweepSpec(StrictModel):
    """A sweep along one grid axis: each point starts from the previous point's final state.

    ``axis`` is a varying grid axis; ``directions`` lists ``up`` (increasing values) and/or
    ``down``, in the order the results' ``direction`` dimension takes them.
    """

    axis: str = Field(min_length=1, max_length=100, description="The grid axis swept along.")
    directions: list[Literal["up", "down"]] = Field(
        ["up", "down"],
        min_length=1,
        max_length=2,
        description="Sweep directions: up (increasing values), down, or both (default).",
    )

    @field_validator("directions")
    @classmethod
    def _distinct(cls, values: list[str]) -> list[str]:
        if len(set(values)) != len(values):
            raise ValueError(f"directions must be distinct, got {values}")
        return values


#: What an adaptive study may locate along its line (service.studies.adaptive).
ADAPTIVE_TARGETS = ("band_edges", "features")
#: The variables an adaptive study's targets may follow.
ADAPTIVE_VARIABLES = ("transmittance_db", "transmittance_linear_db", "impact_effect_db")
#: Points one adaptive line may take at most.
MAX_ADAPTIVE_POINTS = 10_000


class AdaptiveSpec(StrictModel):
    """Sample one grid axis adaptively, line by line (docs/adaptive.md).

    The axis is a range ``{start, stop, num}`` of the grid: the interval searched and ``num``
    starting samples. ``band_edges`` locates every crossing of ``variable`` = ``threshold_db``
    to ``tol`` (axis units), never missing a band at least ``min_width`` wide; ``features``
    refines where ``variable`` jumps by more than ``jump_db`` or bends, to ``resolution``.
    """

    axis: str = Field(min_length=1, max_length=100, description="The grid axis sampled.")
    target: Literal[ADAPTIVE_TARGETS] = Field(  # type: ignore[valid-type]
        "band_edges", description="band_edges (crossings of the threshold) or features."
    )
    variable: Literal[ADAPTIVE_VARIABLES] = Field(  # type: ignore[valid-type]
        "transmittance_db", description="The variable followed (default Γ)."
    )
    threshold_db: Real = Field(0.0, description="band_edges: the threshold (dB), default 0.")
    tol: Real = Field(1e-3, gt=0, description="band_edges: each edge to within this (axis units).")
    min_width: Real | None = Field(
        None,
        gt=0,
        description="band_edges: a band at least this wide is never missed "
        "(default (stop - start) / 64).",
    )
    resolution: Real | None = Field(
        None, gt=0, description="features: interval width to refine to (default tol)."
    )
    jump_db: Real = Field(1.0, gt=0, description="features: a step this large is a feature.")
    max_points: Integer = Field(
        150,
        description=f"Points per line at most (num…{MAX_ADAPTIVE_POINTS}).",
        json_schema_extra={"minimum": 2, "maximum": MAX_ADAPTIVE_POINTS},
    )

    @field_validator("max_points")
    @classmethod
    def _budget(cls, n: int) -> int:
        if not 2 <= n <= MAX_ADAPTIVE_POINTS:
            raise ValueError(f"max_points must be an integer in 2…{MAX_ADAPTIVE_POINTS}, got {n}")
        return n


class RandomInitial(StrictModel):
    """``N`` seeded random initial states around the linear steady state (``random-0`` …)."""

    random: Integer = Field(
        description=f"How many random initial states (1…{MAX_RANDOM_INITIAL}).",
        json_schema_extra={"minimum": 1, "maximum": MAX_RANDOM_INITIAL},
    )
    seed: Integer = Field(
        0, description="Seed of the random states.", json_schema_extra={"minimum": 0}
    )

    @field_validator("random")
    @classmethod
    def _count(cls, n: int) -> int:
        if not 1 <= n <= MAX_RANDOM_INITIAL:
            raise ValueError(f"random must be an integer in 1…{MAX_RANDOM_INITIAL}, got {n}")
        return n

    @field_validator("seed")
    @classmethod
    def _seed(cls, s: int) -> int:
        if not 0 <= s < 2**32:
            raise ValueError(f"seed must be an integer in 0…{2**32 - 1}, got {s}")
        return s


_INITIAL_HINT = "give rest, linear, a list of them ([rest, linear]) or {random: N, seed: S}"


def _initial(value: Any) -> Any:
    """Clear messages for a malformed ``initial`` (the union's own errors list every branch)."""
    if isinstance(value, str):
        if value not in INITIAL_KINDS:
            raise ValueError(f"unknown initial state {shown(value)}; {_INITIAL_HINT}")
        return value
    if isinstance(value, (list, tuple)):
        if not value:
            raise ValueError(f"must not be empty; {_INITIAL_HINT}")
        for i, v in enumerate(value):
            if isinstance(v, Mapping) or (isinstance(v, str) and v.startswith("random")):
                raise ValueError(
                    f"[{i}]: random states cannot be mixed into a list; give "
                    "{random: N, seed: S} on its own"
                )
            if v not in INITIAL_KINDS:
                raise ValueError(f"[{i}]: unknown initial state {shown(v)}; {_INITIAL_HINT}")
        if len(set(value)) != len(value):
            raise ValueError(f"initial states must be distinct, got {list(value)}")
        return list(value)
    if isinstance(value, RandomInitial):
        return value
    if isinstance(value, Mapping):
        try:
            return RandomInitial.model_validate(value)
        except ValidationError as exc:  # one message, not one per branch of the union
            parts = []
            for e in exc.errors():
                where = ".".join(str(x) for x in e["loc"])
                msg = "unknown key" if e["type"] == "extra_forbidden" else str(e["msg"])
                parts.append(f"{where}: {msg.removeprefix('Value error, ')}")
            raise ValueError("; ".join(parts)) from None
    raise ValueError(f"got {shown(value)}; {_INITIAL_HINT}")


#: ``initial:`` of a study: one state, a list of them, or seeded random states.
InitialSpec = Annotated[
    Literal["rest", "linear"] | list[Literal["rest", "linear"]] | RandomInitial,
    BeforeValidator(_initial),
]


def initial_labels(initial: Any) -> list[str]:
    """The labels of a study's initial states (``rest`` when none is given)."""
    if initial is None:
        return ["rest"]
    if isinstance(initial, str):
        return [initial]
    if isinstance(initial, RandomInitial):
        return [f"random-{k}" for k in range(initial.random)]
    return list(initial)


def initial_states(initial: Any) -> list[dict[str, Any]]:
    """The worker's ``initial`` dicts (``kind``, ``seed``, ``index``), one per label."""
    if isinstance(initial, RandomInitial):
        return [{"kind": "random", "seed": initial.seed, "index": k} for k in range(initial.random)]
    return [
        {"kind": kind, "seed": None, "index": k} for k, kind in enumerate(initial_labels(initial))
    ]
