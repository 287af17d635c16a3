"""The nightly schedule: cron slots, one run per slot across processes, reports in the API."""

from __future__ import annotations

import datetime as dt
import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.catalogue import Catalogue
from service.api.schedule import (
    PROCESS_HOLDER,
    RUN_LEASE_GRACE_S,
    NightlyScheduler,
    next_slot,
    record_run,
    recover_interrupted,
    run_lease,
    run_nightly_once,
)
from service.api.settings import Settings

UTC = dt.UTC


def test_next_slot_follows_cron() -> None:
    t = dt.datetime(2026, 11, 21, 1, 59, 30, tzinfo=UTC)
    assert next_slot("0 2 * * *", t) == dt.datetime(2026, 11, 21, 2, 0, tzinfo=UTC)
    assert next_slot("0 2 * * *", t.replace(hour=2, minute=0, second=0)) == dt.datetime(
        2026, 11, 22, 2, 0, tzinfo=UTC
    )
    assert next_slot("*/15 * * * *", t) == dt.datetime(2026, 11, 21, 2, 0, tzinfo=UTC)
    with pytest.raises(ValueError, match="5-field cron"):
        next_slot("0 2 * * * *", t)


def _fake_run(calls: list[str], ok: bool = True) -> Any:
    def run() -> dict[str, Any]:
        calls.append("run")
        time.sleep(0.05)  # long enough for a competing process to try the lease meanwhile
        return {"ok": ok, "report": {"summary": "2 studies, 0 regressions"}, "markdown": "# ok"}

    return run


def test_one_run_per_slot_across_processes(catalogue_url: str) -> None:
    slot = dt.datetime(2026, 11, 21, 2, 0, tzinfo=UTC)
    calls: list[str] = []
    # Separate catalogue objects (own engines and pools), as separate service processes have.
    cats = [Catalogue(catalogue_url) for _ in range(3)]
    ids: list[int | None] = []
    threads = [
        threading.Thread(
            target=lambda c=c, i=i: ids.append(
                run_nightly_once(c, slot, f"proc-{i}", _fake_run(calls))
            )
        )
        for i, c in enumerate(cats)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert calls == ["run"]
    assert sum(i is not None for i in ids) == 1
    # The next slot is a new lease: it runs again.
    assert run_nightly_once(cats[1], slot + dt.timedelta(days=1), "proc-1", _fake_run(calls))
    assert calls == ["run", "run"]
    for c in cats:
        c.close()


def test_scheduler_threads_fire_once_per_slot(catalogue_url: str, tmp_path: Path) -> None:
    # A fake clock that runs 1 minute per 10 ms of real time across two "processes".
    start = dt.datetime(2026, 11, 21, 1, 50, 0, tzinfo=UTC)  # 02:00 comes after ~0.1 s
    t0 = time.monotonic()

    def clock() -> dt.datetime:
        return start + dt.timedelta(minutes=(time.monotonic() - t0) * 100)

    calls: list[str] = []
    s = Settings(data_dir=tmp_path, nightly_cron="0 2 * * *", database_url=catalogue_url)
    scheds = [
        NightlyScheduler(s, Catalogue(catalogue_url), run=_fake_run(calls), clock=clock)
        for _ in range(2)
    ]
    for sc in scheds:
        sc._stop.wait = lambda timeout, ev=sc._stop: threading.Event.wait(ev, 0.005)  # fast
        sc.start()
    deadline = time.monotonic() + 20
    while len(calls) < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.3)
    for sc in scheds:
        sc.stop()
    assert calls == ["run"], "exactly one of the two schedulers ran the 02:00 slot"
    assert sum(len(sc.runs) for sc in scheds) == 1


def test_failed_run_is_recorded(catalogue_url: str) -> None:
    cat = Catalogue(catalogue_url)

    def boom() -> dict[str, Any]:
        raise RuntimeError("baseline folder missing")

    rid = run_nightly_once(cat, dt.datetime(2026, 1, 1, tzinfo=UTC), "p", boom)
    rec = cat.get_regression(rid)
    assert rec["ok"] is False and "baseline folder missing" in rec["error"]
    cat.close()


def test_regression_routes_and_health(tmp_path: Path, catalogue_url: str) -> None:
    s = Settings(data_dir=tmp_path / "d", database_url=catalogue_url, api_token="t")
    with TestClient(create_app(s, run_jobs=False)) as tc:
        cat: Catalogue = tc.app.state.catalogue
        calls: list[str] = []
        rid = run_nightly_once(cat, dt.datetime(2026, 1, 1, tzinfo=UTC), "p",
                               _fake_run(calls, ok=False))  # fmt: skip
        h = {"Authorization": "Bearer t"}
        assert tc.get("/regressions").status_code == 401
        items = tc.get("/regressions", headers=h).json()["items"]
        assert [r["id"] for r in items] == [rid] and items[0]["ok"] is False
        one = tc.get(f"/regressions/{rid}", headers=h).json()
        assert one["report"] == {"summary": "2 studies, 0 regressions"}
        md = tc.get(f"/regressions/{rid}", params={"format": "markdown"}, headers=h)
        assert md.text == "# ok" and md.headers["content-type"].startswith("text/markdown")
        assert tc.get("/regressions/999", headers=h).status_code == 404
        health = tc.get("/health").json()
        assert health["nightly"]["id"] == rid and health["nightly"]["ok"] is False


# --------------------------------------------------------------------------- interrupted runs


def _ago(seconds: float) -> dt.datetime:
    return dt.datetime.now(UTC) - dt.timedelta(seconds=seconds)


def test_a_run_whose_process_died_is_marked_interrupted(catalogue_url: str) -> None:
    cat = Catalogue(catalogue_url)
    try:
        orphan = cat.add_regression("cron")  # its process died before it took its lease
        dead = cat.add_regression("api")  # held by an earlier process with this pid
        cat.acquire_lease(run_lease(dead), f"{socket.gethostname()}:{os.getpid()}:0ld0ld00", 120)
        elsewhere = cat.add_regression("cron")  # alive, as far as anyone can tell
        cat.acquire_lease(run_lease(elsewhere), "other-host:1:abcdef12", 120)

        ended, again = recover_interrupted(cat)
        assert ended == [dead]  # the orphan is within its grace period, elsewhere is alive
        assert again is not None and again > dt.datetime.now(UTC)
        rec = cat.get_regression(dead)
        assert rec["ok"] is False and rec["finished_at"] is not None
        assert rec["summary"].startswith("interrupted")
        assert "interrupted" in rec["error"] and "0ld0ld00" in rec["error"]
        assert rec["markdown"].startswith("# Nightly regression: INTERRUPTED")

        later = dt.datetime.now(UTC) + dt.timedelta(seconds=RUN_LEASE_GRACE_S + 1)
        ended, again = recover_interrupted(cat, now=later)
        assert ended == [orphan]  # past its grace; elsewhere's lease still runs (120 s)
        assert cat.get_regression(elsewhere)["ok"] is None
        expired = dt.datetime.now(UTC) + dt.timedelta(seconds=121)
        assert recover_interrupted(cat, now=expired) == ([elsewhere], None)
        assert "stopped renewing" in cat.get_regression(elsewhere)["error"]
        assert cat.unfinished_regressions() == []
        latest = cat.latest_regression()
        assert latest["id"] == elsewhere and latest["ok"] is False
    finally:
        cat.close()


def test_a_run_in_progress_is_never_taken_for_interrupted(
    catalogue_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import service.api.schedule as schedule

    monkeypatch.setattr(schedule, "RUN_LEASE_TTL_S", 0.3)  # beats every 0.1 s
    cat = Catalogue(catalogue_url)
    release = threading.Event()
    reg_id = cat.add_regression("api")

    def run() -> dict[str, Any]:
        release.wait(10)
        return {"ok": True, "report": {"summary": "fine"}, "markdown": "# ok"}

    t = threading.Thread(target=record_run, args=(cat, reg_id, run))
    t.start()
    try:
        time.sleep(0.2)
        first = cat.lease(run_lease(reg_id))
        assert first is not None and first["holder"] == PROCESS_HOLDER
        time.sleep(0.5)  # longer than the lease's life: only the heartbeat keeps it
        assert recover_interrupted(cat)[0] == []
        second = cat.lease(run_lease(reg_id))
        assert second is not None and second["expires_at"] > first["expires_at"]
    finally:
        release.set()
        t.join(10)
    rec = cat.get_regression(reg_id)
    assert rec["ok"] is True and rec["summary"] == "fine"
    assert cat.lease(run_lease(reg_id)) is None  # given back when the run ended
    cat.close()


def test_service_start_marks_runs_left_by_a_dead_process(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path / "d", api_token="t")
    s.data_dir.mkdir()
    cat = Catalogue(s.catalogue_url())
    reg_id = cat.add_regression("cron")  # as a killed process leaves it: ok null, its lease
    cat.acquire_lease(run_lease(reg_id), f"{socket.gethostname()}:{os.getpid()}:deadbeef", 120)
    cat.close()
    with TestClient(create_app(s, run_jobs=False)) as tc:
        h = {"Authorization": "Bearer t"}
        (item,) = tc.get("/regressions", headers=h).json()["items"]
        assert item["id"] == reg_id and item["ok"] is False
        assert item["summary"].startswith("interrupted") and item["finished_at"]
        md = tc.get(f"/regressions/{reg_id}", params={"format": "markdown"}, headers=h).text
        assert "INTERRUPTED" in md
        assert tc.get("/health").json()["nightly"]["summary"].startswith("interrupted")


# --------------------------------------------------------------------------- a client's report


def test_a_clients_report_is_catalogued(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path / "d", api_token="t")
    h = {"Authorization": "Bearer t"}
    report = {"ok": False, "summary": "2 studies, 10 points: 1 not ok: tiny failed",
              "started": "2026-11-22T02:00:00+00:00", "studies": [{"study": "tiny"}]}  # fmt: skip
    with TestClient(create_app(s, run_jobs=False)) as tc:
        body = {"report": report, "markdown": "# Nightly regression: FAILED\n"}
        assert tc.post("/regressions/reports", json=body).status_code == 401
        r = tc.post("/regressions/reports", json=body, headers=h)
        assert r.status_code == 201, r.text
        rec = r.json()
        assert r.headers["location"] == f"/regressions/{rec['id']}"
        assert rec["trigger"] == "client" and rec["ok"] is False
        assert rec["summary"] == report["summary"]
        assert rec["started_at"].startswith("2026-11-22T02:00:00") and rec["finished_at"]
        assert [x["id"] for x in tc.get("/regressions", headers=h).json()["items"]] == [rec["id"]]
        full = tc.get(f"/regressions/{rec['id']}", headers=h).json()
        assert full["report"] == report and full["markdown"] == body["markdown"]
        for bad in ({"report": {"summary": "x"}}, {"report": report, "extra": 1},
                    {"report": {**report, "ok": "perhaps"}}):  # fmt: skip
            r = tc.post("/regressions/reports", json=bad, headers=h)
            assert r.status_code == 422, (bad, r.text)
        assert tc.get("/regressions", headers=h).json()["total"] == 1
