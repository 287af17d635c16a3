"""Helpers of the service tests (imported explicitly; conftest.py holds only fixtures)."""

from __future__ import annotations

from typing import Any

import xarray as xr

__all__ = ["FAST_SOLVER", "SLOW_SOLVER", "comparable", "tiny_study"]

# A coarse, fast solver: these tests check the service, not the numbers (tests/worker do that).
FAST_SOLVER = {"steps_per_period": 256, "max_periods": 60, "periodicity_tol": 1e-5, "window": 5}
# Tests that act mid-study need a study that lasts seconds even on a fast, idle machine.
SLOW_SOLVER = {"steps_per_period": 2048, "max_periods": 100, "periodicity_tol": 1e-13}


def tiny_study(name: str = "tiny", num: int = 8, gaps: tuple[float, ...] = (0.1, 0.5),
               **solver: Any) -> dict[str, Any]:  # fmt: skip
    """A small non-dimensional study definition (num × len(gaps) points)."""
    return {
        "name": name,
        "solver": {**FAST_SOLVER, **solver},
        "grid": {
            "gamma_r": {"start": 0.5, "stop": 3.0, "num": num},
            "gap": list(gaps),
            "theta": 0.3,
            "sigma": 0.05,
            "gamma_s": 1.0,
        },
    }


def comparable(ds: xr.Dataset) -> xr.Dataset:
    """A dataset without what differs between any two runs (``wall_s``, ``created``)."""
    out = ds.drop_vars("wall_s")
    out.attrs = {k: v for k, v in ds.attrs.items() if k != "created"}
    return out
