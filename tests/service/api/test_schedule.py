"""The nightly schedule: cron slots, one run per slot across processes, reports in the API."""

from __future__ import annotations

import datetime as dt
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.catalogue import Catalogue
from service.api.schedule import NightlyScheduler, next_slot, run_nightly_once
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
