"""Shared fixtures of the service tests: one real dask cluster, study definitions, an app."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import xarray as xr

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


@pytest.fixture(scope="session")
def dask_address() -> Iterator[str]:
    """A real 2-process LocalCluster shared by the service tests."""
    from dask.distributed import LocalCluster

    from worker.simulate import warm_up

    # The workers load the kernels from numba's cache instead of both compiling them (the
    # runner does this for its own clusters; this one is reached by address).
    warm_up()

    cluster = LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
        silence_logs=40,
    )  # fmt: skip
    try:
        yield cluster.scheduler_address
    finally:
        cluster.close()


def database_urls(tmp: Path) -> list[str]:
    """SQLite always; PostgreSQL too when ``IMPACTCELL_TEST_DATABASE_URL`` is set (CI)."""
    urls = [f"sqlite:///{tmp / 'catalogue.sqlite'}"]
    pg = os.environ.get("IMPACTCELL_TEST_DATABASE_URL")
    if pg:
        urls.append(pg)
    return urls


@pytest.fixture(params=["sqlite", "postgresql"])
def catalogue_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The catalogue URL: a SQLite file, and PostgreSQL when CI provides one (emptied first)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'catalogue.sqlite'}"
        return
    url = os.environ.get("IMPACTCELL_TEST_DATABASE_URL")
    if not url:
        pytest.skip("PostgreSQL leg: IMPACTCELL_TEST_DATABASE_URL is not set (.ci/run sets it)")
    from sqlalchemy import create_engine

    from service.catalogue import _Base

    engine = create_engine(url)
    _Base.metadata.drop_all(engine)
    engine.dispose()
    yield url
