"""schemathesis against the OpenAPI schema of a real server: no 5xx for any generated request."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from service.api.server import ServerThread
from service.api.settings import Settings


@pytest.fixture(scope="module")
def api_schema(tmp_path_factory: pytest.TempPathFactory, dask_address: str) -> Iterator:
    data: Path = tmp_path_factory.mktemp("schema") / "data"
    # A small point limit: a generated study that happens to be valid stays cheap.
    s = Settings(host="127.0.0.1", port=0, data_dir=data, scheduler=dask_address, max_points=50)
    server = ServerThread(s).start()
    try:
        yield schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    finally:
        server.stop()


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_server_errors(case: schemathesis.Case) -> None:
    response = case.call()
    assert response.status_code < 500, (case.method, case.formatted_path, response.text[:500])
    ctype = response.headers.get("content-type", "")
    ctype = ctype[0] if isinstance(ctype, list) else ctype  # schemathesis: lists of values
    if ctype.startswith("application/json"):
        body = response.json()
        if response.status_code >= 400:
            assert isinstance(body.get("detail"), str) and body["detail"]
