"""Cross-site safety, NUL characters, strict types, error bodies and the heavy-read pool, in
process (the real server and a browser: ``tests/service/web/test_cross_site.py``)."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import jsonschema
import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient

from service.api import app as app_module
from service.api.admission import Admission
from service.api.app import create_app
from service.api.guard import hide_paths, host_allowed
from service.api.settings import Settings
from tests.service.helpers import JSON_BODY, tiny_study

OWN = "http://127.0.0.1:8000"


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return Settings(data_dir=tmp_path / "data", database_url=f"sqlite:///{tmp_path / 'c.db'}",
                    **kw)  # fmt: skip


@pytest.fixture
def tc(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[TestClient]:
    """The app with the default host names, addressed as http://127.0.0.1:8000."""
    monkeypatch.delenv("IMPACTCELL_ALLOWED_HOSTS")
    app = create_app(_settings(tmp_path), run_jobs=False)
    with TestClient(app, base_url=OWN, raise_server_exceptions=False) as client:
        yield client


def _submit(tc: TestClient) -> str:
    r = tc.post("/studies", json=tiny_study())
    assert r.status_code == 202, r.text
    return r.json()["id"]


def _status(tc: TestClient, sid: str) -> str:
    return tc.get(f"/studies/{sid}").json()["status"]


# --------------------------------------------------------------------------- Host


def test_a_host_the_service_does_not_serve_is_400(tc: TestClient) -> None:
    for host in ("127.0.0.1:8000", "localhost:8000", "LOCALHOST", "[::1]:8000", "localhost."):
        assert tc.get("/health", headers={"host": host}).status_code == 200, host
    for host in ("evil.example", "evil.example:8000", "127.0.0.1.evil.example", "10.0.0.1"):
        for path in ("/health", "/studies", "/"):
            r = tc.get(path, headers={"host": host})
            assert r.status_code == 400, (host, path)
            assert "IMPACTCELL_ALLOWED_HOSTS" in r.json()["detail"]


def test_allowed_hosts_name_the_hosts_served(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("IMPACTCELL_ALLOWED_HOSTS")
    s = _settings(tmp_path, allowed_hosts="impactcell.example.org, *.lab.example")
    assert s.host_names() == ("impactcell.example.org", "*.lab.example")
    assert host_allowed("impactcell.example.org:443", s.host_names())
    assert host_allowed("a.lab.example", s.host_names())
    assert not host_allowed("lab.example.evil", s.host_names())
    assert not host_allowed("localhost", s.host_names())
    assert host_allowed("anything", _settings(tmp_path, allowed_hosts="*").host_names())
    # bound to a specific address, it answers to that address too
    assert "192.0.2.7" in _settings(tmp_path, host="192.0.2.7").host_names()
    assert "0.0.0.0" not in _settings(tmp_path, host="0.0.0.0").host_names()
    with pytest.raises(ValueError, match="allowed_hosts must be .*got 'http://x'"):
        _settings(tmp_path, allowed_hosts="http://x")


# --------------------------------------------------------------------------- state changes


@pytest.mark.parametrize("kind", [None, "text/plain", "application/x-www-form-urlencoded",
                                  "multipart/form-data; boundary=x"])  # fmt: skip
def test_state_changes_without_a_json_or_yaml_type_are_415(tc: TestClient, kind: str) -> None:
    sid = _submit(tc)
    headers = {"content-type": kind} if kind else {}
    body = b'{"name": "x"}'
    r = tc.post("/studies", content=body, headers=headers)
    assert r.status_code == 415 and "Content-Type" in r.json()["detail"]
    for method, path in [("POST", f"/studies/{sid}/cancel"), ("DELETE", f"/studies/{sid}"),
                         ("POST", "/regressions")]:  # fmt: skip
        r = tc.request(method, path, headers=headers)
        assert r.status_code == 415, (method, path)
    assert _status(tc, sid) == "queued" and tc.get("/studies").json()["total"] == 1


def test_a_page_of_another_origin_cannot_change_state(tc: TestClient) -> None:
    sid = _submit(tc)
    for origin in (
        "http://evil.example",
        "null",
        "http://127.0.0.1:8001",
        "https://127.0.0.1:8000",
    ):
        headers = {"origin": origin, **JSON_BODY}
        r = tc.post("/studies", json=tiny_study(name="x", num=3), headers={"origin": origin})
        assert r.status_code == 403 and "another origin" in r.json()["detail"], origin
        assert tc.post(f"/studies/{sid}/cancel", headers=headers).status_code == 403
        assert tc.delete(f"/studies/{sid}", headers=headers).status_code == 403
        assert tc.post("/regressions", headers=headers).status_code == 403
    assert _status(tc, sid) == "queued" and tc.get("/studies").json()["total"] == 1
    # reading is not a state change; the service's own page may change state
    assert tc.get("/studies", headers={"origin": "http://evil.example"}).status_code == 200
    r = tc.post(f"/studies/{sid}/cancel", headers={"origin": OWN, **JSON_BODY})
    assert r.status_code == 200 and r.json()["status"] == "cancelled"


def test_allowed_origins_may_change_state(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IMPACTCELL_ALLOWED_HOSTS", "127.0.0.1")
    s = _settings(tmp_path, allowed_origins="https://impactcell.example.org")
    with TestClient(create_app(s, run_jobs=False), base_url=OWN) as tc:
        headers = {"origin": "https://impactcell.example.org"}
        assert tc.post("/studies", json=tiny_study(), headers=headers).status_code == 202
        headers = {"origin": "https://other.example.org"}
        assert tc.post("/studies", json=tiny_study(), headers=headers).status_code == 403
    with pytest.raises(ValueError, match="allowed_origins must be"):
        _settings(tmp_path, allowed_origins="impactcell.example.org")


# --------------------------------------------------------------------------- NUL, strict types


def _problems(r: httpx.Response) -> dict[str, str]:
    assert r.status_code == 422, r.text
    return {p["path"]: p["message"] for p in r.json()["problems"]}


def test_nul_characters_are_422_naming_the_field(tc: TestClient) -> None:
    nul = "must not contain a NUL character"
    assert _problems(tc.get("/studies?name=a%00b")) == {"query.name": nul}
    assert _problems(tc.get("/points?method=%00&limit=5")) == {"query.method": nul}
    d = tiny_study(name="a\x00b")
    d["description"] = "ok\x00"
    assert _problems(tc.post("/studies", json=d)) == {"name": nul, "description": nul}
    report = {"report": {"ok": True, "summary": "x\x00", "studies": []}}
    r = tc.post("/regressions/reports", json=report)
    assert r.status_code == 422 and "report.summary" in r.json()["detail"]
    assert tc.get("/studies").json()["total"] == 0 and tc.get("/regressions").json()["total"] == 0


def test_nul_characters_never_reach_the_database(tmp_path: Path, catalogue_url: str) -> None:
    """On SQLite and PostgreSQL (which refuses NUL in text: a 500 with the SQL before)."""
    s = Settings(data_dir=tmp_path / "data", database_url=catalogue_url)
    with TestClient(create_app(s, run_jobs=False), raise_server_exceptions=False) as tc:
        for url in ("/studies?name=%00", "/points?method=a%00&limit=1", "/points?version=%00"):
            r = tc.get(url)
            assert r.status_code == 422 and "NUL" in r.json()["detail"], (url, r.text)
        r = tc.post("/studies", json=tiny_study(name="x\x00"))
        assert r.status_code == 422 and r.json()["problems"][0]["path"] == "name"
        assert tc.get("/studies?name=x").json()["total"] == 0


def test_numbers_and_booleans_are_not_text(tc: TestClient) -> None:
    d = tiny_study()
    d["grid"]["theta"] = "0.3"
    d["grid"]["gamma_r"]["num"] = "8"
    d["outputs"] = {"contact": "yes", "response": 1}
    got = _problems(tc.post("/studies", json=d))
    assert "the text '0.3'" in got["grid.theta"] and "the text '8'" in got["grid.gamma_r.num"]
    assert set(got) >= {"outputs.contact", "outputs.response"}
    for report in ({"ok": "yes", "summary": "s", "studies": []},
                   {"ok": True, "summary": 1, "studies": []}):  # fmt: skip
        r = tc.post("/regressions/reports", json={"report": report})
        assert r.status_code == 422, report
    # YAML reads 1e-1 (no dot) as the number JSON reads
    yaml_text = "name: y\ngrid: {gamma_r: {start: 5e-1, stop: 3, num: 4}, gap: 0.1, theta: 3e-1, "
    yaml_text += "sigma: 0.05, gamma_s: 1}\n"
    r = tc.post("/studies", content=yaml_text, headers={"content-type": "application/yaml"})
    assert r.status_code == 202, r.text
    assert r.json()["definition"]["grid"]["theta"] == 0.3


# --------------------------------------------------------------------------- error bodies


def _resolver_schema(openapi: dict[str, Any], path: str, method: str, code: str) -> Any:
    ref = openapi["paths"][path][method]["responses"][code]["content"]["application/json"]
    return {"$ref": ref["schema"]["$ref"], "components": openapi["components"]}


def test_every_422_matches_the_openapi_schema(tc: TestClient) -> None:
    openapi = tc.get("/openapi.json").json()
    text = str(openapi)
    assert "HTTPValidationError" not in text and "ValidationError'" not in text
    sid = _submit(tc)
    cases = [
        ("get", "/studies", "/studies?limit=0"),
        ("get", "/studies", "/studies?status=nope"),
        ("get", "/points", "/points?limit=x&gap=y"),
        ("get", "/regressions/{reg_id}", "/regressions/0"),
        ("get", "/studies/{study_id}/data", f"/studies/{sid}/data?format=xml"),
        ("get", "/studies/{study_id}/timeseries", f"/studies/{sid}/timeseries?periods=0"),
        ("post", "/studies", "/studies"),
        ("post", "/regressions/reports", "/regressions/reports"),
    ]
    for method, path, url in cases:
        if method == "post":
            r = tc.post(url, json={"report": {"ok": "x"}} if "reports" in url else {"grid": 1})
        else:
            r = tc.get(url)
        assert r.status_code == 422, (url, r.text)
        jsonschema.validate(r.json(), _resolver_schema(openapi, path, method, "422"))
    # every error status of every operation is described by ErrorOut, the guard's included
    for path, ops in openapi["paths"].items():
        for method, op in ops.items():
            codes = set(op["responses"])
            assert {"400", "422"} <= codes, (method, path)
            if method in ("post", "delete"):
                assert {"403", "415"} <= codes, (method, path)
    assert "503" in openapi["paths"]["/studies/{study_id}/plots/{kind}.{fmt}"]["get"]["responses"]
    assert "503" not in openapi["paths"]["/health"]["get"]["responses"]


def test_an_internal_error_answers_no_sql_and_no_path(
    tc: TestClient, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    secret = "(psycopg.errors.X) SELECT * FROM studies WHERE name = %(n)s; /srv/impactcell/data"

    def broken(*a: Any, **kw: Any) -> Any:
        raise RuntimeError(secret)

    monkeypatch.setattr(tc.app.state.catalogue, "list_studies", broken)
    with caplog.at_level("ERROR", logger="impactcell.app"):
        r = tc.get("/studies")
    assert r.status_code == 500
    detail = r.json()["detail"]
    assert "SELECT" not in detail and "/srv" not in detail and "RuntimeError" in detail
    ref = detail.rsplit(" ", 1)[-1]
    assert any(ref in rec.getMessage() for rec in caplog.records)  # the log has the reference
    assert app_module.log.name == "impactcell.app"


def test_stored_errors_show_file_names_not_server_paths() -> None:
    text = "OSError: [Errno 28] No space left: '/srv/data/studies/ab/chunk-3.nc'"
    assert hide_paths(text) == "OSError: [Errno 28] No space left: 'chunk-3.nc'"
    hint = "POST /studies/ab12/resume continues; see http://host/a/b"
    assert hide_paths(hint) == hint


def test_regression_reports_show_no_server_paths(tc: TestClient) -> None:
    import datetime as dt

    from service.regression.suite import suite_folders

    data = str(tc.app.state.settings.data_dir.resolve())
    suite, baselines = suite_folders()  # the shipped suite: the service's default
    cat = tc.app.state.catalogue
    reg = cat.add_finished_regression(
        "cron", started_at=dt.datetime.now(dt.UTC), ok=False, summary="1 study",
        report={"suite": str(suite), "baselines": str(baselines),
                "studies": [{"results": f"{data}/nightly/run/tiny.nc"}]},
        markdown=f"see {data}/nightly/run",
    )  # fmt: skip
    r = tc.get(f"/regressions/{reg}")
    assert r.status_code == 200 and data not in r.text and str(suite) not in r.text
    report = r.json()["report"]
    assert report["studies"][0]["results"] == "<data>/nightly/run/tiny.nc"
    assert (report["suite"], report["baselines"]) == ("./nightly", "./baselines")
    md = tc.get(f"/regressions/{reg}?format=markdown").text
    assert md == "see <data>/nightly/run"


# --------------------------------------------------------------------------- heavy reads


def test_the_pool_refuses_beyond_its_queue_with_retry_after() -> None:
    pool = Admission(workers=1, queue=1)
    release = threading.Event()

    async def main() -> list[Any]:
        tasks = [asyncio.ensure_future(pool.run(release.wait)) for _ in range(2)]
        await asyncio.sleep(0.05)
        assert pool.admitted == 2
        with pytest.raises(HTTPException) as refused:
            await pool.run(release.wait)
        release.set()
        return [refused.value, *await asyncio.gather(*tasks)]

    try:
        refused, *done = asyncio.run(main())
    finally:
        pool.close()
    assert refused.status_code == 503 and 1 <= int(refused.headers["Retry-After"]) <= 60
    assert done == [True, True] and pool.admitted == 0


def test_health_answers_while_the_heavy_pool_is_full(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from service.api.routes import results

    release = threading.Event()

    def stuck(*a: Any, **kw: Any) -> Any:
        release.wait(30)
        raise HTTPException(404, "released")

    monkeypatch.setattr(results, "load_dataset", stuck)
    s = _settings(tmp_path, heavy_workers=2, heavy_queue=2)
    with TestClient(create_app(s, run_jobs=False)) as tc:
        url = "/studies/" + "a" * 64 + "/data"
        codes: list[int] = []

        def ask() -> None:
            codes.append(tc.get(url).status_code)

        threads = [threading.Thread(target=ask) for _ in range(4)]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 10
        while tc.app.state.admission.admitted < 4 and time.monotonic() < deadline:
            time.sleep(0.01)
        r = tc.get(url)  # a fifth: over the queue
        assert r.status_code == 503 and int(r.headers["retry-after"]) >= 1
        t0 = time.monotonic()
        assert tc.get("/health").status_code == 200
        assert time.monotonic() - t0 < 1.0
        release.set()
        for t in threads:
            t.join(30)
    assert sorted(codes) == [404] * 4  # each admitted one ran to its own answer
