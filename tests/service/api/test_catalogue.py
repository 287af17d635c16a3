"""The catalogue on SQLite and (in CI) PostgreSQL: studies, files, regressions, leases."""

from __future__ import annotations

import sqlite3
import threading

import pytest

from service.api.catalogue import Catalogue
from service.api.settings import Settings


@pytest.fixture
def cat(catalogue_url: str) -> Catalogue:
    c = Catalogue(catalogue_url)
    yield c
    c.close()


def test_add_study_is_idempotent_and_round_trips(cat: Catalogue) -> None:
    rec, created = cat.add_study("ab12cd34ef", "scan", '{"name": "scan"}', 10)
    assert created and rec["status"] == "queued" and rec["definition"] == {"name": "scan"}
    assert rec["points_irregular"] == rec["points_unsettled"] == 0
    again, created = cat.add_study("ab12cd34ef", "scan", '{"name": "scan"}', 10)
    assert not created and again["submitted_at"] == rec["submitted_at"]
    assert cat.list_studies()[1] == 1


def test_catalogue_from_before_the_unsettled_count_is_upgraded(catalogue_url: str) -> None:
    """A catalogue created before ``points_unsettled`` existed gets the column at startup."""
    from sqlalchemy import create_engine, inspect, text

    old = Catalogue(catalogue_url)
    old.add_study("0123abcd45", "old", "{}", 7)
    old.update_study("0123abcd45", points_irregular=3)
    old.close()
    engine = create_engine(catalogue_url)
    with engine.begin() as conn:  # the table as solver version 1 left it (before migrations)
        conn.execute(text("ALTER TABLE studies DROP COLUMN points_unsettled"))
        # and without what later revisions added (0002: the point store)
        conn.execute(text("ALTER TABLE studies DROP COLUMN points_computed"))
        conn.execute(text("ALTER TABLE studies DROP COLUMN points_reused"))
        for table in ("study_points", "points", "solvers"):
            conn.execute(text(f"DROP TABLE {table}"))
        conn.execute(text("ALTER TABLE leases DROP COLUMN generation"))  # and 0003's
        conn.execute(text("DROP TABLE alembic_version"))
    assert "points_unsettled" not in {c["name"] for c in inspect(engine).get_columns("studies")}
    engine.dispose()

    cats = [Catalogue(catalogue_url) for _ in range(2)]  # a second start finds it there
    cat = cats[0]
    rec = cat.get_study("0123abcd45")
    assert rec["points_unsettled"] == 0 and rec["points_irregular"] == 3
    cat.update_study("0123abcd45", points_unsettled=2)
    assert cats[1].get_study("0123abcd45")["points_unsettled"] == 2
    new, created = cat.add_study("0123abcd46", "new", "{}", 1)
    assert created and new["points_unsettled"] == 0
    for c in cats:
        c.close()


def test_concurrent_submissions_create_one_row(cat: Catalogue) -> None:
    results: list[bool] = []

    def add() -> None:
        results.append(cat.add_study("feedc0de00", "race", "{}", 1)[1])

    threads = [threading.Thread(target=add) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results.count(True) == 1 and len(results) == 8


def test_status_transitions_are_conditional(cat: Catalogue) -> None:
    cat.add_study("0000aaaa11", "s", "{}", 5)
    assert cat.set_status_if("0000aaaa11", ("queued",), "running")
    assert not cat.set_status_if("0000aaaa11", ("queued",), "running")
    cat.update_study("0000aaaa11", points_done=3, failures=[{"index": 1, "reason": "x"}])
    rec = cat.get_study("0000aaaa11")
    assert rec["points_done"] == 3 and rec["failures"] == [{"index": 1, "reason": "x"}]
    assert cat.ids_with_status(("running",)) == ["0000aaaa11"]


def test_name_filter_escapes_wildcards(cat: Catalogue) -> None:
    cat.add_study("0000000001", "a_b", "{}", 1)
    cat.add_study("0000000002", "axb", "{}", 1)
    assert [r["name"] for r in cat.list_studies(name="a_b")[0]] == ["a_b"]
    assert {r["name"] for r in cat.list_studies(name="a")[0]} == {"a_b", "axb"}


def test_name_filter_takes_every_character_literally(cat: Catalogue) -> None:
    for i, name in enumerate(["50%/a\\b", "50x/a\\b", "50%/ab", "5%"]):
        cat.add_study(f"000000001{i}", name, "{}", 1)
    assert [r["name"] for r in cat.list_studies(name="%/a\\")[0]] == ["50%/a\\b"]
    assert {r["name"] for r in cat.list_studies(name="%")[0]} == {"50%/a\\b", "50%/ab", "5%"}


def test_regressions_and_latest(cat: Catalogue) -> None:
    assert cat.latest_regression() is None
    rid = cat.add_regression("cron")
    assert cat.latest_regression() is None  # not finished yet
    cat.finish_regression(rid, ok=False, summary="1 moved", report={"x": 1}, markdown="# r")
    full = cat.get_regression(rid)
    assert full["ok"] is False and full["report"] == {"x": 1} and full["markdown"] == "# r"
    assert cat.latest_regression()["id"] == rid


def test_lease_is_exclusive_until_it_expires(cat: Catalogue) -> None:
    assert cat.acquire_lease("nightly:2026-01-01T02:00", "a", ttl_s=3600)
    assert not cat.acquire_lease("nightly:2026-01-01T02:00", "b", ttl_s=3600)
    assert cat.acquire_lease("nightly:2026-01-01T02:00", "a", ttl_s=3600)  # holder renews
    assert cat.acquire_lease("short", "a", ttl_s=-1)  # already expired
    assert cat.acquire_lease("short", "b", ttl_s=60)  # so another may take it
    cat.release_lease("nightly:2026-01-01T02:00", "a")
    assert cat.acquire_lease("nightly:2026-01-01T02:00", "b", ttl_s=60)


def test_lease_race_has_one_winner(catalogue_url: str) -> None:
    # Separate engines, as separate service processes would have.
    cats = [Catalogue(catalogue_url) for _ in range(4)]
    wins: list[str] = []

    def take(i: int) -> None:
        if cats[i].acquire_lease("nightly:race", f"p{i}", ttl_s=3600):
            wins.append(f"p{i}")

    threads = [threading.Thread(target=take, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for c in cats:
        c.close()
    assert len(wins) == 1


def test_default_catalogue_is_sqlite_in_data_dir(tmp_path) -> None:
    s = Settings(data_dir=tmp_path)
    assert s.catalogue_url() == f"sqlite:///{tmp_path.resolve() / 'catalogue.sqlite'}"
    assert Settings(data_dir=tmp_path, database_url="postgresql://x/y").catalogue_url() == (
        "postgresql://x/y"
    )


@pytest.mark.parametrize("bad", ["xyz", "61 2 * * *", "0 2 * *", "* * * * * *", "0 25 * * *"])
def test_bad_cron_is_rejected_with_clear_error(bad: str) -> None:
    with pytest.raises(ValueError, match=r"nightly_cron must be a 5-field cron expression"):
        Settings(nightly_cron=bad)
    assert Settings(nightly_cron="0 2 * * *").nightly_cron == "0 2 * * *"
    assert Settings(nightly_cron="").nightly_cron is None


class _LockedAtFirst:
    """A DB-API connection whose switch to WAL is refused ``locked`` times, as SQLite refuses a
    second connection switching a new file at the same moment (at once, no busy wait)."""

    def __init__(self, locked: int, message: str = "database is locked") -> None:
        self.locked = locked
        self.message = message
        self.done: list[str] = []

    def cursor(self) -> _LockedAtFirst:
        return self

    def execute(self, sql: str) -> None:
        if sql == "PRAGMA journal_mode=WAL" and self.locked > 0:
            self.locked -= 1
            raise sqlite3.OperationalError(self.message)
        self.done.append(sql)

    def close(self) -> None:
        pass


def test_a_new_catalogue_opened_by_several_processes_at_once_switches_to_wal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from service.api import catalogue

    monkeypatch.setattr(catalogue.time, "sleep", lambda s: None)
    conn = _LockedAtFirst(locked=3)
    catalogue._sqlite_pragmas(conn, None)
    assert conn.done[0] == "PRAGMA journal_mode=WAL" and "PRAGMA foreign_keys=ON" in conn.done
    # a lock that never goes away is still an error, after the tries
    with pytest.raises(sqlite3.OperationalError, match="locked"):
        catalogue._sqlite_pragmas(_LockedAtFirst(locked=catalogue.WAL_TRIES), None)
    # and any other error at once
    other = _LockedAtFirst(locked=1, message="disk I/O error")
    with pytest.raises(sqlite3.OperationalError, match="disk I/O"):
        catalogue._sqlite_pragmas(other, None)
    assert other.locked == 0 and other.done == []
