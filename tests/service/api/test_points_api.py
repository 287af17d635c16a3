"""The point store through the service (issue 16): ``GET /points`` (JSON, CSV, NetCDF, paging,
errors, token), studies that share points computed once (a real dask cluster), the client and
the command line (``run --json`` counts, ``points``, ``gc``) against a real server."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from service.api.catalogue import Catalogue
from service.api.points import SqlPointStore
from service.client import Client
from service.studies.runner import ChunkPool, StudyRun
from service.studies.schema import Study
from tests.service.api.test_api import make_app  # noqa: F401 - the fixture
from tests.service.helpers import Server, run_cli, tiny_study


def _fill(app: Any, *defs: dict[str, Any]) -> list[str]:
    """Run studies through the service's own queue (no cluster needed: serial, in process)."""
    from service.studies.runner import run_study

    cat = Catalogue(app.settings.catalogue_url())
    try:
        store = SqlPointStore(cat.engine)
        return [
            run_study(Study.model_validate(d), app.settings.data_dir, serial=True,
                      points=store).study_id
            for d in defs
        ]  # fmt: skip
    finally:
        cat.close()


@pytest.mark.slow  # runs whole (small) studies
def test_points_route_answers_json_csv_and_netcdf(make_app: Any) -> None:  # noqa: F811
    with make_app(api_token="tok") as app:
        _fill(app, tiny_study("a", num=6))
        h = {"Authorization": "Bearer tok"}
        assert app.http.get("/points").status_code == 401
        r = app.http.get("/points", params={"gap": 0.1, "gamma_r_min": 1, "gamma_r_max": 2},
                         headers=h)  # fmt: skip
        assert r.status_code == 200
        body = r.json()
        assert body["next"] is None and body["count"] == len(body["points"]) == 3  # 1, 1.5, 2
        for p in body["points"]:
            assert p["g1"] == p["g2"] == 0.1 and 1 <= p["gamma_r"] <= 2
            assert p["outcome"] and p["solver"]["max_periods"] == 60
        # paging: next key in the body and the header, every point once
        keys: list[str] = []
        params: dict[str, Any] = {"limit": 5}
        while True:
            r = app.http.get("/points", params=params, headers=h)
            keys += [p["key"] for p in r.json()["points"]]
            nxt = r.json()["next"]
            assert r.headers.get("x-next-after") == nxt
            if nxt is None:
                break
            params["after"] = nxt
        assert len(keys) == len(set(keys)) == 12
        csv = app.http.get("/points", params={"format": "csv", "gap": 0.5}, headers=h)
        assert csv.headers["content-type"].startswith("text/csv")
        assert len(csv.text.strip().splitlines()) == 7
        nc = app.http.get("/points", params={"format": "netcdf"}, headers=h)
        assert nc.headers["content-type"] == "application/x-netcdf"
        ds = _open_bytes(nc.content, app.settings.data_dir / "points.nc")
        assert ds.sizes["point"] == 12 and set(ds.g1.values) == {0.1, 0.5}
        none = app.http.get("/points", params={"theta": 7.0}, headers=h).json()
        assert none == {"points": [], "count": 0, "next": None}


def _open_bytes(data: bytes, path: Path) -> xr.Dataset:
    path.write_bytes(data)
    with xr.open_dataset(path, engine="netcdf4") as ds:
        return ds.load()


@pytest.mark.parametrize(
    ("params", "says"),
    [
        ({"bogus": 1}, "query.bogus"),
        ({"theta": "abc"}, "query.theta"),
        ({"gap": 0.1, "gap_min": 0.0}, "give gap or a range"),
        ({"gamma_r_min": 3, "gamma_r_max": 1}, "gamma_r_min (3.0) is above gamma_r_max (1.0)"),
        ({"limit": 0}, "query.limit"),
        ({"outcome": "great"}, "query.outcome"),
        ({"study": "../etc"}, "study must be a study id"),
        ({"theta": "nan"}, "theta must be a finite number"),
    ],
)
def test_bad_point_queries_name_the_field(make_app: Any, params: dict, says: str) -> None:  # noqa: F811
    with make_app() as app:
        r = app.http.get("/points", params=params)
        assert r.status_code == 422
        assert says in r.json()["detail"]


@pytest.mark.slow
def test_concurrent_studies_compute_shared_points_once(tmp_path: Path, dask_address: str) -> None:
    """Two studies in one pool at once: every distinct point is computed by exactly one task."""
    from dask.distributed import Client as DaskClient

    cat = Catalogue(f"sqlite:///{tmp_path / 'cat.sqlite'}")
    store = SqlPointStore(cat.engine)
    a = Study.model_validate(tiny_study("a", num=8, gaps=(0.1, 0.5)))
    b = Study.model_validate(tiny_study("b", num=8, gaps=(0.5, 0.3)))  # shares gap 0.5
    runs = {s.name: StudyRun(s, tmp_path, points=store, chunk_size=3) for s in (a, b)}
    with DaskClient(dask_address) as client:
        pool = ChunkPool(client, window=8)
        for k, r in runs.items():
            pool.add(k, r)
        done: set[str] = set()
        while len(done) < 2:
            done |= set(pool.step(0.5))
    summaries = {k: r.collate(2) for k, r in runs.items()}
    computed = sum(s.computed for s in summaries.values())
    assert computed == 24 == store.count()  # 32 points asked for, 24 distinct
    assert sum(s.reused for s in summaries.values()) == 8
    with xr.open_dataset(summaries["a"].path) as da, xr.open_dataset(summaries["b"].path) as db:
        np.testing.assert_array_equal(
            da.transmittance_db.sel(gap=0.5).values, db.transmittance_db.sel(gap=0.5).values
        )
    cat.close()


@pytest.mark.slow
def test_service_client_and_cli_share_one_point_store(tmp_path: Path, dask_address: str) -> None:
    data = tmp_path / "data"
    first = tiny_study("cli first", num=6)
    f = tmp_path / "first.yaml"
    f.write_text(json.dumps(first))
    out = run_cli("run", str(f), "--out", str(data), "--json", "--no-progress", "--serial")
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert (summary["computed"], summary["reused"]) == (12, 0)

    srv = Server(data, dask_address)
    try:
        with Client(srv.url) as c:
            renamed = copy.deepcopy(first)
            renamed["name"] = "through the service"
            renamed["grid"]["gap"] = [0.1, 0.5, 0.3]
            rec = c.wait(c.submit(renamed)["id"], progress=False, timeout=300)
            assert (rec["points_computed"], rec["points_reused"]) == (6, 12)
            ds = c.points(theta=0.3, gap=0.5, gamma_r_min=1.0, gamma_r_max=3.0, page=2)
            assert ds.sizes["point"] == 5 and set(ds.g2.values) == {0.5}  # 1, 1.5, …, 3
            assert np.all((ds.gamma_r.values >= 1.0) & (ds.gamma_r.values <= 3.0))
            assert c.points(theta=9.0).sizes["point"] == 0
            c.delete(rec["id"])
    finally:
        srv.stop()
    listed = run_cli("points", "--data-dir", str(data), "--gap", "0.3", "--format", "csv")
    assert listed.returncode == 0 and len(listed.stdout.strip().splitlines()) == 7
    dry = run_cli("gc", "--data-dir", str(data), "--dry-run")
    assert dry.returncode == 0 and "would remove 6 points" in dry.stdout
    gone = run_cli("gc", "--data-dir", str(data))
    assert "removed 6 points" in gone.stdout
    left = run_cli("points", "--data-dir", str(data))
    assert len(left.stdout.strip().splitlines()) == 12  # the CLI study's folder keeps its own
    bad = run_cli("points", "--data-dir", str(data), "--gap", "0.1", "--gap-min", "0")
    assert bad.returncode != 0 and "give --gap or a range" in bad.stderr
