"""``/timeseries``: computed off the API process within a time limit, cached, never blocking."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.routes import timeseries as ts_route
from service.api.settings import Settings
from tests.service.api.test_jobs import HEAVY_SOLVER
from tests.service.helpers import JSON_BODY, Server, tiny_study


def test_a_repeated_request_is_answered_from_the_cache(tmp_path: Path, monkeypatch: Any) -> None:
    calls = []
    real = ts_route.point_history

    def counting(*args: Any) -> Any:
        calls.append(args[2])
        return real(*args)

    monkeypatch.setattr(ts_route, "point_history", counting)
    with TestClient(create_app(Settings(data_dir=tmp_path / "data"), run_jobs=False)) as tc:
        sid = tc.post("/studies", json=tiny_study()).json()["id"]
        q = {"gamma_r": 1.0, "gap": 0.1, "nearest": "true", "periods": 2}
        first = tc.get(f"/studies/{sid}/timeseries", params=q)
        second = tc.get(f"/studies/{sid}/timeseries", params=q)
        assert first.status_code == second.status_code == 200
        assert first.content == second.content and calls == [2]
        nc = tc.get(f"/studies/{sid}/timeseries", params={**q, "format": "netcdf"})
        assert nc.status_code == 200 and nc.content[:3] == b"\x89HD"  # HDF5: NetCDF-4
        assert calls == [2, 2]  # another format is another answer


def test_a_point_over_the_time_limit_is_a_422_naming_the_limit(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path / "data", timeseries_time_limit_s=0.5)
    with TestClient(create_app(s, run_jobs=False)) as tc:
        d = tiny_study(name="heavy", num=2, gaps=(0.1,), **HEAVY_SOLVER)
        sid = tc.post("/studies", json=d).json()["id"]
        r = tc.get(f"/studies/{sid}/timeseries", params={"gamma_r": 0.5, "periods": 2})
        assert r.status_code == 422
        assert "time limit of 0.5 s per point exceeded" in r.json()["detail"]


@pytest.mark.slow
def test_health_answers_while_a_long_timeseries_runs(tmp_path: Path, dask_address: str) -> None:
    limit_s = 8
    srv = Server(tmp_path / "data", dask_address,
                 env={"IMPACTCELL_TIMESERIES_TIME_LIMIT_S": str(limit_s)})  # fmt: skip
    try:
        d = tiny_study(name="heavy", num=2, gaps=(0.1,), **HEAVY_SOLVER)
        sid = httpx.post(f"{srv.url}/studies", json=d).json()["id"]
        # only its definition is needed here
        httpx.post(f"{srv.url}/studies/{sid}/cancel", headers=JSON_BODY)
        out: dict[str, Any] = {}

        def ask() -> None:
            out["r"] = httpx.get(f"{srv.url}/studies/{sid}/timeseries",
                                 params={"gamma_r": 0.5, "periods": 2}, timeout=120)  # fmt: skip

        t = threading.Thread(target=ask)
        t.start()
        slowest = 0.0
        polls = 0
        while t.is_alive():
            t0 = time.monotonic()
            assert httpx.get(f"{srv.url}/health", timeout=10).status_code == 200
            assert httpx.get(f"{srv.url}/studies", timeout=10).status_code == 200
            slowest = max(slowest, time.monotonic() - t0)
            polls += 1
            time.sleep(0.2)
        t.join()
        assert polls >= 5  # the recomputation ran for seconds while /health was asked
        # A server that held requests behind the recomputation would answer after it, up to the
        # limit; half the limit tells the two apart and leaves room for a loaded machine (under
        # pytest -n 2 on CI's 2 cores one poll took 2.3 s).
        assert slowest < limit_s / 2, f"/health and /studies took up to {slowest:.1f} s"
        r = out["r"]
        assert r.status_code == 422 and f"time limit of {limit_s} s per point" in r.json()["detail"]
    finally:
        srv.stop()


def test_a_point_of_a_sweep_study_starts_from_the_initial_state_asked_for(tmp_path: Path) -> None:
    # the hysteresis example's cell at gamma_r 1.8: from rest an impacting orbit, from the
    # linear state the linear response (docs/solvers.md, "Initial states and sweep lines")
    d = {"name": "two-starts", "model": {"coupling": "paper", "modes": 5, "xi": 0.05},
         "initial": ["rest", "linear"], "sweep": {"axis": "gamma_r", "directions": ["down"]},
         "grid": {"gamma_r": [1.75, 1.8], "gap": 0.3, "theta": 0.3, "sigma": 0.05,
                  "gamma_s": 1.0}}  # fmt: skip
    with TestClient(create_app(Settings(data_dir=tmp_path / "data"), run_jobs=False)) as tc:
        sid = tc.post("/studies", json=d).json()["id"]
        q = {"gamma_r": 1.8, "periods": 1, "direction": "down"}
        rest = tc.get(f"/studies/{sid}/timeseries", params=q).json()["result"]
        lin = tc.get(f"/studies/{sid}/timeseries", params={**q, "initial": "linear"}).json()
        assert rest["outcome"] == "periodic" and lin["result"]["outcome"] == "linear"
        assert lin["result"]["periods"] == 0  # proven linear from its start
        assert lin["result"]["transmittance_db"] - rest["transmittance_db"] > 2.0
        bad = tc.get(f"/studies/{sid}/timeseries", params={**q, "initial": "random-3"})
        assert bad.status_code == 422 and "rest, linear" in bad.json()["detail"]


def test_a_fixed_axis_is_accepted_as_by_data_and_time_strictly_increases(tmp_path: Path) -> None:
    import numpy as np
    import xarray as xr

    with TestClient(create_app(Settings(data_dir=tmp_path / "data"), run_jobs=False)) as tc:
        sid = tc.post("/studies", json=tiny_study()).json()["id"]  # θ = 0.3 fixed
        q = {"gamma_r": 1.0, "gap": 0.1, "nearest": "true", "periods": 3}
        plain = tc.get(f"/studies/{sid}/timeseries", params=q)
        with_theta = tc.get(f"/studies/{sid}/timeseries", params={**q, "theta": 0.3})
        assert plain.status_code == with_theta.status_code == 200, with_theta.text
        assert with_theta.json()["series"] == plain.json()["series"]
        wrong = tc.get(f"/studies/{sid}/timeseries", params={**q, "theta": 0.4, "nearest": False})
        assert wrong.status_code == 422
        assert "theta=0.4 is not a coordinate value; values are 0.3" in wrong.json()["detail"]
        unknown = tc.get(f"/studies/{sid}/timeseries", params={**q, "tehta": 0.3})
        assert unknown.status_code == 422 and "'tehta'" in unknown.json()["detail"]
        assert "theta" in unknown.json()["detail"]  # the axes listed include the fixed ones

        nc = tc.get(f"/studies/{sid}/timeseries", params={**q, "format": "netcdf"})
        assert nc.status_code == 200
        (tmp_path / "ts.nc").write_bytes(nc.content)
        ts = xr.load_dataset(tmp_path / "ts.nc", engine="netcdf4")
        time = ts["time"].values
        assert time.size > 10 and np.all(np.diff(time) > 0)
        series = plain.json()["series"]
        assert np.all(np.diff(series["tau"]) > 0)
        # the impacts are still there (the sample after each one is the one kept)
        kinds = ts["kind"].values
        assert np.isin(kinds, (1, 2)).any()
        assert np.isin(series["kind"], (1, 2)).any()
