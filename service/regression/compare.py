"""Comparing a study's new results with its baseline, point by point and by distribution.

Every point is first compared by its ``outcome`` class: linear or periodic, irregular,
unsettled, failed. A point whose class changed (periodic <-> irregular, anything <-> failed,
irregular <-> unsettled, ...) is a regression, reported with its old and new outcome, unless
the point is *sensitive* in either run: an irregular claim that may be transient chaos (the
impact-free response is admissible too, ``TRANSIENT_NOTE`` in its reason) or an orbit whose
Floquet multiplier is at least ``SENSITIVE_MULTIPLIER`` (next to a bifurcation). Where such a
point ends depends on the last bits of its trajectory, so its change is listed as sensitive,
not counted as a regression. Points unsettled in both runs are not compared (their numbers are
not proven). At points linear or periodic in both runs each variable is held to its tolerance
(:class:`~service.regression.spec.Tolerance`).

Irregular points are compared point by point within their error bars: a variable with a
standard error (``transmittance_db_se``) moved if ``|new - old| > error_bars·√(se_old² +
se_new²)`` (default 4 combined standard errors). They are also compared by distribution.
``median_shift`` bounds the median of the paired differences (new - old at
points irregular in both runs; robust with few points and insensitive to how Γ varies along
the grid); ``quantile_shift`` bounds the shift of the quantiles of each run's values at those
points; ``ks_pvalue`` (optional) fails when a two-sample Kolmogorov-Smirnov test gives a smaller
p-value. A check with fewer than ``min_points`` points is skipped (and says so).

A baseline made by another solver version (``solver_version`` attribute; files of solver
version 1 have no ``outcome``) is not comparable: the study is reported as an error telling to
re-cut the baselines with ``impactcell nightly --update-baseline``, and the differences found
(reading an old baseline's outcome from ``response_period``: 0 = irregular) are listed for
information.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr

from service.regression.spec import IrregularCheck, RegressionSpec, Tolerance
from service.studies.dataset import json_number, summarize
from service.studies.variables import OUTCOMES, outcome_names
from worker.cpu import FINGERPRINT_KEYS
from worker.simulate import SOLVER_VERSION
from worker.solvers.engine import TRANSIENT_NOTE

__all__ = [
    "SENSITIVE_MULTIPLIER",
    "Change",
    "DistributionCheck",
    "StudyComparison",
    "compare",
    "outcomes_of",
    "provenance_of",
]

# Outcome classes: a point moving between classes is a regression.
_STEADY = ("linear", "periodic")
_CLASS = {k: ("linear/periodic" if k in _STEADY else k) for k in OUTCOMES}
_CLASSES_TEXT = "same outcome class (linear/periodic, irregular, unsettled, failed)"
# An orbit this close to losing its stability ends otherwise on a change in its last bits.
SENSITIVE_MULTIPLIER = 0.98


# --------------------------------------------------------------------------- comparison results


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
    ``cancelled`` (its study was cancelled before it finished), ``missing-baseline``, and with
    ``--update-baseline`` ``updated`` or ``created``.
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


def provenance_of(ds: xr.Dataset) -> dict[str, str]:
    """The provenance attributes of a results dataset or baseline, as text."""
    keys = (*_PROVENANCE, "baseline_created", "git_dirty")
    return {k: str(ds.attrs[k]) for k in keys if k in ds.attrs}


def outcomes_of(ds: xr.Dataset) -> np.ndarray:
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
        if a.dtype.kind in "US" or b.dtype.kind in "US":  # labels: direction, initial
            same = a.shape == b.shape and bool(np.all(a.astype(str) == b.astype(str)))
        else:
            same = a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-12, atol=0))
        if not same:
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
    # Labels, not what is computed: a run tag (nightly runs through a service) included.
    return {k: v for k, v in d.items() if k not in ("name", "description", "tag")}


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
        # a label (sweep direction, initial state) as itself, a number JSON-safe
        out[str(name)] = str(v) if v.dtype.kind in "US" else json_number(v)  # type: ignore[assignment]
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
        Results datasets (:func:`service.studies.dataset.open_results`) of the same study grid.
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
        new_info=provenance_of(new),
        baseline_info=provenance_of(baseline),
    )
    stale = _stale(new, baseline)
    problems = _grid_problems(new, baseline)
    if problems:
        out.status, out.error = "error", "; ".join(([stale] if stale else []) + problems)
        return out
    out.points = int(new["failed"].size)
    out.counts = {
        "new": summarize(new, outcomes_of(new)),
        "baseline": summarize(baseline, outcomes_of(baseline)),
    }
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
    # The CPU target and library stack (worker.cpu.fingerprint): another rounds differently, and
    # grazing or chaotic points can then end otherwise, which this note explains.
    for key in ("solver_version", "impactcell_version", "git_commit", *FINGERPRINT_KEYS):
        a, b = baseline.attrs.get(key), new.attrs.get(key)
        if a is not None and b is not None and a != b:
            out.notes.append(f"{key}: baseline {a}, new {b}")

    dims = tuple(str(d) for d in new["failed"].dims)
    o_new, o_old = outcomes_of(new), outcomes_of(baseline.transpose(*dims, ...))
    c_new = np.vectorize(_CLASS.get, otypes=[object])(o_new)
    c_old = np.vectorize(_CLASS.get, otypes=[object])(o_old)
    steady = np.isin(o_new, _STEADY) & np.isin(o_old, _STEADY)
    irr_new, irr_old = o_new == "irregular", o_old == "irregular"
    grid = new["failed"]
    reason = new["reason"].values if "reason" in new else None

    s_new, s_old = _sensitive(new, dims), _sensitive(baseline, dims)
    sensitive = np.where(s_new != "", s_new, s_old)
    for i in np.flatnonzero(c_new != c_old):
        note = str(reason.flat[i]) if reason is not None else ""
        why = sensitive.flat[i]
        out.changes.append(
            Change("outcome", "outcome", _coords_at(grid, int(i)), str(o_old.flat[i]),
                   str(o_new.flat[i]), None, _CLASSES_TEXT, regression=not why,
                   note=f"sensitive: {why}; {note}" if why else note)
        )  # fmt: skip
    n_sensitive = sum(1 for c in out.changes if c.kind == "outcome" and not c.regression)
    if n_sensitive:
        out.notes.append(
            f"{n_sensitive} outcome changes at sensitive points (may be transient chaos, or "
            f"Floquet multiplier >= {SENSITIVE_MULTIPLIER:g}): listed, not regressions"
        )
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
                Change("moved", var, _coords_at(a, int(i)), json_number(o), json_number(n),
                       json_number(delta), tol.describe())
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
        if chk.error_bars is not None:
            both = _on(irr_old & irr_new, a, dims)
            _within_error_bars(out, var, chk.error_bars, a, old_v, new, baseline, both)
        out.distribution += _distribution(
            var, chk, old_v, new_v, _on(irr_old, a, dims), _on(irr_new, a, dims)
        )

    out.status = "failed" if out.has_regressions() else "passed"
    return out


def _sensitive(ds: xr.Dataset, dims: tuple[str, ...]) -> np.ndarray:
    """Why each point of ``ds`` is sensitive ("" where it is not): an irregular claim that may be
    transient chaos, or an orbit next to a bifurcation (see the module doc)."""
    shape = tuple(ds.sizes[d] for d in dims)
    why = np.full(shape, "", dtype=object)
    if "floquet_multiplier" in ds and set(ds["floquet_multiplier"].dims) == set(dims):
        rho = np.asarray(ds["floquet_multiplier"].transpose(*dims).values, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            near = np.isfinite(rho) & (rho >= SENSITIVE_MULTIPLIER)
        why[near] = "Floquet multiplier near 1"
    if "may_be_transient" in ds and set(ds["may_be_transient"].dims) == set(dims):
        flag = np.asarray(ds["may_be_transient"].transpose(*dims).values)
        why[flag.astype(bool)] = "may be transient chaos"
    elif "reason" in ds and set(ds["reason"].dims) == set(dims):  # a file without the flag
        text = ds["reason"].transpose(*dims).values.astype(str)
        why[np.char.find(text, TRANSIENT_NOTE) >= 0] = "may be transient chaos"
    return why


def _within_error_bars(
    out: StudyComparison,
    var: str,
    z: float,
    a: xr.DataArray,
    old_v: np.ndarray,
    new: xr.Dataset,
    baseline: xr.Dataset,
    both: np.ndarray,
) -> None:
    """Points irregular in both runs whose ``var`` (``a``, new; ``old_v``, the baseline's
    aligned to it) moved by more than ``z`` combined standard errors (``<var>_se``) go to
    ``out.changes``; a point without an error bar is not compared."""
    se = f"{var}_se"
    if se not in new or se not in baseline:
        out.notes.append(f"{var}: not compared within error bars ({se} not in both datasets)")
        return
    new_v = np.asarray(a.values, dtype=np.float64)
    _, se_old = _aligned(new, baseline, se)
    se_new = np.asarray(new[se].transpose(*a.dims).values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        limit = z * np.hypot(se_old, se_new)
        moved = both & np.isfinite(limit) & (np.abs(new_v - old_v) > limit)
    for i in np.flatnonzero(moved):
        o, n = old_v.flat[i], new_v.flat[i]
        out.changes.append(
            Change("moved", var, _coords_at(a, int(i)), json_number(o), json_number(n),
                   json_number(abs(n - o)),
                   f"within {z:g} combined standard errors ({limit.flat[i]:.3g})")
        )  # fmt: skip


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
            DistributionCheck(var, check, json_number(value), limit, passed, no, nn, npair, skipped,
                              detail if not skipped else {})
        )  # fmt: skip

    if chk.median_shift is not None:
        v = float(abs(np.median(d))) if npair else None
        add("median_shift", v, chk.median_shift, v is not None and v <= chk.median_shift,
            mean_shift=json_number(np.mean(d)) if npair else None)  # fmt: skip
    if chk.quantile_shift is not None:
        if npair:
            qo, qn = np.quantile(xo, chk.quantiles), np.quantile(xn, chk.quantiles)
            v = float(np.max(np.abs(qn - qo)))
            detail = {
                f"q{q:g}": {"old": json_number(a), "new": json_number(b)}
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
