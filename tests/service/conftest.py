"""Fixtures of the service tests: one real dask cluster and the catalogue databases.

Helpers (study definitions, dataset comparison) are in :mod:`tests.service.helpers`.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.settings import Settings
from tests.service.helpers import API_TOKEN

#: The host names of the in-process tests: Starlette's TestClient sends ``Host: testserver``.
TEST_HOSTS = "localhost,127.0.0.1,::1,testserver"


@pytest.fixture(autouse=True, scope="session")
def _test_hosts() -> Iterator[None]:
    """Let the service answer TestClient's host name besides its default loopback names (for
    the whole session: module-scoped apps are made before any test's own fixtures)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IMPACTCELL_ALLOWED_HOSTS", TEST_HOSTS)
        yield


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


@pytest.fixture(params=["sqlite", "postgresql"])
def catalogue_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The catalogue URL: a SQLite file, and PostgreSQL when CI provides one (emptied first)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'catalogue.sqlite'}"
        return
    url = os.environ.get("IMPACTCELL_TEST_DATABASE_URL")
    if not url:
        pytest.skip("PostgreSQL leg: IMPACTCELL_TEST_DATABASE_URL is not set (.ci/run sets it)")
    from sqlalchemy import create_engine, text

    from service.api.catalogue import _Base

    url, schema = _own_schema(url)
    engine = create_engine(url)
    with engine.begin() as conn:
        if schema:
            conn.execute(text(f'CREATE SCHEMA IF NOT EXISTS "{schema}"'))
        # the catalogue's tables, and the migrations' stamp, or the next start would trust it
        _Base.metadata.drop_all(conn)
        conn.execute(text("DROP TABLE IF EXISTS alembic_version"))
    engine.dispose()
    yield url


def _own_schema(url: str) -> tuple[str, str | None]:
    """``url`` for this test process alone, and its schema (``None``: outside xdist, the URL as
    it is). Under pytest-xdist (the README's ``-n 2``) both processes get the one database CI
    starts, and each empties it before its tests: a catalogue test in one process lost its
    tables to the other's. Each process gets its own schema instead (``search_path``, so the
    catalogue's unqualified tables and the migrations' stamp live there); the service under
    test reads the URL like any other."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if not worker:
        return url, None
    from sqlalchemy import make_url

    schema = f"impactcell_test_{worker}"
    own = make_url(url).update_query_dict({"options": f"-csearch_path={schema}"})
    return own.render_as_string(hide_password=False), schema


@pytest.fixture
def token_client(tmp_path: Path) -> Iterator[TestClient]:
    """An in-process app with the bearer token ``API_TOKEN`` and no job runner."""
    s = Settings(data_dir=tmp_path / "data", database_url=f"sqlite:///{tmp_path / 'c.sqlite'}",
                 api_token=API_TOKEN)  # fmt: skip
    with TestClient(create_app(s, run_jobs=False)) as client:
        yield client
