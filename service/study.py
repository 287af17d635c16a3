"""Study definitions: one pydantic model, grid expansion, validation and the content-hash id.

A study file (YAML or JSON) names a cell model, solver settings, the outputs to store and a grid;
the study is the Cartesian product of the grid's axes. Non-dimensional studies vary the
parameters of docs/model.md §3; physical studies (docs/model.md §8) give a ``physical:`` block
in SI units and vary ``frequency_hz`` and any physical field.

Validation reports every problem it can find in one go, each with its path in the file
(``grid.gamma_r.num: ...``), as a :class:`StudyError` (a ``ValueError``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from worker.physical import CELL_FIELDS, PhysicalCell
from worker.simulate import SOLVER_VERSION, SolverSettings
from worker.solvers.settings import LCP_SOLVERS, METHODS

__all__ = [
    "DEFAULT_MAX_POINTS",
    "MODEL_AXES",
    "PHYSICAL_AXES",
    "Axis",
    "Grid",
    "ModelSpec",
    "Outputs",
    "PhysicalSpec",
    "Range",
    "SolverSpec",
    "Study",
    "StudyError",
    "load_study",
    "max_points_limit",
    "parse_study",
]

DEFAULT_MAX_POINTS = 2_000_000

# Canonical axis order (the dataset's dimension order, independent of the file's key order).
# γ_r is last so that a chunk of consecutive points is a piece of one spectrum.
MODEL_AXES: tuple[str, ...] = ("gap", "g1", "g2", "theta", "sigma", "gamma_s", "xi", "gamma_r")
# The SI fields are PhysicalCell's own, so the study schema cannot drift from the cell.
PHYSICAL_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(PhysicalCell))
PHYSICAL_AXES: tuple[str, ...] = (*PHYSICAL_FIELDS, "frequency_hz")
_POSITIVE = {
    "theta", "sigma", "gamma_s", "gamma_r", "frequency_hz", "length_m", "width_m",
    "thickness_m", "density_kg_m3", "youngs_modulus_pa", "outer_mass_kg", "spring_n_m",
    "base_amplitude_m", "base_acceleration_m_s2",
}  # fmt: skip
_PHYSICAL_REQUIRED = CELL_FIELDS


def max_points_limit() -> int:
    """The configured grid-size limit: ``IMPACTCELL_MAX_POINTS`` or 2,000,000."""
    raw = os.environ.get("IMPACTCELL_MAX_POINTS")
    if raw is None:
        return DEFAULT_MAX_POINTS
    try:
        value = int(raw)
    except ValueError:
        raise ValueError(f"IMPACTCELL_MAX_POINTS must be an integer, got {raw!r}") from None
    if value < 1:
        raise ValueError(f"IMPACTCELL_MAX_POINTS must be >= 1, got {value}")
    return value


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


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# --------------------------------------------------------------------------- axes


class Range(_Strict):
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
            count = math.floor((self.stop - self.start) / self.step * (1 + 1e-12) + 1e-9) + 1
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
            # Include ``stop`` when it is reached up to rounding (0.2 + 29·0.2 == 6.0).
            count = math.floor((self.stop - self.start) / self.step * (1 + 1e-12) + 1e-9) + 1
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


_AXIS_TAGS = ("range", "list", "scalar")

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


class Grid(_Strict):
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


class ModelSpec(_Strict):
    """The cell model: coupling, number of modes, damping (docs/model.md §3)."""

    coupling: Literal["paper", "full"] = "paper"
    modes: Integer = Field(5, ge=1, le=30)
    xi: Real = Field(0.05, ge=0)
    xi_b: Real | None = Field(None, ge=0)


# The worker's defaults, so a study's defaults are the solver's (never retyped here).
_SOLVER = SolverSettings()


class SolverSpec(_Strict):
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


class Outputs(_Strict):
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


class PhysicalSpec(_Strict):
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


class Study(_Strict):
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
    limit = max_points_limit() if max_points is None else max_points
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
        elif part in _AXIS_TAGS:
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


def parse_study(data: Any, *, max_points: int | None = None, source: str = "study") -> Study:
    """Validate a study definition (already parsed from YAML/JSON).

    Raises
    ------
    StudyError
        Listing every problem found, each with its path.
    """
    problems: list[tuple[str, str]] = []
    try:
        study = Study.model_validate(data)
    except ValidationError as exc:
        problems += [(_path(e["loc"]), _message(e)) for e in exc.errors()]
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
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read study file {p}: {exc.strerror}") from None
    try:
        if p.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(text)
    except Exception as exc:  # json's ValueError, yaml.YAMLError
        kind = "JSON" if p.suffix.lower() == ".json" else "YAML"
        raise ValueError(f"{p}: not valid {kind}: {exc}") from None
    if not isinstance(data, Mapping):
        raise StudyError([("", "a study file must be a mapping of keys to values")], str(p))
    return parse_study(data, max_points=max_points, source=str(p))
