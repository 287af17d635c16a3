"""Schema migrations of the catalogue (Alembic), run at startup and by ``impactcell db``.

The migration environment ships inside the package (``service/api/migrations/``: ``env.py``,
``script.py.mako``, ``versions/``) and Alembic is configured here, in code, so an installed
package needs no ``alembic.ini``. :func:`upgrade` brings any catalogue database to the newest
revision:

- a new, empty database gets every revision;
- a catalogue created before migrations existed (its tables, no ``alembic_version``) is checked
  against the first revision's schema, stamped at it, then upgraded: its rows are kept;
- a database at a revision this code does not know (written by a newer impactcell) is refused
  with :class:`CatalogueSchemaError` naming both revisions, and left untouched.

Concurrency: the whole upgrade is one transaction that first takes a lock (PostgreSQL: an
advisory lock; SQLite: ``BEGIN IMMEDIATE``, the database's write lock), and both databases roll
DDL back with the transaction. A second process starting at the same time waits, then finds the
database at head and does nothing. On other databases, an upgrade that fails because another
process got there first is recognised afterwards and passes.
"""

from __future__ import annotations

import functools
import logging
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from alembic.util import CommandError
from sqlalchemy import create_engine, event, inspect, make_url, text
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.pool import NullPool

__all__ = [
    "BASELINE",
    "MIGRATIONS_DIR",
    "CatalogueSchemaError",
    "alembic_config",
    "current_revision",
    "downgrade",
    "head_revision",
    "history",
    "new_revision",
    "upgrade",
]

log = logging.getLogger("impactcell.catalogue")

MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"
# The first revision: exactly the schema ``metadata.create_all`` made before migrations.
BASELINE = "0001"
# The tables of the baseline. A database holding any of them but no ``alembic_version`` is a
# catalogue from before migrations.
BASELINE_TABLES = ("studies", "result_files", "regressions", "leases")
# Columns the pre-migration startup added to older catalogues itself (additive, with a server
# default); a catalogue last opened by code older than that still lacks them, so adoption adds
# them before comparing with the baseline.
_PRE_MIGRATION_ADDITIONS = {
    ("studies", "points_unsettled"): "INTEGER DEFAULT 0 NOT NULL",
}
# pg_advisory_xact_lock key of catalogue migrations (any constant; "impactcl" in ASCII).
_PG_LOCK_KEY = 0x696D70616374636C


class CatalogueError(RuntimeError):
    """The catalogue database cannot be used (the message says why)."""


class CatalogueSchemaError(CatalogueError):
    """The catalogue database's schema is not one this code can upgrade or use."""


class CatalogueDriverError(CatalogueError):
    """The Python driver a database URL names is not installed."""


def create_catalogue_engine(url: Any, **kwargs: Any) -> Engine:
    """``sqlalchemy.create_engine``, with a missing driver reported as what it is: the URL
    (password hidden), the module and how to install it (SQLAlchemy raises a bare
    ``ModuleNotFoundError`` from deep inside)."""
    try:
        return create_engine(url, **kwargs)
    except ImportError as exc:
        shown = make_url(url).render_as_string(hide_password=True)
        extra = " (pip install -e '.[postgres]')" if "postgres" in shown.split(":")[0] else ""
        raise CatalogueDriverError(
            f"the catalogue database URL {shown} needs the Python driver {exc.name or exc}, "
            f"which is not installed{extra}"
        ) from None


# ------------------------------------------------------------------------------------------------
# Alembic's configuration and scripts


def alembic_config(connection: Connection | None = None, **attributes: Any) -> Config:
    """Alembic's configuration for the catalogue: the package's scripts, no ``alembic.ini``.

    ``connection`` is what ``env.py`` migrates (it never opens one of its own).
    """
    cfg = Config(attributes={"connection": connection, **attributes})
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    # Revision files are named by their number: 0002_add_study_owner.py
    cfg.set_main_option("file_template", "%%(rev)s_%%(slug)s")
    return cfg


@functools.cache
def _scripts() -> ScriptDirectory:
    # Parsed once per process: the revision files do not change while it runs.
    return ScriptDirectory.from_config(alembic_config())


def head_revision() -> str:
    """The newest revision this code knows."""
    head = _scripts().get_current_head()
    if head is None:  # a packaging error: versions/ missing from the install
        raise CatalogueSchemaError(f"no catalogue migrations found in {MIGRATIONS_DIR}/versions")
    return head


def history() -> list[tuple[str, str]]:
    """Every revision as (id, message), oldest first."""
    revs = list(_scripts().walk_revisions())
    return [(r.revision, r.doc or "") for r in reversed(revs)]


# ------------------------------------------------------------------------------------------------
# Connections that migrate safely


def _engine(url: str, *, lock: bool = True) -> Engine:
    """An engine without a pool whose transactions (with ``lock``) exclude other migrators.

    SQLite: the driver's own transaction handling is turned off so that SQLAlchemy's BEGIN is
    ``BEGIN IMMEDIATE`` (the write lock, taken before reading the revision) and the DDL runs
    inside it; foreign keys are off, because Alembic's batch mode recreates a table by dropping
    it, and with them on, dropping ``studies`` would cascade-delete every ``result_files`` row.
    """
    u = make_url(url)
    if u.get_backend_name() == "sqlite" and u.database in (None, "", ":memory:"):
        raise ValueError(
            f"the catalogue needs a database that outlives a connection; {url!r} is an "
            "in-memory SQLite database (use a file: sqlite:////path/catalogue.sqlite)"
        )
    if u.get_backend_name() != "sqlite":
        return create_catalogue_engine(u, poolclass=NullPool)
    engine = create_catalogue_engine(u, poolclass=NullPool, connect_args={"timeout": 30})
    if not lock:  # reading the revision only: no need to wait for a writer
        return engine

    @event.listens_for(engine, "connect")
    def _connect(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None
        dbapi_conn.execute("PRAGMA foreign_keys=OFF")

    @event.listens_for(engine, "begin")
    def _begin(conn: Connection) -> None:
        conn.exec_driver_sql("BEGIN IMMEDIATE")

    return engine


@contextmanager
def _locked(url: str) -> Iterator[Connection]:
    """A connection in a transaction that holds the migration lock; committed on success."""
    engine = _engine(url)
    try:
        with engine.begin() as conn:
            if conn.dialect.name == "postgresql":
                # Released with the transaction; a second migrator waits here.
                conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_LOCK_KEY})
            yield conn
            if conn.dialect.name == "sqlite":
                _check_foreign_keys(conn)
    finally:
        engine.dispose()


def _check_foreign_keys(conn: Connection) -> None:
    # Foreign keys were off while migrating; refuse to commit a revision that broke them.
    bad = conn.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
    if bad:
        raise CatalogueSchemaError(
            f"the migration left rows whose foreign keys point nowhere: {bad[:5]}; rolled back"
        )


def _current(conn: Connection) -> tuple[str, ...]:
    return tuple(MigrationContext.configure(conn).get_current_heads())


# ------------------------------------------------------------------------------------------------
# Upgrade, downgrade, current


def current_revision(url: str) -> str | None:
    """The database's revision: None for an empty database or one from before migrations."""
    engine = _engine(url, lock=False)
    try:
        with engine.connect() as conn:
            heads = _current(conn)
    finally:
        engine.dispose()
    return ", ".join(heads) if heads else None


def upgrade(url: str, target: str = "head") -> tuple[str | None, str]:
    """Migrate the catalogue at ``url`` to ``target``; returns (revision before, after).

    Raises
    ------
    CatalogueSchemaError
        The database is at a revision this code does not know, or it holds catalogue tables
        without a revision that differ from the first revision's schema.
    """
    try:
        return _upgrade(url, target)
    except (CatalogueSchemaError, ValueError):
        raise
    except Exception:
        # Without a lock (databases other than SQLite and PostgreSQL), another process may have
        # migrated between our check and our DDL: then the database is where we wanted it.
        if target == "head" and _at_head(url):
            log.info("catalogue migrated by another process meanwhile")
            return head_revision(), head_revision()
        raise


def _at_head(url: str) -> bool:
    try:
        return current_revision(url) == head_revision()
    except Exception:  # unreachable, say: the original error is the one to report
        return False


def _upgrade(url: str, target: str) -> tuple[str | None, str]:
    head = head_revision()
    with _locked(url) as conn:
        before = _current(conn)
        _check_known(before)
        if not before and _has_catalogue_tables(conn):
            _adopt(conn)
        if before == (head,) and target in ("head", head):
            return head, head  # the usual start: nothing to do
        with _alembic_errors():
            command.upgrade(alembic_config(conn), target)
        after = _current(conn)
    start = ", ".join(before) or None
    end = ", ".join(after)
    if before != after:
        log.info("catalogue migrated from %s to %s", start or "an empty database", end)
    return start, end


def downgrade(url: str, target: str) -> tuple[str | None, str | None]:
    """Migrate the catalogue back to ``target`` ("base": no tables); returns (before, after).

    Raises
    ------
    CatalogueSchemaError
        The database is at a revision this code does not know.
    """
    with _locked(url) as conn:
        before = _current(conn)
        _check_known(before)
        with _alembic_errors():
            command.downgrade(alembic_config(conn), target)
        after = _current(conn)
    return ", ".join(before) or None, ", ".join(after) or None


@contextmanager
def _alembic_errors() -> Iterator[None]:
    # Alembic's own refusals (an unknown target, an upgrade target below the current revision)
    # are the user's to fix, not a crash: one error type for the CLI and the service to report.
    try:
        yield
    except CommandError as exc:
        raise CatalogueSchemaError(str(exc)) from exc


def _check_known(current: tuple[str, ...]) -> None:
    scripts = _scripts()
    known = {s.revision for s in scripts.walk_revisions()}
    unknown = [r for r in current if r not in known]
    if unknown:
        raise CatalogueSchemaError(
            f"the catalogue database is at revision {', '.join(unknown)}, which this impactcell "
            f"does not know (its newest is {head_revision()}): a newer impactcell migrated it. "
            f"Run that version, or downgrade the database with it first "
            f"(impactcell db downgrade {head_revision()})."
        )


# ------------------------------------------------------------------------------------------------
# Catalogues from before migrations


def _has_catalogue_tables(conn: Connection) -> bool:
    return bool(set(inspect(conn).get_table_names()) & set(BASELINE_TABLES))


def _adopt(conn: Connection) -> None:
    """Stamp a catalogue made by ``create_all`` at the baseline, once its schema is checked."""
    insp = inspect(conn)
    have = set(insp.get_table_names())
    for (table, column), ddl in _PRE_MIGRATION_ADDITIONS.items():
        if table in have and column not in {c["name"] for c in insp.get_columns(table)}:
            conn.execute(text(f"ALTER TABLE {table} ADD COLUMN {column} {ddl}"))
            log.info("catalogue from before migrations: added %s.%s", table, column)
    found = _fingerprint(conn)
    expected = _baseline_fingerprint()
    problems = _differences(expected, found)
    if problems:
        raise CatalogueSchemaError(
            "the catalogue database has catalogue tables but no migration revision, and they "
            f"differ from revision {BASELINE} (the schema before migrations), so it cannot be "
            "adopted: " + "; ".join(problems)
        )
    command.stamp(alembic_config(conn), BASELINE)
    log.info("catalogue from before migrations stamped at revision %s", BASELINE)


def _fingerprint(conn: Connection) -> dict[str, dict[str, Any]]:
    """What of the baseline tables any dialect reflects alike: columns (nullable), primary key,
    indexes and foreign keys (not types: SQLite and PostgreSQL name them differently)."""
    insp = inspect(conn)
    have = set(insp.get_table_names())
    out: dict[str, dict[str, Any]] = {}
    for table in BASELINE_TABLES:
        if table not in have:
            continue
        out[table] = {
            "columns": {c["name"]: bool(c["nullable"]) for c in insp.get_columns(table)},
            "primary key": sorted(insp.get_pk_constraint(table)["constrained_columns"]),
            "indexes": {
                i["name"]: (tuple(i["column_names"]), bool(i["unique"]))
                for i in insp.get_indexes(table)
            },
            "foreign keys": sorted(
                (
                    tuple(f["constrained_columns"]),
                    f["referred_table"],
                    tuple(f["referred_columns"]),
                    (f.get("options") or {}).get("ondelete"),
                )
                for f in insp.get_foreign_keys(table)
            ),
        }
    return out


@functools.cache
def _baseline_fingerprint() -> dict[str, dict[str, Any]]:
    # The baseline revision itself, run on a scratch SQLite file, is the reference.
    with tempfile.TemporaryDirectory(prefix="impactcell-baseline-") as tmp:
        url = f"sqlite:///{Path(tmp) / 'baseline.sqlite'}"
        with _locked(url) as conn:
            command.upgrade(alembic_config(conn), BASELINE)
            return _fingerprint(conn)


def _differences(expected: dict[str, dict[str, Any]], found: dict[str, dict[str, Any]]) -> list:
    out = [f"table {t} is missing" for t in expected if t not in found]
    for table, want in expected.items():
        got = found.get(table)
        if got is None:
            continue
        for what, value in want.items():
            if got[what] != value:
                out.append(f"{table} {what}: expected {value}, found {got[what]}")
    return out


# ------------------------------------------------------------------------------------------------
# New revisions (developers)


def new_revision(message: str, *, autogenerate: bool = True) -> Path:
    """Write the next revision file into ``service/api/migrations/versions/``; returns its path.

    With ``autogenerate``, its operations are the difference between the models of
    :mod:`service.api.catalogue` and a scratch SQLite database at head; review them before
    committing. Meant for a checkout (an editable install), where that folder is the source.
    """
    rev_id = f"{len(history()) + 1:04d}"
    with tempfile.TemporaryDirectory(prefix="impactcell-revision-") as tmp:
        url = f"sqlite:///{Path(tmp) / 'head.sqlite'}"
        if rev_id != "0001":  # (the first revision is made against an empty database)
            upgrade(url)
        with _locked(url) as conn:
            cfg = alembic_config(conn)
            if shutil.which("ruff"):  # the house style for generated code
                cfg.set_section_option("post_write_hooks", "hooks", "ruff_format")
                cfg.set_section_option("post_write_hooks", "ruff_format.type", "exec")
                cfg.set_section_option("post_write_hooks", "ruff_format.executable", "ruff")
                cfg.set_section_option(
                    "post_write_hooks", "ruff_format.options", "format REVISION_SCRIPT_FILENAME"
                )
            script = command.revision(cfg, message, autogenerate=autogenerate, rev_id=rev_id)
    _scripts.cache_clear()
    assert script is not None and not isinstance(script, list)
    return Path(script.path)
