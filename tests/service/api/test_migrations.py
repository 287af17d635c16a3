"""Catalogue migrations (Alembic) on SQLite and (in CI) PostgreSQL: head matches the models, a
catalogue from before migrations is adopted with its rows, revisions go down and up again, a
newer database is refused clearly, concurrent starts are harmless, and ``impactcell db``."""

from __future__ import annotations

import datetime as dt
import re
import shutil
import threading
from pathlib import Path
from typing import Any

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import (
    Boolean,
    Column,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    create_engine,
    insert,
    inspect,
    text,
)

from service.api import migrate
from service.api.catalogue import Catalogue, metadata
from service.api.migrate import BASELINE, CatalogueSchemaError
from service.cli import main

# ------------------------------------------------------------------------------------------------
# Helpers

# The tables exactly as ``metadata.create_all`` made them before migrations (frozen here: the
# models will move on, catalogues made by that code will not).
PRE_MIGRATION = MetaData()
Table(
    "studies", PRE_MIGRATION,
    Column("id", String(64), primary_key=True),
    Column("name", String(200), nullable=False, index=True),
    Column("definition", Text, nullable=False),
    Column("status", String(16), nullable=False, index=True),
    Column("points_total", Integer, nullable=False),
    Column("points_done", Integer, nullable=False),
    Column("points_failed", Integer, nullable=False),
    Column("points_irregular", Integer, nullable=False),
    Column("points_unsettled", Integer, nullable=False, server_default=text("0")),
    Column("submitted_at", DateTime(timezone=True), nullable=False),
    Column("started_at", DateTime(timezone=True)),
    Column("finished_at", DateTime(timezone=True)),
    Column("wall_s", Float),
    Column("error", Text),
    Column("failures", Text, nullable=False),
    Column("seq", Integer, nullable=False),
)  # fmt: skip
Table(
    "result_files", PRE_MIGRATION,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("study_id", ForeignKey("studies.id", ondelete="CASCADE"), nullable=False, index=True),
    Column("path", Text, nullable=False),
    Column("size_bytes", Integer, nullable=False),
    Column("created_at", DateTime(timezone=True), nullable=False),
)  # fmt: skip
Table(
    "regressions", PRE_MIGRATION,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("started_at", DateTime(timezone=True), nullable=False),
    Column("finished_at", DateTime(timezone=True)),
    Column("ok", Boolean),
    Column("trigger", String(32), nullable=False),
    Column("summary", Text, nullable=False),
    Column("report_json", Text, nullable=False),
    Column("report_md", Text, nullable=False),
    Column("error", Text),
)  # fmt: skip
Table(
    "leases", PRE_MIGRATION,
    Column("name", String(200), primary_key=True),
    Column("holder", String(200), nullable=False),
    Column("expires_at", DateTime(timezone=True), nullable=False),
)  # fmt: skip

T0 = dt.datetime(2026, 1, 2, 3, 4, 5, tzinfo=dt.UTC)


def schema_diff(url: str) -> list[Any]:
    """Alembic's autogenerate differences between the database and the models (types and server
    defaults included): empty when the migrations' head is what the models declare."""
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            ctx = MigrationContext.configure(
                conn, opts={"compare_type": True, "compare_server_default": True}
            )
            return compare_metadata(ctx, metadata)
    finally:
        engine.dispose()


def tables(url: str) -> set[str]:
    engine = create_engine(url)
    try:
        return set(inspect(engine).get_table_names())
    finally:
        engine.dispose()


def execute(url: str, *statements: Any) -> None:
    engine = create_engine(url)
    try:
        with engine.begin() as conn:
            for st in statements:
                conn.execute(text(st) if isinstance(st, str) else st)
    finally:
        engine.dispose()


def create_pre_migration_catalogue(url: str) -> None:
    """A catalogue as the code before migrations left it: its tables and rows, no revision."""
    rows = {
        "studies": {
            "id": "0123abcd45", "name": "old", "definition": '{"name": "old"}',
            "status": "finished", "points_total": 4, "points_done": 4, "points_failed": 1,
            "points_irregular": 2, "points_unsettled": 1, "submitted_at": T0, "started_at": T0,
            "finished_at": T0, "wall_s": 1.5, "error": None, "failures": "[]", "seq": 1,
        },
        "result_files": {
            "study_id": "0123abcd45", "path": "old.nc", "size_bytes": 10, "created_at": T0,
        },
        "regressions": {
            "started_at": T0, "finished_at": T0, "ok": True, "trigger": "cron",
            "summary": "all match", "report_json": "{}", "report_md": "# ok", "error": None,
        },
        "leases": {"name": "nightly:x", "holder": "p1", "expires_at": T0.replace(year=2099)},
    }  # fmt: skip
    engine = create_engine(url)
    try:
        PRE_MIGRATION.create_all(engine)
        with engine.begin() as conn:
            for name, row in rows.items():
                conn.execute(insert(PRE_MIGRATION.tables[name]), [row])
    finally:
        engine.dispose()


# ------------------------------------------------------------------------------------------------
# (a) head is the models


def test_upgrading_an_empty_database_gives_the_models_schema(catalogue_url: str) -> None:
    assert migrate.current_revision(catalogue_url) is None
    assert migrate.upgrade(catalogue_url) == (None, migrate.head_revision())
    assert migrate.current_revision(catalogue_url) == migrate.head_revision()
    # A model changed without a revision (or a revision that differs from the models) fails here.
    assert schema_diff(catalogue_url) == []


def test_opening_a_catalogue_upgrades_it_and_a_second_open_changes_nothing(
    catalogue_url: str,
) -> None:
    Catalogue(catalogue_url).close()
    assert migrate.current_revision(catalogue_url) == migrate.head_revision()
    head = migrate.head_revision()
    assert migrate.upgrade(catalogue_url) == (head, head)


# ------------------------------------------------------------------------------------------------
# (b) catalogues from before migrations


def test_catalogue_from_before_migrations_is_stamped_and_keeps_its_rows(
    catalogue_url: str,
) -> None:
    create_pre_migration_catalogue(catalogue_url)
    assert "alembic_version" not in tables(catalogue_url)
    cat = Catalogue(catalogue_url)
    try:
        assert migrate.current_revision(catalogue_url) == migrate.head_revision()
        rec = cat.get_study("0123abcd45")
        assert rec["name"] == "old" and rec["definition"] == {"name": "old"}
        assert (rec["points_failed"], rec["points_irregular"], rec["points_unsettled"]) == (1, 2, 1)
        assert rec["submitted_at"] == "2026-01-02T03:04:05.000+00:00"
        assert cat.result_files("0123abcd45")[0]["path"] == "old.nc"
        assert cat.latest_regression()["summary"] == "all match"
        assert not cat.acquire_lease("nightly:x", "p2", ttl_s=60)  # p1's, held until 2099
        new, created = cat.add_study("0123abcd46", "new", "{}", 1)
        assert created and cat.list_studies()[1] == 2
    finally:
        cat.close()
    assert schema_diff(catalogue_url) == []


def test_baseline_is_what_create_all_made(tmp_path: Path) -> None:
    # The adoption check compares with the baseline revision: they must agree to begin with.
    old, new = f"sqlite:///{tmp_path / 'old.sqlite'}", f"sqlite:///{tmp_path / 'new.sqlite'}"
    create_pre_migration_catalogue(old)
    migrate.upgrade(new, BASELINE)
    engine_old, engine_new = create_engine(old), create_engine(new)
    try:
        with engine_old.connect() as a, engine_new.connect() as b:
            assert migrate._fingerprint(a) == migrate._fingerprint(b)
            assert set(migrate._fingerprint(a)) == set(migrate.BASELINE_TABLES)
    finally:
        engine_old.dispose()
        engine_new.dispose()


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("DROP TABLE leases", "table leases is missing"),
        ("DROP INDEX ix_studies_status", "studies indexes"),
        ("ALTER TABLE regressions ADD COLUMN extra INTEGER", "regressions columns"),
    ],
)
def test_catalogue_from_before_migrations_that_differs_is_refused(
    catalogue_url: str, damage: str, message: str
) -> None:
    create_pre_migration_catalogue(catalogue_url)
    execute(catalogue_url, damage)
    with pytest.raises(CatalogueSchemaError, match=rf"differ from revision {BASELINE}.*{message}"):
        Catalogue(catalogue_url)
    # Left as it was: no stamp, the rows there.
    assert "alembic_version" not in tables(catalogue_url)
    engine = create_engine(catalogue_url)
    try:
        with engine.connect() as conn:
            assert conn.execute(text("SELECT count(*) FROM studies")).scalar() == 1
    finally:
        engine.dispose()


def test_unrelated_tables_do_not_make_a_catalogue(catalogue_url: str) -> None:
    # A shared database with someone else's tables is an empty catalogue, not an old one.
    execute(catalogue_url, "CREATE TABLE other_app (id INTEGER PRIMARY KEY)")
    try:
        assert migrate.upgrade(catalogue_url) == (None, migrate.head_revision())
        assert "other_app" in tables(catalogue_url)
    finally:
        execute(catalogue_url, "DROP TABLE other_app")


# ------------------------------------------------------------------------------------------------
# (c) down and up again


def test_every_revision_goes_down_to_base_and_up_again(catalogue_url: str) -> None:
    revisions = [rev for rev, _ in migrate.history()]
    for rev in revisions:  # one step at a time, as deployments meet them
        migrate.upgrade(catalogue_url, rev)
        assert migrate.current_revision(catalogue_url) == rev
    cat = Catalogue(catalogue_url)
    cat.add_study("feedc0de01", "s", "{}", 1)
    cat.close()
    for i in range(len(revisions) - 1, -1, -1):
        migrate.downgrade(catalogue_url, revisions[i - 1] if i else "base")
        assert migrate.current_revision(catalogue_url) == (revisions[i - 1] if i else None)
    assert not tables(catalogue_url) & (set(migrate.BASELINE_TABLES) | set(metadata.tables))
    assert migrate.upgrade(catalogue_url) == (None, migrate.head_revision())
    assert schema_diff(catalogue_url) == []


# ------------------------------------------------------------------------------------------------
# (d) a newer database


def test_a_revision_from_newer_code_is_refused_naming_both(catalogue_url: str) -> None:
    migrate.upgrade(catalogue_url)
    execute(catalogue_url, "UPDATE alembic_version SET version_num = '0099'")
    head = migrate.head_revision()
    with pytest.raises(CatalogueSchemaError, match=rf"revision 0099.*newest is {head}"):
        Catalogue(catalogue_url)
    with pytest.raises(CatalogueSchemaError, match="0099"):
        migrate.downgrade(catalogue_url, "base")
    assert migrate.current_revision(catalogue_url) == "0099"  # untouched


# ------------------------------------------------------------------------------------------------
# Concurrency


@pytest.mark.parametrize("old", [False, True], ids=["empty", "before-migrations"])
def test_concurrent_starts_migrate_once(catalogue_url: str, old: bool) -> None:
    if old:
        create_pre_migration_catalogue(catalogue_url)
    results: list[Any] = []
    start = threading.Barrier(4)

    def open_one() -> None:
        start.wait()
        try:
            results.append(migrate.upgrade(catalogue_url))
        except Exception as exc:  # collected: the assertion below names it
            results.append(exc)

    threads = [threading.Thread(target=open_one) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    head = migrate.head_revision()
    assert all(isinstance(r, tuple) for r in results), results
    assert results.count((None, head)) == 1 and results.count((head, head)) == 3, results
    cat = Catalogue(catalogue_url)
    try:
        assert cat.list_studies()[1] == (1 if old else 0)
    finally:
        cat.close()


def test_in_memory_sqlite_is_refused_clearly() -> None:
    with pytest.raises(ValueError, match="in-memory SQLite"):
        Catalogue("sqlite://")


# ------------------------------------------------------------------------------------------------
# impactcell db


def test_db_commands(
    catalogue_url: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    head = migrate.head_revision()
    monkeypatch.setenv("IMPACTCELL_DATABASE_URL", catalogue_url)  # through Settings
    assert main(["db", "current"]) == 0
    out = capsys.readouterr().out  # (SQLite: no file yet; PostgreSQL: no revision)
    assert "no database yet" in out or "no revision" in out
    assert main(["db", "upgrade"]) == 0
    assert f"upgraded from nothing to {head}" in capsys.readouterr().out
    assert main(["db", "current"]) == 0
    assert f": {head} (head)" in capsys.readouterr().out
    assert main(["db", "upgrade", "--database-url", catalogue_url]) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert main(["db", "downgrade", "base"]) == 2
    assert "--yes" in capsys.readouterr().err
    assert main(["db", "downgrade", "base", "--yes"]) == 0
    assert f"downgraded from {head} to base" in capsys.readouterr().out
    assert main(["db", "upgrade"]) == 0
    capsys.readouterr()
    execute(catalogue_url, "UPDATE alembic_version SET version_num = '0099'")
    assert main(["db", "current"]) == 0
    assert "0099 (unknown to this impactcell" in capsys.readouterr().out
    assert main(["db", "upgrade"]) == 1
    err = capsys.readouterr().err
    assert "revision 0099" in err and f"newest is {head}" in err and "Traceback" not in err


def test_db_commands_default_to_sqlite_in_the_data_dir(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("IMPACTCELL_DATABASE_URL", raising=False)
    data = tmp_path / "data"
    assert main(["db", "current", "--data-dir", str(data)]) == 0
    assert "no database yet" in capsys.readouterr().out and not data.exists()
    assert main(["db", "upgrade", "--data-dir", str(data)]) == 0
    assert (data / "catalogue.sqlite").is_file()
    assert main(["db", "downgrade", "0042", "--data-dir", str(data)]) == 1
    assert "Can't locate revision identified by '0042'" in capsys.readouterr().err
    assert main(["db", "history"]) == 0
    assert f"{migrate.head_revision()}  " in capsys.readouterr().out
    bad = "postgresql+psycopg://u:secret@127.0.0.1:1/none"
    assert main(["db", "current", "--database-url", bad]) == 1
    err = capsys.readouterr().err
    assert "u:***@127.0.0.1:1/none" in err and "secret" not in err


def test_new_revision_autogenerates_from_the_models(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # On a copy of the scripts: models unchanged, so the next revision has nothing to do, and it
    # applies on top of the others.
    scripts = tmp_path / "migrations"
    shutil.copytree(migrate.MIGRATIONS_DIR, scripts, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(migrate, "MIGRATIONS_DIR", scripts)
    migrate._scripts.cache_clear()
    try:
        before = migrate.head_revision()
        path = migrate.new_revision("nothing yet")
        assert path.parent == scripts / "versions"
        assert path.name == f"{int(before) + 1:04d}_nothing_yet.py"
        body = path.read_text()
        assert f"Revises: {before}\n" in body
        assert re.search(rf"down_revision: .* = [\"']{before}[\"']", body)  # ruff-formatted or not
        assert "op." not in body.split("def upgrade")[1]
        url = f"sqlite:///{tmp_path / 'c.sqlite'}"
        assert migrate.upgrade(url) == (None, path.name[:4])
    finally:
        monkeypatch.undo()
        migrate._scripts.cache_clear()


def test_a_missing_database_driver_is_named_with_the_url_and_how_to_install_it() -> None:
    import importlib.util

    url = "mysql+mysqldb://u:secret@127.0.0.1:1/none"
    if importlib.util.find_spec("MySQLdb") is not None:  # the driver is there: no error to see
        migrate.create_catalogue_engine(url).dispose()
        return
    with pytest.raises(migrate.CatalogueDriverError) as err:
        migrate.create_catalogue_engine(url)
    text = str(err.value)
    assert "MySQLdb" in text and "u:***@127.0.0.1:1/none" in text and "secret" not in text
