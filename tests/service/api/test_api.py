"""Many small API tests, in process (TestClient: the real app, its lifespan, no network)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr
import yaml
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.catalogue import STATUSES
from service.api.settings import Settings
from service.client import (
    Client,
    Conflict,
    InvalidRequest,
    NotFound,
    PayloadTooLarge,
    Unauthorized,
)
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from service.studies.variables import OUTCOMES, outcome_names
from tests.service.helpers import (
    JSON_BODY,
    SLOW_SOLVER,
    AppTransport,
    comparable,
    tiny_study,
)


class App:
    """A running app (lifespan on) and a client talking to it through the ASGI transport."""

    def __init__(self, settings: Settings, run_jobs: bool) -> None:
        self.settings = settings
        self.tc = TestClient(create_app(settings, run_jobs=run_jobs))

    def __enter__(self) -> App:
        self.tc.__enter__()
        self.http = self.tc
        self.client = Client("http://testserver", transport=AppTransport(self.tc),
                             token=self.settings.api_token or "")  # fmt: skip
        return self

    def __exit__(self, *exc: object) -> None:
        self.tc.__exit__(None, None, None)


@pytest.fixture
def make_app(tmp_path: Path, catalogue_url: str, request: pytest.FixtureRequest) -> Iterator[Any]:
    """An app factory; the real cluster is started only for an app that runs jobs (those tests
    are marked slow: without jobs the API is exercised in process, with no cluster)."""

    def make(run_jobs: bool = False, **kw: Any) -> App:
        scheduler = request.getfixturevalue("dask_address") if run_jobs else None
        s = Settings(data_dir=tmp_path / "data", database_url=catalogue_url,
                     scheduler=scheduler, **kw)  # fmt: skip
        return App(s, run_jobs)

    yield make


def test_health_needs_no_token_and_reports_versions(make_app: Any) -> None:
    with make_app(api_token="s3cret") as app:
        r = app.http.get("/health")
        assert r.status_code == 200
        body = r.json()
        assert body["status"] == "ok" and body["solver_version"]
        assert set(body["studies"]) == set(STATUSES)


def test_submit_is_idempotent_json_and_yaml(make_app: Any) -> None:
    d = tiny_study()
    with make_app() as app:
        r = app.http.post("/studies", json=d)
        assert r.status_code == 202
        sid = r.json()["id"]
        assert r.headers["location"] == f"/studies/{sid}"
        assert r.json()["status"] == "queued" and r.json()["points_total"] == 16
        again = app.http.post("/studies", json=d)
        assert again.status_code == 200 and again.json()["id"] == sid
        as_yaml = app.http.post("/studies", content=yaml.safe_dump(d),
                                headers={"Content-Type": "application/yaml"})  # fmt: skip
        assert as_yaml.status_code == 200 and as_yaml.json()["id"] == sid
        listed = app.http.get("/studies").json()
        assert listed["total"] == 1  # never a duplicate


def test_invalid_study_lists_every_problem_with_its_path(make_app: Any) -> None:
    d = tiny_study()
    d["grid"]["gamma_r"] = {"start": 1.0, "stop": 0.5, "num": 0}
    d["solver"]["method"] = "rk4"
    with make_app() as app:
        with pytest.raises(InvalidRequest) as err:
            app.client.submit(d)
        paths = {p["path"] for p in err.value.problems}
        assert any(p.startswith("solver.method") for p in paths), paths
        assert any(p.startswith("grid.gamma_r") for p in paths), paths
        assert "rk4" in err.value.message or "method" in err.value.message


@pytest.mark.parametrize(
    ("body", "ctype", "status"),
    [
        (b"{not json", "application/json", 400),
        (b"a: [1, 2", "application/yaml", 400),
        (b"[1, 2, 3]", "application/json", 422),
        (b"name: x", "text/plain", 415),
        (b"\xff\xfe", "application/json", 400),
    ],
)
def test_bad_bodies_get_clear_4xx(make_app: Any, body: bytes, ctype: str, status: int) -> None:
    with make_app() as app:
        r = app.http.post("/studies", content=body, headers={"Content-Type": ctype})
        assert r.status_code == status, r.text
        assert isinstance(r.json()["detail"], str) and r.json()["detail"]


def test_body_over_limit_is_413_with_and_without_length(make_app: Any) -> None:
    d = tiny_study()
    d["description"] = "x" * 5000
    with make_app(max_body_bytes=2048) as app:
        with pytest.raises(PayloadTooLarge):
            app.client.submit(d)

        def chunks() -> Iterator[bytes]:  # no Content-Length: streamed, counted as it comes
            text = json.dumps(d).encode()
            for i in range(0, len(text), 500):
                yield text[i : i + 500]

        headers = {"Content-Type": "application/json"}
        r = app.http.post("/studies", content=chunks(), headers=headers)
        assert r.status_code == 413
        assert "2048" in r.json()["detail"]


def test_grid_over_point_limit_is_422(make_app: Any) -> None:
    with make_app(max_points=10) as app:
        with pytest.raises(InvalidRequest) as err:
            app.client.submit(tiny_study())
        assert "16" in err.value.message and "10" in err.value.message


@pytest.mark.parametrize("sid", ["0123456789abcdef0123", "..%2F..%2Fetc", "ZZZZ", "a" * 64])
def test_unknown_or_malformed_ids_are_404(make_app: Any, sid: str) -> None:
    with make_app() as app:
        for path in ("", "/dataset", "/data", "/bandgap", "/timeseries", "/plots/bandgap.png"):
            r = app.http.get(f"/studies/{sid}{path}")
            assert r.status_code == 404, (path, r.text)
        assert app.http.delete(f"/studies/{sid}", headers=JSON_BODY).status_code == 404
        with pytest.raises(NotFound):
            app.client.get(sid)


def test_list_filters_and_pages(make_app: Any) -> None:
    with make_app() as app:
        ids = [app.client.submit(tiny_study(name=f"scan-{i}", num=4 + i))["id"] for i in range(5)]
        app.client.submit(tiny_study(name="other", num=3))
        app.client.cancel(ids[0])
        assert {r["id"] for r in app.client.list(name="scan")} == set(ids)
        assert [r["id"] for r in app.client.list(status="cancelled")] == [ids[0]]
        page = app.http.get("/studies", params={"limit": 2, "offset": 1}).json()
        assert page["total"] == 6 and len(page["items"]) == 2
        assert page["items"][0]["name"] == "scan-4"  # newest first, offset 1
        r = app.http.get("/studies", params={"status": "sleeping"})
        assert r.status_code == 422 and "sleeping" in r.json()["detail"]


def test_cancel_and_resume_state_rules(make_app: Any) -> None:
    with make_app() as app:
        sid = app.client.submit(tiny_study())["id"]
        rec = app.client.cancel(sid)
        assert rec["status"] == "cancelled" and rec["finished_at"]
        with pytest.raises(Conflict, match="only queued or running"):
            app.client.cancel(sid)
        assert app.client.resume(sid)["status"] == "queued"
        with pytest.raises(Conflict, match="only cancelled or failed"):
            app.client.resume(sid)


def test_auth_on_and_off(make_app: Any) -> None:
    with make_app(api_token="s3cret") as app:
        assert app.http.get("/studies").status_code == 401
        r = app.http.get("/studies", headers={"Authorization": "Bearer wrong"})
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
        r = app.http.post("/studies", json=tiny_study())
        assert r.status_code == 401
        ok = app.http.get("/studies", headers={"Authorization": "Bearer s3cret"})
        assert ok.status_code == 200
        with pytest.raises(Unauthorized):
            Client("http://testserver", transport=AppTransport(app.tc), token="nope").list()
        good = Client("http://testserver", transport=AppTransport(app.tc), token="s3cret")
        assert good.submit(tiny_study())["status"] == "queued"
    with make_app() as app:  # no token configured: open
        assert app.http.get("/studies").status_code == 200


def _run_part(settings: Settings, d: dict[str, Any], chunks: int) -> None:
    """Compute the first ``chunks`` chunks of a study straight through the runner."""
    study = parse_study(d)
    seen = {"n": 0}

    def on_chunk(*_: Any) -> None:
        seen["n"] += 1

    s = run_study(study, settings.data_dir, serial=True, chunk_size=4, on_chunk=on_chunk,
                  cancel=lambda: seen["n"] >= chunks)  # fmt: skip
    assert s.cancelled


def test_partial_dataset_and_slices_while_unfinished(make_app: Any) -> None:
    d = tiny_study()
    with make_app() as app:
        sid = app.client.submit(d)["id"]
        _run_part(app.settings, d, chunks=2)  # 8 of 16 points
        r = app.http.get(f"/studies/{sid}/dataset")
        assert r.status_code == 200 and r.headers["x-impactcell-partial"] == "1"
        ds = app.client.dataset(sid)
        assert int(ds.attrs["partial"]) == 1 and int(ds.attrs["points_done"]) == 8
        assert int(ds["pending"].sum()) == 8
        gamma = ds["transmittance_db"].values
        assert np.isfinite(gamma[~ds["pending"].values]).all()
        assert np.isnan(gamma[ds["pending"].values]).all()
        out = app.http.get(f"/studies/{sid}/data", params={"gap": 0.1}).json()
        assert out["partial"] is True and len(out["values"]) == 8


def test_data_selection_errors_name_field_and_value(make_app: Any) -> None:
    d = tiny_study()
    with make_app() as app:
        sid = app.client.submit(d)["id"]
        _run_part(app.settings, d, chunks=1)
        r = app.http.get(f"/studies/{sid}/data", params={"gap": 0.35})
        assert r.status_code == 422 and "gap" in r.json()["detail"] and "0.35" in r.json()["detail"]
        r = app.http.get(f"/studies/{sid}/data", params={"variable": "nope"})
        assert r.status_code == 422 and "nope" in r.json()["detail"]
        r = app.http.get(f"/studies/{sid}/data", params={"gap": 0.35, "nearest": "true"})
        assert r.status_code == 200
        r = app.http.get(f"/studies/{sid}/timeseries", params={"gamma_r": 1.0, "nearest": "true"})
        assert r.status_code == 422 and "gap" in r.json()["detail"]  # gap not chosen


def _wait(client: Client, sid: str, timeout: float = 180) -> dict[str, Any]:
    return client.wait(sid, progress=False, timeout=timeout, poll=0.2)


@pytest.mark.slow
def test_run_matches_runner_and_results_routes(make_app: Any, tmp_path: Path) -> None:
    d = tiny_study(name="served")
    with make_app(run_jobs=True) as app:
        sid = app.client.submit(d)["id"]
        rec = _wait(app.client, sid)
        assert rec["points_done"] == 16 and rec["progress"] == 1.0 and rec["wall_s"] > 0
        ds = app.client.dataset(sid)
        ref = run_study(parse_study(d), tmp_path / "ref", serial=True)
        xr.testing.assert_identical(comparable(ds), comparable(open_results(ref.path)))
        bg = app.client.bandgap_map(sid, x="gamma_r", y="gap")
        assert bg["transmittance_db"].shape == (2, 8)
        np.testing.assert_array_equal(
            bg["attenuating"].values, (ds["transmittance_db"].transpose("gap", "gamma_r") < 0)
        )
        png = app.client.plot(sid, "transmittance", hue="gap")
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        gr = float(ds.gamma_r[3])
        ts = app.client.timeseries(sid, gamma_r=gr, gap=0.1, periods=2)  # an xarray Dataset
        tau = ts["time"].values
        # Every grid point of the 2 recorded periods (256 a period), plus the events.
        assert len(tau) >= 2 * 256 and np.all(np.diff(tau) >= 0)
        assert 0 <= tau[0] < 2 * np.pi / gr and tau[-1] == pytest.approx(2 * 2 * np.pi / gr)
        assert {"s", "w_tip", "s_b", "theta_eff", "impulse1", "kind"} <= set(ts.data_vars)
        assert all(ts[k].dims == ("time",) for k in ("s", "w_tip", "kind"))
        result = json.loads(ts.attrs["result"])
        assert result["method"] == "event" and "state" not in ts
        # the event solver's log, column by column
        events = {k[len("event_") :] for k in ts.data_vars if k.startswith("event_")}
        assert events == {"tau", "kind", "stop", "residual", "impulse"}
        assert set(ts["event_kind"].values) <= {1, 2} and set(ts["event_stop"].values) <= {1, 2}
        assert result["transmittance_db"] == pytest.approx(
            float(ds["transmittance_db"].sel(gap=0.1).isel(gamma_r=3)), abs=1e-9
        )
        assert result["outcome"] == str(outcome_names(ds["outcome"].sel(gap=0.1))[3])
        r = app.http.get(f"/studies/{sid}/timeseries",
                         params={"gamma_r": gr, "gap": 0.1, "format": "netcdf",
                                 "periods": 1})  # fmt: skip
        assert r.status_code == 200 and r.content[:4] == b"\x89HDF"
        nc = tmp_path / "ts.nc"
        nc.write_bytes(r.content)
        with xr.open_dataset(nc) as h:
            assert h["kind"].dtype.kind == "i" and h["s"].sizes["time"] == h.sizes["time"] > 256
            assert h["event_tau"].dims == ("event",) and 0 < h.sizes["event"] <= ts.sizes["event"]
            assert json.loads(h.attrs["result"])["outcome"] == result["outcome"]
        counts = {k: int((outcome_names(ds["outcome"]) == k).sum()) for k in OUTCOMES}
        assert rec["points_irregular"] == counts["irregular"]
        assert rec["points_unsettled"] == counts["unsettled"]
        files = app.settings.data_dir / "studies" / sid
        assert (files / "results.nc").is_file()


@pytest.mark.slow
def test_cancel_running_study_keeps_finished_chunks(make_app: Any) -> None:
    d = tiny_study(name="long", num=120, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)  # 480 points
    with make_app(run_jobs=True) as app:
        sid = app.client.submit(d)["id"]
        t0 = time.monotonic()
        while app.client.get(sid)["points_done"] == 0:
            assert time.monotonic() - t0 < 120
            time.sleep(0.05)
        rec = app.client.cancel(sid)
        assert rec["status"] == "cancelled"
        time.sleep(1.0)
        store = StudyStore(app.settings.data_dir, parse_study(d))
        done = int(store.done_mask().sum())
        assert 0 < done < 480
        assert not store.results_path.exists()
        assert app.client.get(sid)["status"] == "cancelled"
        # Resume: completes from the kept chunks; the result equals an uninterrupted run.
        app.client.resume(sid)
        rec = _wait(app.client, sid)
        assert rec["status"] == "finished" and rec["points_done"] == 480


def test_restart_resumes_interrupted_study(tmp_path: Path, catalogue_url: str,
                                           dask_address: str) -> None:  # fmt: skip
    d = tiny_study(name="restart", num=120, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)
    s = Settings(data_dir=tmp_path / "data", database_url=catalogue_url, scheduler=dask_address)
    study = parse_study(d)
    store = StudyStore(s.data_dir, study)
    with App(s, run_jobs=True) as app:
        sid = app.client.submit(d)["id"]
        t0 = time.monotonic()
        while app.client.get(sid)["points_done"] < 40:
            assert time.monotonic() - t0 < 120
            time.sleep(0.05)
        wall_before = app.client.get(sid)["wall_s"]
    # The service stopped mid-study: finished chunks kept, the study left to resume.
    done_before = int(store.done_mask().sum())
    assert 0 < done_before < 480
    with App(s, run_jobs=True) as app:
        rec = app.client.get(sid)
        assert rec["status"] in ("queued", "running")
        assert rec["wall_s"] >= wall_before > 0  # running time carries over the restart
        rec = _wait(app.client, sid)
        assert rec["points_done"] == 480 and rec["wall_s"] > wall_before
        ds = app.client.dataset(sid)
    ref = run_study(study, tmp_path / "ref", serial=True)
    xr.testing.assert_identical(comparable(ds), comparable(open_results(ref.path)))
