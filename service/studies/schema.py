"""Study definitions: one pydantic model, validation and the content-hash id.

A study file (YAML or JSON) names a cell model, solver settings, the outputs to store and a grid;
the study is the Cartesian product of the grid's axes (:mod:`service.studies.grid`).
Non-dimensional studies vary the parameters of docs/model.md §3; physical studies
(docs/model.md §8) give a ``physical:`` block in SI units and vary ``frequency_hz`` and any
physical field.

Validation reports every problem it can find in one go, each with its path in the file
(``grid.gamma_r.num: ...``), as a :class:`StudyError` (a ``ValueError``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import (
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from service.studies.files import read_study_file
from service.studies.grid import AXIS_TAGS, Axis, Integer, Real, StrictModel, axis_values
from service.studies.variables import MODEL_AXES, PHYSICAL_AXES, PHYSICAL_FIELDS
from worker.physical import CELL_FIELDS, PhysicalCell
from worker.simulate import SOLVER_VERSION, SolverSettings
from worker.solvers.settings import LCP_SOLVERS, METHODS

__all__ = [
    "DEFAULT_MAX_POINTS",
    "Grid",
    "ModelSpec",
    "Outputs",
    "PhysicalSpec",
    "SolverSpec",
    "Study",
    "StudyError",
    "load_study",
    "parse_study",
    "validation_problems",
]

# The grid-size limit when none is given (``Settings.max_points``, ``--max-points``).
DEFAULT_MAX_POINTS = 2_000_000

_POSITIVE = {
    "theta", "sigma", "gamma_s", "gamma_r", "frequency_hz", "length_m", "width_m",
    "thickness_m", "density_kg_m3", "youngs_modulus_pa", "outer_mass_kg", "spring_n_m",
    "base_amplitude_m", "base_acceleration_m_s2",
}  # fmt: skip
_PHYSICAL_REQUIRED = CELL_FIELDS


# --------------------------------------------------------------------------- the study


class Grid(StrictModel):
    """Every axis a study may vary; which ones are allowed depends on the kind of study."""

    # Non-dimensional axes (docs/model.md §3).
    gamma_r: Axis | None = None
    gap: Axis | None = None
    g1: Axis | None = None
    g2: Axis | None = None
    theta: Axis | None = None
    sigma: Axis | None = None
    gamma_s: Axis | None = None
    xi: Axis | None = None
    # Physical axes (docs/model.md §8).
    frequency_hz: Axis | None = None
    length_m: Axis | None = None
    width_m: Axis | None = None
    thickness_m: Axis | None = None
    density_kg_m3: Axis | None = None
    youngs_modulus_pa: Axis | None = None
    outer_mass_kg: Axis | None = None
    spring_n_m: Axis | None = None
    damping_ratio: Axis | None = None
    gap_m: Axis | None = None
    gap1_m: Axis | None = None
    gap2_m: Axis | None = None
    base_amplitude_m: Axis | None = None
    base_acceleration_m_s2: Axis | None = None

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
        bad = values <= 0 if name in _POSITIVE else values < 0
        if np.any(bad):
            i = int(np.argmax(bad))
            what = "> 0" if name in _POSITIVE else ">= 0"
            where = f" (value {i})" if values.size > 1 else ""
            raise ValueError(f"must be {what}, got {values[i]:g}{where}")
        if np.unique(values).size != values.size:
            raise ValueError("values must be distinct")
        return value

    def given(self) -> dict[str, Any]:
        """The axes that are set, by name."""
        names = type(self).model_fields
        return {k: getattr(self, k) for k in names if getattr(self, k) is not None}


# --------------------------------------------------------------------------- the study


class ModelSpec(StrictModel):
    """The cell model: coupling, number of modes, damping (docs/model.md §3)."""

    coupling: Literal["paper", "full"] = "paper"
    modes: Integer = Field(5, ge=1, le=30)
    xi: Real = Field(0.05, ge=0)
    xi_b: Real | None = Field(None, ge=0)


# The worker's defaults, so a study's defaults are the solver's (never retyped here).
_SOLVER = SolverSettings()


class SolverSpec(StrictModel):
    """How every point is integrated and how it ends (``worker.simulate.SolverSettings``).

    Every default is the worker's; ``SolverSettings`` validates the values and names the field
    and its allowed range.
    """

    method: Literal[METHODS] = _SOLVER.method  # type: ignore[valid-type]
    steps_per_period: Integer | None = _SOLVER.steps_per_period
    coarse_steps: Integer = _SOLVER.coarse_steps
    max_periods: Integer = _SOLVER.max_periods
    periodicity_tol: Real = _SOLVER.periodicity_tol
    window: Integer = _SOLVER.window
    stat_tol_db: Real = _SOLVER.stat_tol_db
    near_margin: Real = _SOLVER.near_margin
    adaptive: bool = _SOLVER.adaptive
    early_stop: bool = _SOLVER.early_stop
    extrapolate: bool = _SOLVER.extrapolate
    linear_tail: bool = _SOLVER.linear_tail
    lcp: Literal[LCP_SOLVERS] = _SOLVER.lcp  # type: ignore[valid-type]

    @model_validator(mode="after")
    def _check(self) -> SolverSpec:
        self.settings()  # SolverSettings names the field and the allowed range
        return self

    def settings(self) -> SolverSettings:
        """The worker's solver settings."""
        return SolverSettings(**self.model_dump())


class Outputs(StrictModel):
    """Which result groups are stored (failed, reason and wall_s always are).

    transmittance: ``transmittance_db``, ``transmittance_db_se``, ``amplitude``;
    effective_mass: ``theta_eff``, ``theta_eff_slope``; response: ``outcome``,
    ``response_period``, ``impacts_per_period``, ``floquet_multiplier``, ``periods``,
    ``steps``; contact (off by default: diagnostics that cost storage, not insight):
    ``peak_impulse``, ``contact_steps``, ``coarse_steps``, ``steady_period``.
    """

    transmittance: bool = True
    effective_mass: bool = True
    response: bool = True
    contact: bool = False


class PhysicalSpec(StrictModel):
    """A cell in SI units (``worker.physical.PhysicalCell``); grid axes override fields."""

    length_m: Real | None = None
    width_m: Real | None = None
    thickness_m: Real | None = None
    density_kg_m3: Real | None = None
    youngs_modulus_pa: Real | None = None
    outer_mass_kg: Real | None = None
    spring_n_m: Real | None = None
    damping_ratio: Real | None = None
    gap_m: Real | None = None
    gap1_m: Real | None = None
    gap2_m: Real | None = None
    base_amplitude_m: Real | None = None
    base_acceleration_m_s2: Real | None = None


class Study(StrictModel):
    """A parameter study: the Cartesian product of ``grid``'s axes."""

    name: str = Field(min_length=1, max_length=200)
    description: str = ""
    model: ModelSpec = ModelSpec()
    solver: SolverSpec = SolverSpec()
    outputs: Outputs = Outputs()
    physical: PhysicalSpec | None = None
    grid: Grid

    # ---------------------------------------------------------------- identity

    def canonical(self) -> dict[str, Any]:
        """The definition with every default filled in, as plain JSON data."""
        return self.model_dump(mode="json", exclude_none=True)

    def canonical_json(self) -> str:
        """Canonical JSON text: sorted keys, no whitespace."""
        return json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))

    @property
    def id(self) -> str:
        """Content hash of the canonical definition plus the solver version."""
        text = f"{self.canonical_json()}\nsolver={SOLVER_VERSION}"
        return hashlib.sha256(text.encode()).hexdigest()[:20]

    # ---------------------------------------------------------------- grid

    @property
    def is_physical(self) -> bool:
        """Whether this is a physical (SI) study."""
        return self.physical is not None

    def axes(self) -> dict[str, np.ndarray]:
        """Every grid axis in canonical order, name -> values."""
        order = PHYSICAL_AXES if self.is_physical else MODEL_AXES
        given = self.grid.given()
        return {k: axis_values(given[k]) for k in order if k in given}

    def dims(self) -> dict[str, np.ndarray]:
        """The varying axes (more than one value): the dataset's dimensions."""
        return {k: v for k, v in self.axes().items() if v.size > 1}

    def scalars(self) -> dict[str, float]:
        """The axes with a single value: the dataset's scalar coordinates."""
        return {k: float(v[0]) for k, v in self.axes().items() if v.size == 1}

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the results (one entry per varying axis)."""
        return tuple(v.size for v in self.dims().values())

    @property
    def size(self) -> int:
        """Number of points."""
        return math.prod(v.size for v in self.axes().values())

    def coords_at(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Axis values of points ``start:stop`` (flat C-order index), name -> array."""
        axes = self.axes()
        shape = tuple(v.size for v in axes.values())
        idx = np.unravel_index(np.arange(start, stop), shape)
        return {k: v[i] for (k, v), i in zip(axes.items(), idx, strict=True)}

    def points(self, start: int, stop: int) -> list[dict[str, Any]]:
        """``CellParams`` keyword dicts of points ``start:stop`` (flat C-order index)."""
        cols = self.coords_at(start, stop)
        n = stop - start
        m = self.model
        common: dict[str, Any] = {"modes": m.modes, "coupling": m.coupling}
        if m.xi_b is not None:
            common["xi_b"] = m.xi_b
        out = []
        if self.is_physical:
            assert self.physical is not None
            base = self.physical.model_dump(exclude_none=True)
            for i in range(n):
                fields = {**base, **{k: float(v[i]) for k, v in cols.items()}}
                f = fields.pop("frequency_hz")
                p = PhysicalCell(**fields).to_model(f)
                out.append({**p, **common})
            return out
        for i in range(n):
            row = {k: float(v[i]) for k, v in cols.items()}
            if "gap" in row:
                g = row.pop("gap")
                row["g1"] = row["g2"] = g
            row.setdefault("xi", m.xi)
            out.append({**row, **common})
        return out

    def iter_points(self, chunk: int = 4096) -> Iterator[dict[str, Any]]:
        """Every point in order (for serial reference runs and tests)."""
        for s in range(0, self.size, chunk):
            yield from self.points(s, min(s + chunk, self.size))

    # ---------------------------------------------------------------- semantic checks

    def problems(self, max_points: int | None = None) -> list[tuple[str, str]]:
        """Cross-field problems: (path, message) pairs; empty when the study is sound."""
        return _grid_problems(
            self.grid,
            self.physical,
            explicit_xi="xi" in self.model.model_fields_set,
            max_points=max_points,
        )


def _presence_problems(given: set[str]) -> list[tuple[str, str]]:
    """Required axes of a non-dimensional study, from the keys alone."""
    out: list[tuple[str, str]] = []
    for k in ("gamma_r", "theta", "sigma", "gamma_s"):
        if k not in given:
            out.append((f"grid.{k}", "is required (a number, a list or a range)"))
    if "gap" in given and ("g1" in given or "g2" in given):
        out.append(("grid.gap", "give either gap (both stops) or g1 and g2, not both"))
    elif "gap" not in given and ("g1" in given) != ("g2" in given):
        missing = "g2" if "g1" in given else "g1"
        out.append((f"grid.{missing}", "is required with the other stop's gap"))
    elif "gap" not in given and "g1" not in given:
        out.append(("grid.gap", "is required (or g1 and g2)"))
    return out


def _grid_problems(
    grid: Grid,
    physical: PhysicalSpec | None,
    *,
    explicit_xi: bool,
    max_points: int | None,
) -> list[tuple[str, str]]:
    limit = DEFAULT_MAX_POINTS if max_points is None else max_points
    out: list[tuple[str, str]] = []
    given = grid.given()
    if physical is None:
        for k in given:
            if k not in MODEL_AXES:
                out.append(
                    (f"grid.{k}", "is a physical axis; give a physical: block or use "
                     f"one of {', '.join(MODEL_AXES)}")
                )  # fmt: skip
        out += _presence_problems(set(given))
        if explicit_xi and "xi" in given:
            out.append(("grid.xi", "is also given as model.xi; give it in one place"))
    else:
        for k in given:
            if k not in PHYSICAL_AXES:
                out.append(
                    (f"grid.{k}", "is a non-dimensional axis; a physical study varies "
                     f"frequency_hz and the physical fields ({', '.join(PHYSICAL_FIELDS)})")
                )  # fmt: skip
        if "frequency_hz" not in given:
            out.append(("grid.frequency_hz", "is required in a physical study"))
        if explicit_xi:
            out.append(("model.xi", "a physical study takes physical.damping_ratio instead"))
        base = physical.model_dump(exclude_none=True)
        for k in _PHYSICAL_REQUIRED:
            if k not in base and k not in given:
                out.append((f"physical.{k}", "is required (in physical: or as a grid axis)"))
        if not any(k in base or k in given for k in ("gap_m", "gap1_m")) or not any(
            k in base or k in given for k in ("gap_m", "gap2_m")
        ):
            out.append(("physical.gap_m", "is required (or gap1_m and gap2_m)"))
        excitation = [
            k for k in ("base_amplitude_m", "base_acceleration_m_s2") if k in base or k in given
        ]
        if len(excitation) != 1:
            out.append(
                ("physical.base_amplitude_m", "give exactly one of base_amplitude_m and "
                 f"base_acceleration_m_s2, got {', '.join(excitation) or 'neither'}")
            )  # fmt: skip
        if not out:
            first = {k: float(axis_values(v)[0]) for k, v in given.items()}
            first.pop("frequency_hz", None)
            try:
                PhysicalCell(**{**base, **first})
            except (TypeError, ValueError) as exc:
                out.append(("physical", str(exc)))
    size = math.prod(axis_values(v).size for v in given.values()) if given else 0
    if size > limit:
        out.append(("grid", f"has {size:,} points, more than the limit of {limit:,}"))
    return out


# --------------------------------------------------------------------------- errors, loading


class StudyError(ValueError):
    """Every problem with a study definition, each with its path in the file."""

    def __init__(self, problems: Sequence[tuple[str, str]], source: str = "study") -> None:
        self.problems = list(problems)
        lines = "\n".join(f"  {p}: {m}" if p else f"  {m}" for p, m in self.problems)
        n = len(self.problems)
        super().__init__(f"{source}: {n} problem{'s' if n != 1 else ''}\n{lines}")


def _path(loc: Sequence[Any]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in AXIS_TAGS:
            # Union tags (which shape of axis was tried) are not part of the file's path.
            continue
        else:
            out += f".{part}" if out else str(part)
    return out


def _message(err: Mapping[str, Any]) -> str:
    kind = err["type"]
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "missing":
        return "is required"
    msg = str(err["msg"])
    return msg.removeprefix("Value error, ")


def validation_problems(exc: ValidationError) -> list[tuple[str, str]]:
    """A pydantic error of a study-file block as (path in the block, message) pairs."""
    return [(_path(e["loc"]), _message(e)) for e in exc.errors()]


def parse_study(data: Any, *, max_points: int | None = None, source: str = "study") -> Study:
    """Validate a study definition (already parsed from YAML/JSON).

    ``max_points`` limits the grid size (default :data:`DEFAULT_MAX_POINTS`).

    Raises
    ------
    StudyError
        Listing every problem found, each with its path.
    """
    problems: list[tuple[str, str]] = []
    try:
        study = Study.model_validate(data)
    except ValidationError as exc:
        problems += validation_problems(exc)
        # Check the grid on its own too, so a bad key elsewhere does not hide grid problems.
        if isinstance(data, Mapping) and isinstance(data.get("grid"), Mapping):
            grid_ok = not any(p == "grid" or p.startswith("grid.") for p, _ in problems)
            if grid_ok:
                try:
                    grid = Grid.model_validate(data["grid"])
                    physical = (
                        PhysicalSpec.model_validate(data["physical"])
                        if isinstance(data.get("physical"), Mapping)
                        else None
                    )
                except ValidationError:
                    pass
                else:
                    explicit_xi = isinstance(data.get("model"), Mapping) and "xi" in data["model"]
                    problems += [
                        pr
                        for pr in _grid_problems(
                            grid, physical, explicit_xi=explicit_xi, max_points=max_points
                        )
                        if not pr[0].startswith("physical")
                    ]
            elif "physical" not in data:
                problems += _presence_problems(set(data["grid"]))
        raise StudyError(problems, source) from None
    problems = study.problems(max_points)
    if problems:
        raise StudyError(problems, source)
    return study


def load_study(path: str | os.PathLike[str], *, max_points: int | None = None) -> Study:
    """Read and validate a study file (``.yaml``, ``.yml`` or ``.json``)."""
    source = str(Path(path))
    data = read_study_file(path)
    if not isinstance(data, Mapping):
        raise StudyError([("", "a study file must be a mapping of keys to values")], source)
    return parse_study(data, max_points=max_points, source=source)
