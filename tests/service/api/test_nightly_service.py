"""The nightly suite run by the service: through its own job queue and cluster, studies listed,
fresh runs by tag, and a report that says when a study was cancelled or failed.

The ``slow`` tests start a real service (uvicorn on 127.0.0.1) on a real dask cluster; the
others drive :class:`~service.api.nightly.NightlyRunner` with a stand-in job queue.
"""

from __future__ import annotations

import shutil
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import dask.distributed
import httpx
import pytest
import yaml
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.catalogue import Catalogue
from service.api.nightly import SUITE_LEASE, NightlyBusy, NightlyRunner
from service.api.schedule import record_run
from service.api.server import ServerThread
from service.api.settings import Settings
from service.client import Client, Conflict
from service.regression.run import run_suite
from service.regression.suite import SuiteError, load_suite
from service.studies.schema import Study
from tests.service.helpers import JSON_BODY, SLOW_SOLVER, Server, tiny_study, write_suite

TOKEN = "n1ght"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny suite with baselines made from it (serially), once per module."""
    root = tmp_path_factory.mktemp("suite")
    write_suite(root / "nightly")
    report = run_suite(root / "nightly", data_dir=root / "data", update_baseline=True,
                       serial=True)  # fmt: skip
    assert report.ok and (root / "baselines" / "tiny.nc").is_file()
    return root


def _wait_report(c: Client, reg_id: int, timeout: float = 240) -> dict[str, Any]:
    t0 = time.monotonic()
    while True:
        rec = c.regression(reg_id)
        if rec["finished_at"] is not None:
            return rec
        assert time.monotonic() - t0 < timeout, rec
        time.sleep(0.2)


# --------------------------------------------------------------------------- a real service


@pytest.mark.slow
def test_nightly_runs_through_the_service_queue_on_its_own_cluster(
    made: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Embedded cluster: the service's is the only LocalCluster, and the suite's studies are
    the queue's (listed, tagged, fresh every run), compared into a stored report."""
    clusters: list[Any] = []

    class Counted(dask.distributed.LocalCluster):  # type: ignore[misc]
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            clusters.append(self)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(dask.distributed, "LocalCluster", Counted)
    s = Settings(host="127.0.0.1", port=0, data_dir=tmp_path / "data", workers=1,
                 api_token=TOKEN, nightly_dir=made / "nightly")  # fmt: skip
    server = ServerThread(s).start()
    try:
        with Client(server.url, token=TOKEN) as c:
            user = c.submit(tiny_study(name="user", num=4))  # the service's cluster starts
            c.wait(user["id"], progress=False, timeout=180, poll=0.2)
            r = httpx.post(f"{server.url}/regressions", headers={**AUTH, **JSON_BODY})
            assert r.status_code == 202, r.text
            first = r.json()
            assert r.headers["location"] == f"/regressions/{first['id']}"
            assert first["trigger"] == "api" and first["ok"] is None
            with pytest.raises(Conflict, match="in progress"):  # one run at a time
                c.run_nightly()
            rec = _wait_report(c, first["id"])
            assert rec["ok"] is True, rec["markdown"]
            report = rec["report"]
            assert report["mode"].startswith("service job queue (tag nightly-")
            assert [x["status"] for x in report["studies"]] == ["passed", "passed"]
            assert "# Nightly regression: PASSED" in rec["markdown"]

            # The suite's studies are the queue's: listed with their names, each tagged.
            listed = {r["id"]: r for r in c.list(full=True)}
            ids = {x["study_id"] for x in report["studies"]}
            assert ids <= set(listed)
            assert {listed[i]["name"] for i in ids} == {"tiny", "tiny-euler"}
            tags = {listed[i]["definition"]["tag"] for i in ids}
            assert len(tags) == 1 and next(iter(tags)).startswith("nightly-")
            assert all(listed[i]["status"] == "finished" for i in ids)

            # A second run is fresh: new tag, new studies, the same verdict.
            second = _wait_report(c, c.run_nightly()["id"])
            assert second["ok"] is True
            ids2 = {x["study_id"] for x in second["report"]["studies"]}
            assert not ids2 & ids and len(c.list()) == 5
            health = c.health()
            assert health["nightly"]["id"] == second["id"] and health["nightly"]["ok"] is True
        assert len(clusters) == 1, "the nightly run must not start a cluster of its own"
    finally:
        server.stop()


@pytest.mark.slow
def test_a_cancelled_nightly_study_fails_the_report(tmp_path: Path, dask_address: str) -> None:
    suite = tmp_path / "nightly"
    suite.mkdir()
    slow = tiny_study(name="nightly-slow", num=150, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)
    (suite / "slow.yaml").write_text(yaml.safe_dump(slow), encoding="utf-8")
    # A run needs every baseline before it starts; this one is never read (cancelled first).
    (tmp_path / "baselines").mkdir()
    (tmp_path / "baselines" / "slow.nc").write_bytes(b"")
    s = Settings(host="127.0.0.1", port=0, data_dir=tmp_path / "data", scheduler=dask_address,
                 api_token=TOKEN, nightly_dir=suite)  # fmt: skip
    server = ServerThread(s).start()
    try:
        with Client(server.url, token=TOKEN) as c:
            reg = c.run_nightly()
            t0 = time.monotonic()
            while not (mine := c.list(name="nightly-slow", full=True)):
                assert time.monotonic() - t0 < 30
                time.sleep(0.05)
            assert mine[0]["definition"]["tag"].startswith("nightly-")
            c.cancel(mine[0]["id"])
            rec = _wait_report(c, reg["id"])
        assert rec["ok"] is False
        (study,) = rec["report"]["studies"]
        assert study["status"] == "cancelled" and "was cancelled" in study["error"]
        assert "slow cancelled" in rec["summary"]
        assert "# Nightly regression: FAILED" in rec["markdown"]
        assert f"study {mine[0]['id']} was cancelled" in rec["markdown"]
    finally:
        server.stop()


@pytest.mark.slow
def test_studies_whose_canonical_form_the_input_rules_refuse_run_on_the_service(
    tmp_path: Path, dask_address: str
) -> None:
    """The queue reads its stored (canonical) definitions back: a physical study (table1) and
    one with an xi axis (paper-params) run, as the service's nightly needs them to."""
    entries = {e.stem: e for e in load_suite()}
    s = Settings(host="127.0.0.1", port=0, data_dir=tmp_path / "data", scheduler=dask_address)
    server = ServerThread(s).start()
    try:
        with Client(server.url) as c:
            for stem in ("table1", "paper-params"):
                entry = entries[stem]
                rec = c.submit(entry.definition)
                assert rec["id"] == entry.study.id
                rec = c.wait(rec["id"], progress=False, timeout=240, poll=0.2)
                assert rec["points_done"] == entry.study.size
                assert c.dataset(rec["id"]).attrs["study_id"] == entry.study.id
    finally:
        server.stop()


# --------------------------------------------------------------------------- a stand-in queue


class FakeJobs:
    """A job queue that ends every study with ``outcome`` (or leaves it queued: ``None``)."""

    running = True

    def __init__(self, catalogue: Catalogue, outcome: str | None) -> None:
        self.catalogue = catalogue
        self.outcome = outcome
        self.submitted: list[Study] = []
        self.cancelled: list[str] = []

    def submit(self, study: Study) -> tuple[dict[str, Any], bool]:
        self.submitted.append(study)
        rec, created = self.catalogue.add_study(
            study.id, study.name, study.canonical_json(), study.size
        )
        if self.outcome is not None:
            self.catalogue.update_study(study.id, status=self.outcome, error="RuntimeError: boom")
        return rec, created

    def cancel(self, sid: str) -> dict[str, Any]:
        self.cancelled.append(sid)
        self.catalogue.update_study(sid, status="cancelled")
        rec = self.catalogue.get_study(sid)
        assert rec is not None
        return rec


@pytest.fixture
def catalogue(tmp_path: Path) -> Iterator[Catalogue]:
    cat = Catalogue(f"sqlite:///{tmp_path / 'catalogue.sqlite'}")
    yield cat
    cat.close()


def test_a_failed_study_is_reported_as_such(
    made: Path, tmp_path: Path, catalogue: Catalogue
) -> None:
    s = Settings(data_dir=tmp_path / "data", nightly_dir=made / "nightly")
    jobs = FakeJobs(catalogue, "failed")
    out = NightlyRunner(s, catalogue, jobs, poll=0.01).run()  # type: ignore[arg-type]
    assert out["ok"] is False
    tags = {st.tag for st in jobs.submitted}
    assert len(tags) == 1 and next(iter(tags)).startswith("nightly-")
    studies = out["report"]["studies"]
    assert [x["status"] for x in studies] == ["error", "error"]
    assert all("failed on the service: RuntimeError: boom" in x["error"] for x in studies)
    assert [x["study_id"] for x in studies] == [st.id for st in jobs.submitted]
    assert "2 not ok" in out["report"]["summary"]
    # The report is also on disk, in the run's folder named like its tag.
    (run_dir,) = (tmp_path / "data" / "nightly").iterdir()
    assert next(iter(tags)) == f"nightly-{run_dir.name}"
    assert (run_dir / "report.md").is_file()


def test_a_stopping_service_cancels_the_runs_studies_and_says_so(
    made: Path, tmp_path: Path, catalogue: Catalogue
) -> None:
    s = Settings(data_dir=tmp_path / "data", nightly_dir=made / "nightly")
    jobs = FakeJobs(catalogue, None)  # studies stay queued
    runner = NightlyRunner(s, catalogue, jobs, poll=0.01)  # type: ignore[arg-type]
    out: dict[str, Any] = {}
    t = threading.Thread(target=lambda: out.update(runner.run()))
    t.start()
    while len(jobs.submitted) < 2:
        time.sleep(0.01)
    runner.stop()
    t.join(10)
    assert out["ok"] is False
    assert [x["status"] for x in out["report"]["studies"]] == ["cancelled", "cancelled"]
    assert "the service stopped" in out["report"]["studies"][0]["error"]
    assert jobs.cancelled == [st.id for st in jobs.submitted]


def test_start_refuses_a_second_run_and_an_idle_queue(
    made: Path, tmp_path: Path, catalogue: Catalogue
) -> None:
    s = Settings(data_dir=tmp_path / "data", nightly_dir=made / "nightly")
    jobs = FakeJobs(catalogue, None)
    runner = NightlyRunner(s, catalogue, jobs, poll=0.01)  # type: ignore[arg-type]
    reg_id = runner.start()
    with pytest.raises(NightlyBusy, match="in progress"):
        runner.start()
    runner.stop()
    assert catalogue.get_regression(reg_id)["ok"] is False
    assert not runner.busy
    jobs.running = False
    with pytest.raises(NightlyBusy, match="job runner is not running"):
        NightlyRunner(s, catalogue, jobs).start()  # type: ignore[arg-type]


def test_one_nightly_run_at_a_time_across_service_processes(
    made: Path, tmp_path: Path, catalogue: Catalogue
) -> None:
    s = Settings(data_dir=tmp_path / "data", nightly_dir=made / "nightly")
    jobs = FakeJobs(catalogue, "finished")
    runner = NightlyRunner(s, catalogue, jobs, poll=0.01)  # type: ignore[arg-type]
    # another process (another host) runs the suite now
    assert catalogue.acquire_lease(SUITE_LEASE, "elsewhere:1:abcd", 60)
    with pytest.raises(NightlyBusy, match="another service process"):
        runner.start()
    with pytest.raises(NightlyBusy, match="another service process"):
        runner.run()
    assert jobs.submitted == [] and not runner.busy
    assert catalogue.list_regressions()[1] == 0  # nothing recorded by the refused start
    catalogue.release_lease(SUITE_LEASE, "elsewhere:1:abcd")
    runner.run()  # now it may; and gives the lease back when it ends
    assert len(jobs.submitted) == 2 and catalogue.lease_free(SUITE_LEASE)


def test_the_cron_schedule_runs_the_services_runner(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path / "d", nightly_cron="0 2 * * *")
    with TestClient(create_app(s, run_jobs=False)) as tc:
        state = tc.app.state
        assert state.nightly.run == state.nightly_runner.run
        assert state.nightly_runner.jobs is state.jobs
        # Without a runner thread no study would run: the API says so instead of queueing.
        r = tc.post("/regressions", headers=JSON_BODY)
        assert r.status_code == 503 and "job runner is not running" in r.json()["detail"]


def test_missing_baselines_fail_the_run_before_any_study_is_queued(
    made: Path, tmp_path: Path, catalogue: Catalogue
) -> None:
    shutil.copytree(made / "nightly", tmp_path / "nightly")
    (tmp_path / "baselines").mkdir()
    shutil.copy(made / "baselines" / "tiny.nc", tmp_path / "baselines")  # not tiny-euler's
    s = Settings(data_dir=tmp_path / "data", nightly_dir=tmp_path / "nightly")
    jobs = FakeJobs(catalogue, "finished")
    runner = NightlyRunner(s, catalogue, jobs, poll=0.01)  # type: ignore[arg-type]
    with pytest.raises(SuiteError, match=r"no baseline in .* for tiny-euler\.nc"):
        runner.run()
    assert jobs.submitted == []  # refused before anything was queued
    reg_id = catalogue.add_regression("cron")
    record_run(catalogue, reg_id, runner.run)  # what the schedule stores
    rec = catalogue.get_regression(reg_id)
    assert rec["ok"] is False and "tiny-euler.nc" in rec["error"]
    assert jobs.submitted == []


def test_the_service_markdown_report_shows_no_server_paths(
    made: Path, tmp_path: Path, catalogue: Catalogue
) -> None:
    s = Settings(data_dir=tmp_path / "data", nightly_dir=made / "nightly")
    jobs = FakeJobs(catalogue, "cancelled")
    out = NightlyRunner(s, catalogue, jobs, poll=0.01).run()  # type: ignore[arg-type]
    md = out["markdown"]
    assert "Suite `nightly`, baselines `baselines`" in md
    assert str(made) not in md and str(tmp_path) not in md
    assert out["report"]["suite"] == str(made / "nightly")  # the JSON keeps the real paths


@pytest.mark.slow
def test_a_run_killed_with_its_service_is_marked_interrupted_on_restart(
    tmp_path: Path, dask_address: str
) -> None:
    suite = tmp_path / "nightly"
    suite.mkdir()
    slow = tiny_study(name="nightly-slow", num=150, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)
    (suite / "slow.yaml").write_text(yaml.safe_dump(slow), encoding="utf-8")
    (tmp_path / "baselines").mkdir()
    (tmp_path / "baselines" / "slow.nc").write_bytes(b"")  # never read: the run is killed
    data = tmp_path / "data"
    env = {"IMPACTCELL_NIGHTLY_DIR": str(suite)}
    first = Server(data, dask_address, token=TOKEN, env=env)
    try:
        r = httpx.post(f"{first.url}/regressions", headers={**AUTH, **JSON_BODY})
        assert r.status_code == 202, r.text
        reg_id = r.json()["id"]
        t0 = time.monotonic()
        while not httpx.get(f"{first.url}/studies", params={"name": "nightly-slow"},
                            headers=AUTH).json()["items"]:  # fmt: skip
            assert time.monotonic() - t0 < 30
            time.sleep(0.05)
    finally:
        first.stop(signal.SIGKILL)  # as a crash: the run's row is left without an outcome
    second = Server(data, dask_address, token=TOKEN, env=env)
    try:
        rec = httpx.get(f"{second.url}/regressions/{reg_id}", headers=AUTH).json()
        assert rec["ok"] is False and rec["finished_at"] is not None, rec
        assert rec["summary"].startswith("interrupted")
        assert "is gone" in rec["error"]  # its process, on this host, no longer exists
        health = httpx.get(f"{second.url}/health").json()
        assert health["nightly"]["id"] == reg_id and health["nightly"]["ok"] is False
    finally:
        second.stop()
