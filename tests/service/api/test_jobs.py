"""The job manager under real use: queue positions, cancel that stops running work, delete,
a per-point budget, fair sharing of the cluster, and one runner per study across processes."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.catalogue import Catalogue, LeaseRow
from service.api.jobs import lease_name
from service.api.settings import Settings
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from tests.service.helpers import JSON_BODY, Server, tiny_study
from worker.simulate import simulate_chunk

# Points of one to two seconds each (Euler, 1.6e7 steps, the whole budget).
MEDIUM_SOLVER = {"method": "euler", "steps_per_period": 4096, "max_periods": 4000,
                 "early_stop": False, "window": 10}  # fmt: skip
# Points of a minute or more each (Euler, 6.5e8 steps): work that only a working cancel can stop.
HEAVY_SOLVER = {"method": "euler", "steps_per_period": 65_536, "max_periods": 10_000,
                "early_stop": False, "window": 10}  # fmt: skip


@pytest.fixture
def api(tmp_path: Path) -> Iterator[tuple[TestClient, Settings]]:
    """The app without its runner thread: the records, as the API shows them."""
    s = Settings(data_dir=tmp_path / "data")
    with TestClient(create_app(s, run_jobs=False)) as tc:
        yield tc, s


def _wait(http: Any, sid: str, until: Any, timeout: float = 180.0) -> dict[str, Any]:
    t0 = time.monotonic()
    while True:
        rec = http.get(f"/studies/{sid}").json()
        if until(rec):
            return rec
        assert time.monotonic() - t0 < timeout, rec
        time.sleep(0.1)


# --------------------------------------------------------------------------- records


def test_queued_studies_show_their_place_in_the_queue(api: Any) -> None:
    tc, _ = api
    ids = [tc.post("/studies", json=tiny_study(name=f"q{i}", num=3 + i)).json()["id"]
           for i in range(3)]  # fmt: skip
    assert [tc.get(f"/studies/{i}").json()["queue_position"] for i in ids] == [1, 2, 3]
    assert tc.post(f"/studies/{ids[0]}/cancel", headers=JSON_BODY).status_code == 200
    recs = [tc.get(f"/studies/{i}").json() for i in ids]
    assert [r["queue_position"] for r in recs] == [None, 1, 2]
    assert all(r["eta_s"] is None and r["rate_points_per_s"] is None for r in recs)
    listed = {r["id"]: r["queue_position"] for r in tc.get("/studies").json()["items"]}
    assert listed == {ids[0]: None, ids[1]: 1, ids[2]: 2}


def test_a_cancelled_study_says_how_to_resume_it(api: Any) -> None:
    tc, _ = api
    d = tiny_study()
    sid = tc.post("/studies", json=d).json()["id"]
    rec = tc.post(f"/studies/{sid}/cancel", headers=JSON_BODY).json()
    assert rec["status"] == "cancelled" and f"/studies/{sid}/resume" in rec["hint"]
    again = tc.post("/studies", json=d)
    assert again.status_code == 200 and again.json()["status"] == "cancelled"
    assert "resume" in again.json()["hint"]
    assert tc.post(f"/studies/{sid}/cancel", headers=JSON_BODY).status_code == 409


def test_delete_removes_the_record_and_every_file(api: Any) -> None:
    tc, s = api
    d = tiny_study()
    sid = tc.post("/studies", json=d).json()["id"]
    study = parse_study(d)
    # some finished chunks and a results file, as a run leaves them
    run_study(study, s.data_dir, serial=True)
    store = StudyStore(s.data_dir, study)
    assert store.results_path.is_file()
    r = tc.delete(f"/studies/{sid}", headers=JSON_BODY)
    assert r.status_code == 204 and r.content == b""
    assert tc.get(f"/studies/{sid}").status_code == 404
    assert not store.folder.exists()
    assert tc.delete(f"/studies/{sid}", headers=JSON_BODY).status_code == 404
    # the same definition is a new study again
    assert tc.post("/studies", json=d).status_code == 202


def test_the_rate_and_eta_of_a_running_study_come_from_its_running_time(api: Any) -> None:
    tc, s = api
    sid = tc.post("/studies", json=tiny_study(num=50)).json()["id"]  # 100 points
    cat = Catalogue(s.catalogue_url())
    try:
        cat.update_study(sid, status="running", points_done=40, wall_s=8.0)
    finally:
        cat.close()
    rec = tc.get(f"/studies/{sid}").json()
    assert rec["rate_points_per_s"] == pytest.approx(5.0)
    assert rec["eta_s"] == pytest.approx(12.0)
    assert rec["queue_position"] is None


# --------------------------------------------------------------------------- a real cluster


def _app(tmp_path: Path, dask_address: str, **kw: Any) -> TestClient:
    s = Settings(data_dir=tmp_path / "data", scheduler=dask_address, **kw)
    return TestClient(create_app(s, run_jobs=True))


@pytest.mark.slow
def test_cancel_stops_running_points_and_frees_the_cluster(tmp_path: Path,
                                                           dask_address: str) -> None:  # fmt: skip
    d = tiny_study(name="heavy", num=2, gaps=(0.1,), **HEAVY_SOLVER)  # 2 points, ≥ 60 s each
    with _app(tmp_path, dask_address) as tc:
        sid = tc.post("/studies", json=d).json()["id"]
        _wait(tc, sid, lambda r: r["status"] == "running")
        time.sleep(3.0)  # both points are inside their kernels now
        assert tc.post(f"/studies/{sid}/cancel", headers=JSON_BODY).json()["status"] == "cancelled"
        t0 = time.monotonic()
        # A small study gets the cluster at once: the cancelled points stopped (they would
        # hold both workers for a minute or more).
        small = tc.post("/studies", json=tiny_study(name="after", num=2, gaps=(0.1,))).json()
        rec = _wait(tc, small["id"], lambda r: r["status"] == "finished", timeout=120)
        freed_s = time.monotonic() - t0
        assert rec["points_done"] == 2
        assert freed_s < 30.0, f"the cluster was busy for {freed_s:.0f} s after the cancel"
        # nothing of the cancelled study is written after the cancel
        time.sleep(2.0)
        store = StudyStore(tc.app.state.settings.data_dir, parse_study(d))
        assert int(store.done_mask().sum()) == 0 and not store.results_path.exists()
        assert tc.get(f"/studies/{sid}").json()["status"] == "cancelled"


@pytest.mark.slow
def test_a_point_over_its_time_limit_fails_with_the_reason(tmp_path: Path,
                                                           dask_address: str) -> None:  # fmt: skip
    d = tiny_study(name="limited", num=2, gaps=(0.1,), **HEAVY_SOLVER)
    with _app(tmp_path, dask_address, point_time_limit_s=1.0) as tc:
        sid = tc.post("/studies", json=d).json()["id"]
        rec = _wait(tc, sid, lambda r: r["status"] in ("finished", "failed"), timeout=120)
        assert rec["status"] == "finished" and rec["points_failed"] == 2
        assert all("time limit of 1 s per point" in f["reason"] for f in rec["failures"])
        ds = open_results(StudyStore(tc.app.state.settings.data_dir, parse_study(d)).results_path)
        assert bool(ds["failed"].all()) and np.isnan(ds["transmittance_db"].values).all()


@pytest.mark.slow
def test_a_small_study_is_not_held_behind_a_large_one(tmp_path: Path,
                                                      dask_address: str) -> None:  # fmt: skip
    # 24 points of 1–2 s each, in chunks of three: the big study holds the cluster for 10 s or
    # more on any machine, while its first chunk is done within seconds. (400 quick
    # event points, as before, could all finish before the small study was seen finished.)
    big = tiny_study(name="big", num=6, gaps=(0.1, 0.3, 0.5, 0.7), **MEDIUM_SOLVER)
    small = tiny_study(name="small", num=2, gaps=(0.1,))
    with _app(tmp_path, dask_address) as tc:
        bid = tc.post("/studies", json=big).json()["id"]
        _wait(tc, bid, lambda r: r["points_done"] > 0)
        sid = tc.post("/studies", json=small).json()["id"]
        rec = _wait(tc, sid, lambda r: r["status"] == "finished")
        assert rec["points_done"] == 2
        b = tc.get(f"/studies/{bid}").json()
        assert b["status"] == "running" and b["points_done"] < 24
        assert b["rate_points_per_s"] > 0 and b["eta_s"] > 0
        tc.post(f"/studies/{bid}/cancel", headers=JSON_BODY)


@pytest.mark.slow
def test_two_service_processes_never_run_one_study_twice(tmp_path: Path,
                                                         dask_address: str) -> None:  # fmt: skip
    data = tmp_path / "data"
    env = {"IMPACTCELL_LEASE_TTL_S": "3"}
    # 24 points of a second or two each (whole budget, no early stop): the study outlasts the
    # checks below on any machine, and each point's number does not depend on where it ran.
    d = tiny_study(name="shared", num=12, gaps=(0.1, 0.5), **MEDIUM_SOLVER)
    study = parse_study(d)
    a = Server(data, dask_address, env=env)
    b = None
    cat = Catalogue(Settings(data_dir=data).catalogue_url())
    try:
        sid = httpx.post(f"{a.url}/studies", json=d).json()["id"]
        t0 = time.monotonic()
        while httpx.get(f"{a.url}/studies/{sid}").json()["status"] != "running":
            assert time.monotonic() - t0 < 120
            time.sleep(0.1)
        b = Server(data, dask_address, env=env)  # a second service on the same catalogue
        holders = set()
        done = []
        for _ in range(40):  # ~4 lease periods: b sees the study running and leaves it
            rec = httpx.get(f"{b.url}/studies/{sid}").json()
            assert rec["status"] == "running", rec  # still running: the takeover is tested
            holders.add(_holder(cat, sid))
            done.append(rec["points_done"])
            time.sleep(0.1)
        assert holders == {f"pid:{a.proc.pid}"}, holders
        assert done == sorted(done) and done[-1] < 24  # only forward: nobody restarted it
        # The first process dies: the second takes the study over after its lease expires.
        a.stop(signal.SIGKILL)
        t0 = time.monotonic()
        while (rec := httpx.get(f"{b.url}/studies/{sid}").json())["status"] != "finished":
            assert time.monotonic() - t0 < 300, rec
            time.sleep(0.2)
        assert rec["points_done"] == 24 and rec["points_failed"] == 0
        ds = open_results(StudyStore(data, study).results_path)
        # every point is the one a run of its own gives (three of them, recomputed here)
        gamma = ds["transmittance_db"].values.ravel()
        for i in (0, 11, 23):
            ref = simulate_chunk(study.points(i, i + 1), study.solver.settings().__dict__)[0]
            assert gamma[i] == ref["transmittance_db"]
    finally:
        cat.close()
        for srv in (a, b):
            if srv is not None:
                srv.stop()


def _holder(cat: Catalogue, sid: str) -> str:
    """``pid:<n>`` of the process holding the study's lease ("" when none)."""
    with cat._tx() as s:
        row = s.get(LeaseRow, lease_name(sid))
        return "" if row is None else "pid:" + row.holder.split(":")[1]


def test_submitting_a_cancelled_study_with_resume_queues_it_again(api: Any) -> None:
    tc, _ = api
    d = tiny_study()
    sid = tc.post("/studies", json=d).json()["id"]
    tc.post(f"/studies/{sid}/cancel", headers=JSON_BODY)
    r = tc.post("/studies", params={"resume": "true"}, json=d)
    assert r.status_code == 200 and r.json()["status"] == "queued" and r.json()["hint"] is None
    # a queued (or finished) study is returned as it is
    r = tc.post("/studies", params={"resume": "true"}, json=d)
    assert r.status_code == 200 and r.json()["status"] == "queued"


def test_a_list_leaves_out_definitions_unless_asked(api: Any) -> None:
    tc, _ = api
    d = tiny_study(name="described")
    d["description"] = "x" * 5000
    sid = tc.post("/studies", json=d).json()["id"]
    light = tc.get("/studies").json()["items"]
    assert [r["definition"] for r in light] == [None] and light[0]["id"] == sid
    full = tc.get("/studies", params={"full": "true"}).json()["items"]
    assert full[0]["definition"]["description"] == "x" * 5000
    assert tc.get(f"/studies/{sid}").json()["definition"]["name"] == "described"
    d["description"] = "x" * 10_001  # descriptions have a limit too
    r = tc.post("/studies", json=d)
    assert r.status_code == 422 and "description" in r.json()["detail"]


def test_sweep_studies_advertise_their_hysteresis(api: Any) -> None:
    tc, _ = api
    plain = tc.post("/studies", json=tiny_study()).json()
    assert "hysteresis" not in plain["links"]
    d = tiny_study(name="swept")
    d["sweep"] = {"axis": "gamma_r", "directions": ["up", "down"]}
    rec = tc.post("/studies", json=d).json()
    assert rec["links"]["hysteresis"] == f"/studies/{rec['id']}/hysteresis"
    assert rec["links"]["hysteresis_plot"].endswith("/plots/hysteresis.png")
    assert rec["points_total"] == 2 * 16  # up and down over the 16-point grid
