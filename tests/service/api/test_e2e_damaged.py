"""End to end with damaged files (issue 63): a real ``impactcell serve`` process and dask
cluster; a chunk file of a cancelled study and then the finished study's results file are
damaged on disk. No answer is a 500 or shows a server path, the study finishes, its dataset
equals a clean run's, and no point is computed twice."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import netCDF4
import pytest
import xarray as xr

from service.client import Client
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from tests.service.helpers import SLOW_SOLVER, Server, comparable, tiny_study

pytestmark = pytest.mark.slow

ROUTES = ("/dataset", "/data", "/bandgap")


def _clean(body: bytes, data: Path) -> bool:
    """Whether a response body names no server path."""
    return not any(p in body for p in (str(data.resolve()).encode(), b"/tmp/", b"results.nc"))


def test_a_damaged_chunk_and_results_file_heal_without_loss(
    tmp_path: Path, dask_address: str
) -> None:
    d = tiny_study(name="heal", num=75, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)  # 300 points
    study = parse_study(d)
    data = tmp_path / "data"
    store = StudyStore(data, study)
    # A short lease: the runner looks for queued studies every lease_ttl_s / 3 (a rebuild
    # queued by a request is one).
    srv = Server(data, dask_address, env={"IMPACTCELL_LEASE_TTL_S": "3"})
    try:
        with Client(srv.url) as c:
            sid = c.submit(d)["id"]
            t0 = time.monotonic()
            while c.get(sid)["points_done"] < 40:
                assert time.monotonic() - t0 < 120, srv.logtext()
                time.sleep(0.05)
            c.cancel(sid)
            done = int(store.done_mask().sum())
            assert 0 < done < 300, "the study finished before it was cancelled"

            # 1. a truncated chunk file: its points are pending, no request fails
            start, stop, victim = store.chunks()[0]
            victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
            for route in ROUTES:
                r = httpx.get(f"{srv.url}/studies/{sid}{route}", timeout=60)
                assert r.status_code == 200, (route, r.text[:300])
                assert _clean(r.content, data), route
            partial = c.dataset(sid)
            assert int(partial.attrs["points_done"]) == done - (stop - start)
            assert not victim.exists()
            assert [p.name.split(".npz.")[0] for p in (store.folder / "damaged").iterdir()] == [
                victim.stem
            ]

            # resumed: the damaged chunk's points come from the point store, the rest are
            # computed, each once
            c.resume(sid)
            rec = c.wait(sid, progress=False, timeout=240, poll=0.2)
            assert rec["status"] == "finished", rec
            assert rec["points_computed"] == 300 - done and rec["points_reused"] == done
            healed = c.dataset(sid)

            # 2. an overwritten coordinate value in the results file (still valid NetCDF)
            with netCDF4.Dataset(store.results_path, "r+") as nc:
                nc["gamma_r"][3] = 99.0
            first = httpx.get(f"{srv.url}/studies/{sid}/data", timeout=60)
            assert first.status_code == 503, first.text[:300]
            assert "failed its SHA-256 check" in first.json()["detail"]
            assert _clean(first.content, data)
            for route in ROUTES:  # partial (from the rebuild's chunks) or rebuilt: never a 500
                r = httpx.get(f"{srv.url}/studies/{sid}{route}", timeout=60)
                assert r.status_code in (200, 503), (route, r.text[:300])
                assert _clean(r.content, data), route
            rec = c.wait(sid, progress=False, timeout=120, poll=0.2)
            assert rec["status"] == "finished", rec
            assert rec["points_computed"] == 0 and rec["points_reused"] == 300  # from the store
            rebuilt = c.dataset(sid)
    finally:
        srv.stop()
    ref = comparable(open_results(run_study(study, tmp_path / "ref", serial=True).path))
    xr.testing.assert_identical(comparable(healed), ref)
    xr.testing.assert_identical(comparable(rebuilt), ref)
