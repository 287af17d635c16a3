"""The nightly regression suite: run fixed studies and compare them with stored baselines.

A suite is a folder of study files (``studies/nightly/*.yaml``). Each is a normal study plus
one extra top-level block, ``regression:``, that :func:`load_suite` removes before
:func:`service.study.parse_study` (so it does not change the study id)::

    regression:
      tolerances:                       # at points linear or periodic in both runs
        transmittance_db: {abs: 1.0e-3}     # |new - old| <= abs + rel * |old|
        theta_eff: {abs: 1.0e-3, rel: 1.0e-3}
        response_period: {exact: true}      # identical (missing == missing)
      irregular:                        # distributions over points irregular in both runs
        transmittance_db: {median_shift: 0.5, quantile_shift: 1.0, quantiles: [0.25, 0.5, 0.75]}

Variables not listed keep their defaults (:data:`DEFAULT_TOLERANCES`,
:data:`DEFAULT_IRREGULAR`). Every point is first compared by its ``outcome`` class: linear or
periodic, irregular, unsettled, failed. A point whose class changed (periodic <-> irregular,
anything <-> failed, irregular <-> unsettled, ...) is a regression, reported with its old and new
outcome. Points unsettled in both runs are not compared (their numbers are not proven).

Irregular points are compared by distribution, because their values depend on every bit of a
chaotic trajectory. ``median_shift`` bounds the median of the paired differences (new - old at
points irregular in both runs; robust with few points and insensitive to how Γ varies along
the grid); ``quantile_shift`` bounds the shift of the quantiles of each run's values at those
points; ``ks_pvalue`` (optional) fails when a two-sample Kolmogorov-Smirnov test gives a smaller
p-value. A check with fewer than ``min_points`` points is skipped (and says so).

Baselines are ``<baselines>/<study-file-stem>.nc``: the comparison variables and coordinates of
a results file, with its provenance attributes and ``baseline_created``. A baseline made by
another solver version (``solver_version`` attribute; files of solver version 1 have no
``outcome``) is not comparable: the study is reported as an error telling to re-cut the
baselines with ``impactcell nightly --update-baseline``, and the differences found (reading an
old baseline's outcome from ``response_period``: 0 = irregular) are listed for information.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic import model_validator as _model_validator

from service.store import (
    OUTCOMES,
    VARIABLES,
    atomic_write,
    data_root,
    encoding,
    open_results,
    outcome_counts,
    outcome_names,
)
from service.study import Integer, Real, Study, StudyError, _message, _path, parse_study
from worker.simulate import SOLVER_VERSION

__all__ = [
    "DEFAULT_BASELINES",
    "DEFAULT_IRREGULAR",
    "DEFAULT_SUITE",
    "DEFAULT_TOLERANCES",
    "Change",
    "DistributionCheck",
    "IrregularCheck",
    "NightlyReport",
    "RegressionSpec",
    "StudyComparison",
    "SuiteEntry",
    "SuiteError",
    "Tolerance",
    "compare",
    "load_suite",
    "run_suite",
    "write_baseline",
]

DEFAULT_SUITE = Path("studies/nightly")
DEFAULT_BASELINES = Path("studies/baselines")
_REPO = Path(__file__).resolve().parents[1]
_SUFFIXES = (".yaml", ".yml", ".json")
# Variables a tolerance may name (everything measured; not wall_s, failed, reason).
COMPARABLE = tuple(
    k for k, v in VARIABLES.items() if v.group and v.kind in ("float", "maskint", "int", "bool")
)
# Variables a distribution check may name.
DISTRIBUTABLE = tuple(k for k, v in VARIABLES.items() if v.group and v.kind == "float")
# Variables of solver version 1 that are gone, and what replaced them (for the error message).
_RENAMED = {"theta_eff_mean": "theta_eff_slope", "converged": "outcome"}
# Always kept in a baseline: how every point ended (and, for older readers, failed/period).
_ALWAYS = ("outcome", "response_period", "failed")
# Outcome classes: a point moving between classes is a regression.
_STEADY = ("linear", "periodic")
_CLASS = {k: ("linear/periodic" if k in _STEADY else k) for k in OUTCOMES}
_CLASSES_TEXT = "same outcome class (linear/periodic, irregular, unsettled, failed)"


# --------------------------------------------------------------------------- the regression block


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _replaced(name: str) -> str:
    new = _RENAMED.get(str(name))
    return f" (replaced by {new} in solver version 2)" if new else ""


class Tolerance(_Strict):
    """How far a variable may move at periodic points: ``abs + rel·|old|``, or ``exact``."""

    abs: Real | None = Field(None, ge=0)
    rel: Real | None = Field(None, ge=0)
    exact: bool = False

    @_model_validator(mode="after")
    def _check(self) -> Tolerance:
        if self.exact and (self.abs is not None or self.rel is not None):
            raise ValueError("give exact: true or abs/rel, not both")
        if not self.exact and self.abs is None and self.rel is None:
            raise ValueError("give abs and/or rel, or exact: true")
        return self

    def limit(self, old: np.ndarray) -> np.ndarray:
        """The allowed |new - old| at each old value (0 when exact)."""
        if self.exact:
            return np.zeros_like(old, dtype=np.float64)
        return (self.abs or 0.0) + (self.rel or 0.0) * np.abs(old)

    def describe(self) -> str:
        """Short text: ``exact``, ``abs 0.001``, ``abs 0.001 + rel 0.001``."""
        if self.exact:
            return "exact"
        parts = []
        if self.abs is not None:
            parts.append(f"abs {self.abs:g}")
        if self.rel is not None:
            parts.append(f"rel {self.rel:g}")
        return " + ".join(parts)


class IrregularCheck(_Strict):
    """Distribution checks of one variable over irregular points (see the module doc)."""

    median_shift: Real | None = Field(None, ge=0)
    quantile_shift: Real | None = Field(None, ge=0)
    quantiles: list[Real] = Field(default_factory=lambda: [0.25, 0.5, 0.75], min_length=1)
    ks_pvalue: Real | None = Field(None, gt=0, lt=1)
    min_points: Integer = Field(5, ge=1)

    @field_validator("quantiles")
    @classmethod
    def _unit(cls, v: list[float]) -> list[float]:
        bad = [q for q in v if not 0.0 <= q <= 1.0]
        if bad:
            raise ValueError(f"quantiles must be in [0, 1], got {bad[0]:g}")
        return v

    @_model_validator(mode="after")
    def _check(self) -> IrregularCheck:
        if self.median_shift is None and self.quantile_shift is None and self.ks_pvalue is None:
            raise ValueError("give at least one of median_shift, quantile_shift, ks_pvalue")
        return self


DEFAULT_TOLERANCES: dict[str, Tolerance] = {
    "transmittance_db": Tolerance(abs=1e-3),
    "response_period": Tolerance(exact=True),
}
DEFAULT_IRREGULAR: dict[str, IrregularCheck] = {
    "transmittance_db": IrregularCheck(median_shift=0.5, quantile_shift=1.0),
}


class RegressionSpec(_Strict):
    """The ``regression:`` block of a nightly study file."""

    tolerances: dict[str, Tolerance] = Field(default_factory=dict)
    irregular: dict[str, IrregularCheck] = Field(default_factory=dict)

    @field_validator("tolerances", mode="before")
    @classmethod
    def _tolerance_names(cls, v: Any) -> Any:
        if isinstance(v, Mapping):
            for k in v:
                if k not in COMPARABLE:
                    raise ValueError(
                        f"unknown variable {k!r}{_replaced(k)}; tolerances may name "
                        f"{', '.join(COMPARABLE)}"
                    )
        return v

    @field_validator("irregular", mode="before")
    @classmethod
    def _irregular_names(cls, v: Any) -> Any:
        if isinstance(v, Mapping):
            for k in v:
                if k not in DISTRIBUTABLE:
                    raise ValueError(
                        f"unknown variable {k!r}{_replaced(k)}; irregular checks may name "
                        f"{', '.join(DISTRIBUTABLE)}"
                    )
        return v

    def effective_tolerances(self) -> dict[str, Tolerance]:
        """Tolerances with the defaults for variables not listed."""
        return {**DEFAULT_TOLERANCES, **self.tolerances}

    def effective_irregular(self) -> dict[str, IrregularCheck]:
        """Distribution checks with the defaults for variables not listed."""
        return {**DEFAULT_IRREGULAR, **self.irregular}

    def variables(self) -> list[str]:
        """Every variable the comparison reads (the baseline keeps these)."""
        names = set(_ALWAYS) | set(self.effective_tolerances()) | set(self.effective_irregular())
        return [k for k in VARIABLES if k in names]


# --------------------------------------------------------------------------- the suite


class SuiteError(ValueError):
    """Every problem with a suite folder, each with its file and path in the file."""

    def __init__(self, problems: Sequence[str]) -> None:
        self.problems = list(problems)
        super().__init__("nightly suite: " + "\n".join(self.problems))


@dataclass(frozen=True)
class SuiteEntry:
    """One study file of the suite."""

    path: Path
    study: Study
    spec: RegressionSpec
    definition: dict[str, Any]  # the file's study definition without ``regression``

    @property
    def stem(self) -> str:
        """The file name without suffix: the baseline's name."""
        return self.path.stem


def _resolve(path: str | os.PathLike[str], default: Path) -> Path:
    """``path``; a relative default missing here is looked up in the source tree."""
    p = Path(path)
    if p == default and not p.exists() and (_REPO / default).exists():
        return _REPO / default
    return p


def _read(path: Path) -> Any:
    text = path.read_text(encoding="utf-8")
    if path.suffix.lower() == ".json":
        return json.loads(text)
    import yaml

    return yaml.safe_load(text)


def load_suite(directory: str | os.PathLike[str] = DEFAULT_SUITE) -> list[SuiteEntry]:
    """Read and validate every study file in ``directory`` (sorted by name).

    Raises
    ------
    SuiteError
        Listing every problem of every file (a ``ValueError``).
    """
    folder = _resolve(directory, DEFAULT_SUITE)
    if not folder.is_dir():
        raise SuiteError([f"suite folder {folder} does not exist"])
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in _SUFFIXES and p.is_file())
    if not files:
        raise SuiteError([f"no study files ({', '.join(_SUFFIXES)}) in {folder}"])
    problems: list[str] = []
    entries: list[SuiteEntry] = []
    stems: dict[str, Path] = {}
    for path in files:
        if path.stem in stems:
            problems.append(
                f"{path}: same name as {stems[path.stem].name}; baselines are named by file stem"
            )
            continue
        stems[path.stem] = path
        try:
            data = _read(path)
        except Exception as exc:  # OSError, json/yaml errors
            problems.append(f"{path}: cannot read: {exc}")
            continue
        if not isinstance(data, Mapping):
            problems.append(f"{path}: a study file must be a mapping of keys to values")
            continue
        definition = {k: v for k, v in data.items() if k != "regression"}
        errs: list[str] = []
        spec: RegressionSpec | None = None
        block = data.get("regression")
        try:
            spec = RegressionSpec.model_validate({} if block is None else block)
        except ValidationError as exc:
            for e in exc.errors():
                where = _path(e["loc"])
                errs.append(f"regression{'.' + where if where else ''}: {_message(e)}")
        study: Study | None = None
        try:
            study = parse_study(definition, source=str(path))
        except StudyError as exc:
            errs += [f"{p}: {m}" if p else m for p, m in exc.problems]
        if study is not None and spec is not None:
            groups = {g for g, on in study.outputs.model_dump().items() if on}
            for name in spec.variables():
                group = VARIABLES[name].group
                if group and group not in groups:
                    errs.append(
                        f"outputs.{group}: the regression compares {name}; switch "
                        f"{group} on (or drop {name} from the regression block)"
                    )
        if errs:
            problems += [f"{path}: {e}" for e in errs]
            continue
        assert study is not None and spec is not None
        entries.append(SuiteEntry(path=path, study=study, spec=spec, definition=definition))
    if problems:
        raise SuiteError(problems)
    return entries


# --------------------------------------------------------------------------- comparison results


def _num(x: Any) -> float | int | None:
    """A JSON-safe number (``None`` for missing)."""
    if x is None:
        return None
    v = float(x)
    if not math.isfinite(v):
        return None
    return int(v) if v.is_integer() and abs(v) < 2**53 else v


@dataclass
class Change:
    """One point that differs from the baseline.

    kind: ``moved`` (a variable beyond its tolerance; old and new values) or ``outcome`` (the
    outcome class changed: old and new outcome names, ``note`` the new point's reason if any).
    """

    kind: str
    variable: str
    coords: dict[str, float]
    old: float | str | None
    new: float | str | None
    delta: float | None
    tolerance: str
    regression: bool = True
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {
            "kind": self.kind,
            "variable": self.variable,
            "coords": self.coords,
            "old": self.old,
            "new": self.new,
            "delta": self.delta,
            "tolerance": self.tolerance,
            "regression": self.regression,
            "note": self.note,
        }


@dataclass
class DistributionCheck:
    """One distribution check over irregular points."""

    variable: str
    check: str  # median_shift | quantile_shift | ks_pvalue
    value: float | None
    limit: float
    passed: bool
    n_old: int
    n_new: int
    n_paired: int
    skipped: str = ""  # why the check was not applied
    detail: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


_OK_STATUS = ("passed", "updated", "created")


@dataclass
class StudyComparison:
    """A study's comparison with its baseline.

    status: ``passed``, ``failed`` (regressions), ``error`` (could not run or compare),
    ``missing-baseline``, and with ``--update-baseline`` ``updated`` or ``created``.
    """

    study: str  # suite file stem
    name: str = ""
    study_id: str = ""
    status: str = "passed"
    points: int = 0
    counts: dict[str, dict[str, int]] = field(default_factory=dict)
    changes: list[Change] = field(default_factory=list)
    distribution: list[DistributionCheck] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # regressions that are not points
    notes: list[str] = field(default_factory=list)
    error: str | None = None
    new_info: dict[str, str] = field(default_factory=dict)
    baseline_info: dict[str, str] = field(default_factory=dict)
    baseline: str | None = None
    results: str | None = None
    wall_s: float | None = None

    @property
    def ok(self) -> bool:
        """No regression, no error, baseline present (or just written)."""
        return self.status in _OK_STATUS

    @property
    def regressions(self) -> list[Change]:
        """The changes that are regressions."""
        return [c for c in self.changes if c.regression]

    @property
    def failed_checks(self) -> list[DistributionCheck]:
        """Distribution checks that failed."""
        return [d for d in self.distribution if not d.passed]

    def has_regressions(self) -> bool:
        """Whether anything compared differs beyond its tolerance."""
        return bool(self.regressions or self.failed_checks or self.problems)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {
            "study": self.study,
            "name": self.name,
            "study_id": self.study_id,
            "status": self.status,
            "ok": self.ok,
            "points": self.points,
            "counts": self.counts,
            "regressions": len(self.regressions),
            "changes": [c.to_json() for c in self.changes],
            "distribution": [d.to_json() for d in self.distribution],
            "problems": self.problems,
            "notes": self.notes,
            "error": self.error,
            "new": self.new_info,
            "baseline_info": self.baseline_info,
            "baseline": self.baseline,
            "results": self.results,
            "wall_s": self.wall_s,
        }


# --------------------------------------------------------------------------- comparison


_PROVENANCE = ("impactcell_version", "git_commit", "solver_version", "solver_settings", "created")


def _provenance(ds: xr.Dataset) -> dict[str, str]:
    keys = (*_PROVENANCE, "baseline_created", "git_dirty")
    return {k: str(ds.attrs[k]) for k in keys if k in ds.attrs}


def _outcomes(ds: xr.Dataset) -> np.ndarray:
    """Outcome names of every point (str array in the dims of ``failed``).

    Datasets of solver version 1 have no ``outcome``: it is read from ``failed`` and
    ``response_period`` (``periodic`` for a period > 0, ``irregular`` for 0, which then also
    covers what is now ``unsettled``).
    """
    dims = ds["failed"].dims
    if "outcome" in ds:
        return outcome_names(ds["outcome"].transpose(*dims))
    failed = ds["failed"].values.astype(bool)
    rp = np.asarray(ds["response_period"].transpose(*dims).values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(failed, "failed", np.where(rp > 0, "periodic", "irregular")).astype(str)


def _counts(ds: xr.Dataset) -> dict[str, int]:
    failed = ds["failed"].values.astype(bool)
    return {"points": int(failed.size), **outcome_counts(_outcomes(ds))}


def _grid_problems(new: xr.Dataset, old: xr.Dataset) -> list[str]:
    out = []
    for ds, which in ((new, "new results"), (old, "baseline")):
        # ``outcome`` may be read from these two in files that predate it
        missing = [v for v in ("failed", "response_period") if v not in ds]
        if missing:
            out.append(f"{which} lack {', '.join(missing)}")
    if out:
        return out
    dn, do = new["failed"].dims, old["failed"].dims
    if set(dn) != set(do):
        return [f"grid axes differ: baseline {list(do)}, new {list(dn)}"]
    for d in dn:
        a, b = new[d].values, old[d].values
        if a.shape != b.shape or not np.allclose(a, b, rtol=1e-12, atol=0):
            return [f"grid axis {d} differs: baseline {b.size} values, new {a.size} values"]
    return []


def _stale(new: xr.Dataset, baseline: xr.Dataset) -> str | None:
    """Why the baseline is from another solver version (None: it is not)."""
    v_old, v_new = baseline.attrs.get("solver_version"), new.attrs.get("solver_version")
    mismatch = v_old is not None and v_new is not None and str(v_old) != str(v_new)
    if "outcome" in baseline and not mismatch:
        return None
    made = f"solver version {v_old}" if v_old is not None else "an unknown solver version"
    lacks = "" if "outcome" in baseline else " and has no outcome variable"
    return (
        f"the baseline predates solver version {v_new or SOLVER_VERSION}: it was made with "
        f"{made}{lacks}, so its numbers are not comparable with today's; re-cut the baselines "
        "deliberately with `impactcell nightly --update-baseline` (the report then lists what "
        "changed)"
    )


def _definition(ds: xr.Dataset) -> dict[str, Any] | None:
    text = ds.attrs.get("study")
    if not text:
        return None
    try:
        d = json.loads(str(text))
    except ValueError:
        return None
    if not isinstance(d, dict):
        return None
    return {k: v for k, v in d.items() if k not in ("name", "description")}


def _diff(old: Any, new: Any, where: str, differ: list[str], one_sided: list[str]) -> None:
    """Paths where two definitions differ; keys present on one side only go to ``one_sided``."""
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            path = f"{where}.{k}" if where else str(k)
            if k not in old or k not in new:
                one_sided.append(path)
            else:
                _diff(old[k], new[k], path, differ, one_sided)
    elif old != new:
        differ.append(where or "definition")


def _coords_at(da: xr.DataArray, flat: int) -> dict[str, float]:
    """Coordinates (dimension and derived) of element ``flat`` of ``da``."""
    idx = dict(zip(da.dims, np.unravel_index(flat, da.shape), strict=True))
    out: dict[str, float] = {}
    for name, c in da.coords.items():
        if c.ndim == 0 or not set(c.dims) <= set(idx):
            continue
        v = c.isel({d: idx[d] for d in c.dims}).values
        out[str(name)] = _num(v)  # type: ignore[assignment]
    for d in da.dims:  # a dimension without a coordinate: its index
        out.setdefault(str(d), int(idx[d]))
    return out


def _on(mask: np.ndarray, like: xr.DataArray, dims: tuple[str, ...]) -> np.ndarray:
    """A study-grid mask broadcast to the dims of ``like`` (e.g. with ``stop``)."""
    m = xr.DataArray(mask, dims=dims)
    return m.broadcast_like(like).transpose(*like.dims).values


def _aligned(new: xr.Dataset, old: xr.Dataset, var: str) -> tuple[xr.DataArray, np.ndarray]:
    a = new[var]
    b = old[var].transpose(*a.dims)
    return a, np.asarray(b.values, dtype=np.float64)


def _moved(old: np.ndarray, new: np.ndarray, tol: Tolerance) -> np.ndarray:
    nan_o, nan_n = np.isnan(old), np.isnan(new)
    both = nan_o & nan_n
    one = nan_o ^ nan_n
    with np.errstate(invalid="ignore"):
        diff = new != old if tol.exact else np.abs(new - old) > tol.limit(old)
    return one | (diff & ~both)


def compare(
    new: xr.Dataset,
    baseline: xr.Dataset,
    spec: RegressionSpec | None = None,
    *,
    study: str = "",
) -> StudyComparison:
    """Compare a study's new results with its baseline.

    Parameters
    ----------
    new, baseline : xr.Dataset
        Results datasets (:func:`service.store.open_results`) of the same study grid.
    spec : RegressionSpec, optional
        Tolerances and distribution checks (default: the defaults only).
    study : str
        Label (the suite file's stem).

    Returns
    -------
    StudyComparison
        ``passed``, ``failed`` (with every moved point, its coordinates, old and new values or
        outcomes) or ``error`` (grids or definitions differ, or the baseline is from another
        solver version: then the differences are listed, but none counts as a regression).
    """
    spec = spec or RegressionSpec()
    out = StudyComparison(
        study=study,
        name=str(new.attrs.get("study_name", "")),
        study_id=str(new.attrs.get("study_id", "")),
        new_info=_provenance(new),
        baseline_info=_provenance(baseline),
    )
    stale = _stale(new, baseline)
    problems = _grid_problems(new, baseline)
    if problems:
        out.status, out.error = "error", "; ".join(([stale] if stale else []) + problems)
        return out
    out.points = int(new["failed"].size)
    out.counts = {"new": _counts(new), "baseline": _counts(baseline)}
    dn, db = _definition(new), _definition(baseline)
    if dn is not None and db is not None:
        differ: list[str] = []
        one_sided: list[str] = []
        _diff(db, dn, "", differ, one_sided)
        if differ and not stale:
            out.status = "error"
            out.error = (
                f"the baseline was made from a different study definition (differs in "
                f"{', '.join(differ)}); if the change is deliberate, rerun with --update-baseline"
            )
            return out
        if differ:  # expected across solver versions (their defaults change)
            out.notes.append(f"definition differs from the baseline's in {', '.join(differ)}")
        if one_sided:  # e.g. a solver setting added since, at its default
            out.notes.append(f"definition keys in only one of the runs: {', '.join(one_sided)}")
    for key in ("solver_version", "impactcell_version", "git_commit"):
        a, b = baseline.attrs.get(key), new.attrs.get(key)
        if a is not None and b is not None and a != b:
            out.notes.append(f"{key}: baseline {a}, new {b}")

    dims = tuple(str(d) for d in new["failed"].dims)
    o_new, o_old = _outcomes(new), _outcomes(baseline.transpose(*dims, ...))
    c_new = np.vectorize(_CLASS.get, otypes=[object])(o_new)
    c_old = np.vectorize(_CLASS.get, otypes=[object])(o_old)
    steady = np.isin(o_new, _STEADY) & np.isin(o_old, _STEADY)
    irr_new, irr_old = o_new == "irregular", o_old == "irregular"
    grid = new["failed"]
    reason = new["reason"].values if "reason" in new else None

    for i in np.flatnonzero(c_new != c_old):
        note = str(reason.flat[i]) if reason is not None else ""
        out.changes.append(
            Change("outcome", "outcome", _coords_at(grid, int(i)), str(o_old.flat[i]),
                   str(o_new.flat[i]), None, _CLASSES_TEXT, note=note)
        )  # fmt: skip
    unsettled = int(np.sum((o_new == "unsettled") & (o_old == "unsettled")))
    if unsettled:
        out.notes.append(f"{unsettled} points unsettled in both runs (not compared)")

    for var, tol in spec.effective_tolerances().items():
        lacking = [w for w, ds in (("baseline", baseline), ("new results", new)) if var not in ds]
        if lacking:
            out.problems.append(
                f"{var}: not in the {' and '.join(lacking)}; rerun with --update-baseline"
            )
            continue
        a, old_v = _aligned(new, baseline, var)
        new_v = np.asarray(a.values, dtype=np.float64)
        mask = _on(steady, a, dims)
        moved = _moved(old_v, new_v, tol) & mask
        for i in np.flatnonzero(moved):
            o, n = old_v.flat[i], new_v.flat[i]
            delta = abs(n - o) if np.isfinite(o) and np.isfinite(n) else None
            out.changes.append(
                Change("moved", var, _coords_at(a, int(i)), _num(o), _num(n), _num(delta),
                       tol.describe())
            )  # fmt: skip

    if stale:
        # Not comparable: what differs is listed for information (and for --update-baseline).
        for c in out.changes:
            c.regression = False
        out.problems.clear()
        out.notes.append("distribution checks skipped: the baseline is from another solver")
        out.status, out.error = "error", stale
        return out

    for var, chk in spec.effective_irregular().items():
        if var not in new or var not in baseline:
            out.problems.append(f"{var}: not in both datasets; rerun with --update-baseline")
            continue
        a, old_v = _aligned(new, baseline, var)
        new_v = np.asarray(a.values, dtype=np.float64)
        out.distribution += _distribution(
            var, chk, old_v, new_v, _on(irr_old, a, dims), _on(irr_new, a, dims)
        )

    out.status = "failed" if out.has_regressions() else "passed"
    return out


def _distribution(
    var: str,
    chk: IrregularCheck,
    old: np.ndarray,
    new: np.ndarray,
    irr_old: np.ndarray,
    irr_new: np.ndarray,
) -> list[DistributionCheck]:
    """The distribution checks of one variable over the points irregular in both runs.

    ``n_old`` and ``n_new`` count each run's irregular points; the checks use the points
    irregular in both (``n_paired``), where a point that changed class is already a regression.
    """
    pair = irr_old & irr_new & np.isfinite(old) & np.isfinite(new)
    xo, xn = old[pair], new[pair]
    d = xn - xo
    no, nn, npair = int(np.sum(irr_old)), int(np.sum(irr_new)), int(d.size)
    out: list[DistributionCheck] = []

    def add(check: str, value: float | None, limit: float, passed: bool, **detail: Any):
        skipped = ""
        if npair < chk.min_points:
            skipped = (
                f"{npair} points irregular in both runs, fewer than min_points = {chk.min_points}"
            )
            value, passed = None, True
        out.append(
            DistributionCheck(var, check, _num(value), limit, passed, no, nn, npair, skipped,
                              detail if not skipped else {})
        )  # fmt: skip

    if chk.median_shift is not None:
        v = float(abs(np.median(d))) if npair else None
        add("median_shift", v, chk.median_shift, v is not None and v <= chk.median_shift,
            mean_shift=_num(np.mean(d)) if npair else None)  # fmt: skip
    if chk.quantile_shift is not None:
        if npair:
            qo, qn = np.quantile(xo, chk.quantiles), np.quantile(xn, chk.quantiles)
            v = float(np.max(np.abs(qn - qo)))
            detail = {
                f"q{q:g}": {"old": _num(a), "new": _num(b)}
                for q, a, b in zip(chk.quantiles, qo, qn, strict=True)
            }
        else:
            v, detail = None, {}
        add("quantile_shift", v, chk.quantile_shift, v is not None and v <= chk.quantile_shift,
            **detail)  # fmt: skip
    if chk.ks_pvalue is not None:
        p = None
        if npair:
            from scipy.stats import ks_2samp

            p = float(ks_2samp(xo, xn).pvalue)
        add("ks_pvalue", p, chk.ks_pvalue, p is not None and p >= chk.ks_pvalue)
    return out


# --------------------------------------------------------------------------- baselines


def _git_dirty() -> str:
    try:
        r = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=_REPO,
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    if r.returncode != 0:
        return "unknown"
    return "yes" if r.stdout.strip() else "no"


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def write_baseline(
    ds: xr.Dataset, path: str | os.PathLike[str], spec: RegressionSpec, *, source: str = ""
) -> Path:
    """Write the comparison variables and coordinates of ``ds`` as a baseline (atomic, zlib).

    The results' global attributes (version, git commit, solver version and settings, study)
    are kept; ``baseline_created``, ``baseline_source`` and ``git_dirty`` are added.
    """
    keep = [v for v in spec.variables() if v in ds.data_vars]
    out = ds[keep]
    if "stop" in out.coords and not any("stop" in out[v].dims for v in keep):
        out = out.drop_vars("stop")
    out.attrs = {
        **ds.attrs,
        "baseline_created": _now(),
        "baseline_source": source,
        "baseline_variables": " ".join(keep),
        "git_dirty": _git_dirty(),
    }
    p = Path(path)
    enc = encoding(out)
    atomic_write(p, lambda tmp: out.to_netcdf(tmp, engine="netcdf4", encoding=enc))
    os.chmod(p, 0o644)  # a shared, committed file (the temporary file was private)
    return p


# --------------------------------------------------------------------------- the report


def _fmt(x: Any, digits: int = 9) -> str:
    if x is None:
        return "missing"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return str(x)


def _coords_text(c: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={_fmt(v, 8)}" for k, v in c.items())


@dataclass
class NightlyReport:
    """What a nightly run found, study by study."""

    studies: list[StudyComparison]
    suite: str
    baselines: str
    mode: str  # "embedded" or the service URL
    update_baseline: bool
    started: str
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    report_dir: str | None = None
    max_rows: int = 200  # markdown rows of changes per study (the JSON has them all)

    @property
    def ok(self) -> bool:
        """Every study passed (or, updating, had its baseline written)."""
        return bool(self.studies) and all(s.ok for s in self.studies)

    def summary(self) -> str:
        """One line: how many studies and points, and which studies are not ok and why."""
        n, pts = len(self.studies), sum(s.points for s in self.studies)
        head = f"{n} stud{'y' if n == 1 else 'ies'}, {pts} points"
        bad = [s for s in self.studies if not s.ok]
        if not bad:
            if self.update_baseline:
                changed = sum(1 for s in self.studies if s.changes or s.status == "created")
                return f"{head}: baselines written ({changed} new or changed)"
            return f"{head}: no regressions"
        parts = []
        for s in bad:
            why = [f"{len(s.regressions)} changed points"] if s.regressions else []
            if s.failed_checks:
                why.append(f"{len(s.failed_checks)} failed distribution checks")
            parts.append(f"{s.study} {s.status}" + (f" ({', '.join(why)})" if why else ""))
        return f"{head}: {len(bad)} not ok: " + "; ".join(parts)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict: the run, then one entry per study with every change."""
        return {
            "ok": self.ok,
            "summary": self.summary(),
            "started": self.started,
            "wall_s": self.wall_s,
            "mode": self.mode,
            "suite": self.suite,
            "baselines": self.baselines,
            "update_baseline": self.update_baseline,
            "notes": self.notes,
            "studies": [s.to_json() for s in self.studies],
        }

    def to_markdown(self) -> str:
        """A markdown report: a summary table, then every moved point and failed check."""
        if self.update_baseline:
            verdict = "BASELINES UPDATED" if self.ok else "BASELINE UPDATE INCOMPLETE"
        else:
            verdict = "PASSED" if self.ok else "FAILED"
        lines = [
            f"# Nightly regression: {verdict}",
            "",
            f"Started {self.started}, {self.wall_s:.1f} s, mode {self.mode}. Suite `{self.suite}`, "
            f"baselines `{self.baselines}`.",
            "",
            self.summary() + ".",
            "",
            "| study | points | linear | periodic | irregular | unsettled | failed | status | "
            "changes | distribution checks |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for s in self.studies:
            c = s.counts.get("new", {})
            n_checks = len(s.distribution)
            checks = f"{n_checks - len(s.failed_checks)}/{n_checks} ok" if n_checks else "-"
            changes = len(s.regressions) if not self.update_baseline else len(s.changes)
            per = " | ".join(str(c.get(k, "")) for k in OUTCOMES)
            lines.append(f"| {s.study} | {s.points} | {per} | {s.status} | {changes} | {checks} |")
        rows = [(s, ch) for s in self.studies for ch in s.changes]
        if rows:
            title = "Changes written to the baselines" if self.update_baseline else "Moved points"
            lines += [
                "",
                f"## {title}",
                "",
                "| study | coordinates | variable | kind | old | new | abs diff | tolerance |",
                "|---|---|---|---|---|---|---|---|",
            ]
            shown: dict[str, int] = {}
            for s, ch in rows:
                shown[s.study] = shown.get(s.study, 0) + 1
                if shown[s.study] > self.max_rows:
                    continue
                lines.append(
                    f"| {s.study} | {_coords_text(ch.coords)} | {ch.variable} | {ch.kind} | "
                    f"{_fmt(ch.old)} | {_fmt(ch.new)} | "
                    f"{'-' if ch.kind == 'outcome' else _fmt(ch.delta, 3)} | {ch.tolerance} |"
                )
            for study, n in shown.items():
                if n > self.max_rows:
                    lines.append(f"\n{study}: {n - self.max_rows} more rows in report.json.")
        dist = [(s, d) for s in self.studies for d in s.distribution]
        if dist:
            lines += [
                "",
                "## Irregular points (distribution checks)",
                "",
                "| study | variable | check | value | limit | points old/new/paired | result |",
                "|---|---|---|---|---|---|---|",
            ]
            for s, d in dist:
                result = f"skipped: {d.skipped}" if d.skipped else ("ok" if d.passed else "FAIL")
                lines.append(
                    f"| {s.study} | {d.variable} | {d.check} | {_fmt(d.value, 4)} | {d.limit:g} "
                    f"| {d.n_old}/{d.n_new}/{d.n_paired} | {result} |"
                )
        msgs = [
            (s.study, m)
            for s in self.studies
            for m in ([s.error] if s.error else []) + s.problems + s.notes
        ]
        msgs += [("suite", n) for n in self.notes]
        if msgs:
            lines += ["", "## Notes and errors", ""]
            lines += [f"- {who}: {m}" for who, m in msgs]
        return "\n".join(lines) + "\n"

    def write(self, directory: str | os.PathLike[str]) -> tuple[Path, Path]:
        """Write ``report.json`` and ``report.md`` into ``directory``."""
        d = Path(directory)
        self.report_dir = str(d)
        text_json = json.dumps(self.to_json(), indent=1, allow_nan=False)
        text_md = self.to_markdown()
        pj, pm = d / "report.json", d / "report.md"
        atomic_write(pj, lambda p: p.write_text(text_json, encoding="utf-8"))
        atomic_write(pm, lambda p: p.write_text(text_md, encoding="utf-8"))
        return pj, pm


# --------------------------------------------------------------------------- running


def _stamp_dir(base: Path) -> Path:
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    d, i = base / stamp, 1
    while d.exists():
        d, i = base / f"{stamp}-{i}", i + 1
    return d


def _embedded_client(workers: int | None) -> tuple[Any, Any]:
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=40,
    )
    return Client(cluster), cluster


def run_suite(
    directory: str | os.PathLike[str] = DEFAULT_SUITE,
    baselines: str | os.PathLike[str] = DEFAULT_BASELINES,
    url: str | None = None,
    token: str | None = None,
    data_dir: str | os.PathLike[str] | None = None,
    update_baseline: bool = False,
    report_dir: str | os.PathLike[str] | None = None,
    workers: int | None = None,
    *,
    serial: bool = False,
    scheduler: str | None = None,
    log: Callable[[str], None] | None = None,
) -> NightlyReport:
    """Run every study of the suite, compare with the baselines, write the reports.

    Parameters
    ----------
    directory : path
        The suite folder (default ``studies/nightly``).
    baselines : path
        Baseline folder (default ``studies/baselines``): ``<file stem>.nc`` per study.
    url, token : str, optional
        Run on an impactcell service (``service.client.Client``) instead of embedded.
    data_dir : path, optional
        Data root (default ``$IMPACTCELL_DATA_DIR`` or ``./data``). Embedded runs go to a fresh
        ``<data_dir>/nightly/<timestamp>/runs`` so results are never reused from an earlier run.
    update_baseline : bool
        Write the new results as baselines (the report lists what changed as ``updated``).
    report_dir : path, optional
        Where ``report.json`` and ``report.md`` go (default ``<data_dir>/nightly/<timestamp>``).
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    serial : bool
        Embedded, in this process, without dask.
    scheduler : str, optional
        ``tcp://host:port`` of a dask scheduler to run on instead of an embedded cluster.
    log : callable, optional
        Called with one line of progress per study.

    Raises
    ------
    SuiteError
        The suite folder or a study file in it is bad (nothing is run).
    """
    t0 = time.perf_counter()
    started = _now()
    entries = load_suite(directory)
    suite_dir = entries[0].path.parent
    base_dir = _resolve(baselines, DEFAULT_BASELINES)
    if base_dir.exists() and not base_dir.is_dir():
        raise SuiteError([f"baselines {base_dir} is not a folder"])
    run_dir = _stamp_dir(data_root(data_dir) / "nightly")
    reports = Path(report_dir) if report_dir is not None else run_dir
    say = log or (lambda _msg: None)

    client: Any = None
    cluster: Any = None
    results: list[StudyComparison] = []
    try:
        if url is not None:
            try:
                from service.client import Client
            except ImportError as exc:
                raise ValueError(
                    f"--url needs service.client, which cannot be imported: {exc}"
                ) from None
            client = Client(url, token=token)
        elif not serial and scheduler:
            from dask.distributed import Client as DaskClient

            client = DaskClient(scheduler, timeout="30s")
        elif not serial:
            client, cluster = _embedded_client(workers)
        for k, entry in enumerate(entries, 1):
            t = time.perf_counter()
            cmp = _run_one(entry, base_dir, run_dir / "runs", url, client, serial, update_baseline)
            cmp.wall_s = round(time.perf_counter() - t, 3)
            results.append(cmp)
            say(
                f"[{k}/{len(entries)}] {entry.stem}: {entry.study.size} points, "
                f"{cmp.wall_s:.1f} s, {cmp.status}"
                + (f" ({len(cmp.regressions)} changed points)" if cmp.regressions else "")
            )
    finally:
        if cluster is not None:
            client.close()
            cluster.close()
        elif client is not None and hasattr(client, "close"):
            client.close()

    notes = []
    if base_dir.is_dir():
        stems = {e.stem for e in entries}
        orphans = sorted(p.name for p in base_dir.glob("*.nc") if p.stem not in stems)
        if orphans:
            notes.append(f"baselines without a suite file (not used): {', '.join(orphans)}")
    report = NightlyReport(
        studies=results,
        suite=str(suite_dir),
        baselines=str(base_dir),
        mode=url
        or ("embedded, serial" if serial else f"dask {scheduler}" if scheduler else "embedded"),
        update_baseline=update_baseline,
        started=started,
        wall_s=round(time.perf_counter() - t0, 3),
        notes=notes,
    )
    report.write(reports)
    return report


def _run_one(
    entry: SuiteEntry,
    base_dir: Path,
    run_root: Path,
    url: str | None,
    client: Any,
    serial: bool,
    update: bool,
) -> StudyComparison:
    """Run one study, compare it with its baseline, write the baseline when updating."""
    bpath = base_dir / f"{entry.stem}.nc"
    label = {"study": entry.stem, "name": entry.study.name, "baseline": str(bpath)}
    try:
        if url is not None:
            # The service returns an identical earlier study as is; a run tag in the
            # description (ignored by the comparison) makes this a fresh run of today's code.
            definition = entry.study.canonical()
            tag = f"nightly run {run_root.parent.name}"
            definition["description"] = f"{definition.get('description') or ''} [{tag}]".strip()
            rec = client.submit(definition)
            client.wait(rec["id"], progress=False)
            ds = client.dataset(rec["id"])
            where = f"{url} study {rec['id']}"
        else:
            from service.runner import run_study

            summary = run_study(entry.study, run_root, client=client, serial=serial)
            ds = open_results(summary.path)
            where = str(summary.path)
    except Exception as exc:  # a run that could not finish is reported, not raised
        return StudyComparison(
            **label,
            study_id=entry.study.id,
            points=entry.study.size,
            status="error",
            error=f"run failed: {type(exc).__name__}: {exc}",
        )

    old: xr.Dataset | None = None
    unreadable = ""
    if bpath.exists():
        try:
            old = open_results(bpath)
        except ValueError as exc:
            unreadable = str(exc)
    if old is not None:
        try:
            cmp = compare(ds, old, entry.spec, study=entry.stem)
        except Exception as exc:  # a malformed baseline: report it, go on with the suite
            cmp = StudyComparison(
                study=entry.stem,
                name=entry.study.name,
                study_id=entry.study.id,
                points=entry.study.size,
                status="error",
                error=f"cannot compare with {bpath}: {type(exc).__name__}: {exc}",
            )
            unreadable = cmp.error
    else:
        cmp = StudyComparison(
            study=entry.stem,
            name=entry.study.name,
            study_id=str(ds.attrs.get("study_id", entry.study.id)),
            points=int(ds["failed"].size),
            counts={"new": _counts(ds)},
            new_info=_provenance(ds),
            status="error" if unreadable else "missing-baseline",
            error=unreadable
            or f"no baseline {bpath}; create it with `impactcell nightly --update-baseline`",
        )
    cmp.baseline, cmp.results = str(bpath), where
    if update:
        if cmp.error and (old is not None or unreadable):
            cmp.notes.append(f"replaced a baseline that could not be compared: {cmp.error}")
        cmp.error = None
        cmp.status = "updated" if bpath.exists() else "created"
        write_baseline(ds, bpath, entry.spec, source=str(entry.path.name))
    return cmp
