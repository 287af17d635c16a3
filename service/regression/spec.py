"""The ``regression:`` block of a nightly study file: tolerances and distribution checks.

Each file of the suite (:mod:`service.regression.suite`) is a normal study plus one extra
top-level block, ``regression:``, removed before the study is parsed (so it does not change the
study id)::

    regression:
      tolerances:                       # at points linear or periodic in both runs
        transmittance_db: {abs: 1.0e-3}     # |new - old| <= abs + rel * |old|
        theta_eff: {abs: 1.0e-3, rel: 1.0e-3}
        response_period: {exact: true}      # identical (missing == missing)
      irregular:                        # distributions over points irregular in both runs
        transmittance_db: {median_shift: 0.5, quantile_shift: 1.0, quantiles: [0.25, 0.5, 0.75]}

Variables not listed keep their defaults (:data:`DEFAULT_TOLERANCES`,
:data:`DEFAULT_IRREGULAR`). What the checks mean is in :mod:`service.regression.compare`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import Field, field_validator, model_validator

from service.studies.grid import Integer, Real, StrictModel
from service.studies.variables import VARIABLES

__all__ = [
    "COMPARABLE",
    "DEFAULT_IRREGULAR",
    "DEFAULT_TOLERANCES",
    "DISTRIBUTABLE",
    "IrregularCheck",
    "RegressionSpec",
    "Tolerance",
]

# Variables a tolerance may name (everything measured; not wall_s, failed, reason).
COMPARABLE = tuple(
    k for k, v in VARIABLES.items() if v.group and v.kind in ("float", "maskint", "int", "bool")
)
# Variables a distribution check may name.
DISTRIBUTABLE = tuple(k for k, v in VARIABLES.items() if v.group and v.kind == "float")
# Variables of solver version 1 that are gone, and what replaced them (for the error message).
_RENAMED = {"theta_eff_mean": "theta_eff_slope", "converged": "outcome"}
# Always kept in a baseline: how every point ended (and, for older readers, failed/period).
# ``reason`` tells a sensitive point (one that may be transient chaos) from a regression.
_ALWAYS = ("outcome", "response_period", "failed", "reason")


def _replaced(name: str) -> str:
    new = _RENAMED.get(str(name))
    return f" (replaced by {new} in solver version 2)" if new else ""


class Tolerance(StrictModel):
    """How far a variable may move at periodic points: ``abs + rel·|old|``, or ``exact``."""

    abs: Real | None = Field(None, ge=0)
    rel: Real | None = Field(None, ge=0)
    exact: bool = False

    @model_validator(mode="after")
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


class IrregularCheck(StrictModel):
    """Distribution checks of one variable over irregular points (see the module doc)."""

    median_shift: Real | None = Field(None, ge=0)
    quantile_shift: Real | None = Field(None, ge=0)
    quantiles: list[Real] = Field(default_factory=lambda: [0.25, 0.5, 0.75], min_length=1)
    ks_pvalue: Real | None = Field(None, gt=0, lt=1)
    min_points: Integer = Field(5, ge=1)
    # Point by point where the variable has a standard error (``<variable>_se``): moved if
    # |new - old| > error_bars * sqrt(se_old² + se_new²). None: not compared point by point.
    error_bars: Real | None = Field(4.0, gt=0)

    @field_validator("quantiles")
    @classmethod
    def _unit(cls, v: list[float]) -> list[float]:
        bad = [q for q in v if not 0.0 <= q <= 1.0]
        if bad:
            raise ValueError(f"quantiles must be in [0, 1], got {bad[0]:g}")
        return v

    @model_validator(mode="after")
    def _check(self) -> IrregularCheck:
        checks = (self.median_shift, self.quantile_shift, self.ks_pvalue, self.error_bars)
        if all(c is None for c in checks):
            raise ValueError(
                "give at least one of median_shift, quantile_shift, ks_pvalue, error_bars"
            )
        return self


DEFAULT_TOLERANCES: dict[str, Tolerance] = {
    "transmittance_db": Tolerance(abs=1e-3),
    "response_period": Tolerance(exact=True),
    # the attraction rate a point reports: computed to round-off (event's exact monodromy
    # matrix) or to the finite differences' truncation (up to ~1e-2); a multiplier that
    # appears or goes is a change too
    "floquet_multiplier": Tolerance(abs=1e-6),
}
DEFAULT_IRREGULAR: dict[str, IrregularCheck] = {
    "transmittance_db": IrregularCheck(median_shift=0.5, quantile_shift=1.0),
}


class RegressionSpec(StrictModel):
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
        irregular = self.effective_irregular()
        errors = {f"{k}_se" for k, c in irregular.items() if c.error_bars is not None}
        names = set(_ALWAYS) | set(self.effective_tolerances()) | set(irregular) | errors
        return [k for k in VARIABLES if k in names]
