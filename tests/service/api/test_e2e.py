"""End to end: a real ``impactcell serve`` process (uvicorn on 127.0.0.1, random port), the
client over HTTP, a real dask cluster, real NetCDF files; and a restart after SIGTERM/SIGKILL."""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
import xarray as xr

from service.client import Client
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from tests.service.helpers import SLOW_SOLVER, Server, comparable, tiny_study

# real `impactcell serve` processes and whole studies: the slow tier
pytestmark = pytest.mark.slow


@pytest.fixture
def server(tmp_path: Path, dask_address: str) -> Iterator[Server]:
    srv = Server(tmp_path / "data", dask_address, token="e2e-token")
    yield srv
    srv.stop()


def test_submit_wait_dataset_bandgap_plot_timeseries(server: Server, tmp_path: Path) -> None:
    d = tiny_study(name="e2e", num=12, gaps=(0.1, 0.5, 2.0))
    with Client(server.url, token="e2e-token") as c:
        assert httpx.get(f"{server.url}/studies").status_code == 401  # auth is on
        rec = c.submit(d)
        assert rec["status"] in ("queued", "running") and rec["points_total"] == 36
        rec = c.wait(rec["id"], progress=False, timeout=180, poll=0.2)
        assert rec["status"] == "finished" and rec["points_done"] == 36
        ds = c.dataset(rec["id"])
        ref = run_study(parse_study(d), tmp_path / "ref", serial=True)
        xr.testing.assert_identical(comparable(ds), comparable(open_results(ref.path)))

        bg = c.bandgap_map(rec["id"], x="gamma_r", y="gap", threshold_db=0.0)
        gamma = ds["transmittance_db"].transpose("gap", "gamma_r").values
        np.testing.assert_array_equal(bg["transmittance_db"].values, gamma)
        edges = json.loads(bg.attrs["edges"])
        assert [e["y"] for e in edges] == [0.1, 0.5, 2.0]
        for e, row in zip(edges, gamma, strict=True):
            # Every band edge is a linear-interpolation crossing or the grid end.
            for a, b in e["bands"]:
                assert 0.5 <= a < b <= 3.0
            assert bool(e["bands"]) == bool((row < 0).any())

        png = c.plot(rec["id"], "bandgap", x="gamma_r", y="gap")
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
        w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert w >= 600 and h >= 400

        g = float(ds.gamma_r[5])
        ts = c.timeseries(rec["id"], gamma_r=g, gap=0.1, periods=3)  # an xarray Dataset
        assert ts.sizes["time"] >= 3 * 256  # every grid point, plus the events
        assert float(ts["time"][-1]) == pytest.approx(3 * 2 * np.pi / g)
        assert json.loads(ts.attrs["result"])["transmittance_db"] == pytest.approx(
            float(ds["transmittance_db"].sel(gap=0.1, gamma_r=g)), abs=1e-9
        )
        assert c.health()["studies"]["finished"] == 1


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_restart_mid_study_completes_without_loss(
    tmp_path: Path, dask_address: str, sig: int
) -> None:
    # 1,000 points: on two idle cores they take a few seconds, so the stop comes mid-study
    d = tiny_study(name=f"restart-{sig}", num=250, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)
    data = tmp_path / "data"
    # a short lease: after SIGKILL the restarted service takes the study over once the dead
    # process's lease expires (30 s by default; test_jobs.py uses 3 s too)
    env = {"IMPACTCELL_LEASE_TTL_S": "3"}
    srv = Server(data, dask_address, env=env)
    with Client(srv.url) as c:
        sid = c.submit(d)["id"]
        t0 = time.monotonic()
        while c.get(sid)["points_done"] < 64:
            assert time.monotonic() - t0 < 120, srv.logtext()
            time.sleep(0.05)
    srv.stop(sig)
    study = parse_study(d)
    done = int(StudyStore(data, study).done_mask().sum())
    assert 0 < done < 1000
    srv = Server(data, dask_address, env=env)
    try:
        with Client(srv.url) as c:
            rec = c.wait(sid, progress=False, timeout=240, poll=0.2)
            assert rec["points_done"] == 1000
            ds = c.dataset(sid)
    finally:
        srv.stop()
    ref = run_study(study, tmp_path / "ref", serial=True)
    xr.testing.assert_identical(comparable(ds), comparable(open_results(ref.path)))
