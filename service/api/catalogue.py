"""The results catalogue: studies, their results files, regression reports and leases.

SQLAlchemy 2 on any URL: a SQLite file in the data dir by default, PostgreSQL (or anything
SQLAlchemy speaks) through ``IMPACTCELL_DATABASE_URL``. Access goes through the plain methods of
:class:`Catalogue`; callers never see sessions.

The schema is versioned with Alembic (:mod:`service.api.migrate`, revisions in
``service/api/migrations/versions/``): opening a catalogue upgrades its database to the newest
revision, so a model change here needs a revision there (``impactcell db revision``);
``tests/service/api/test_migrations.py`` fails until the two agree.
"""

from __future__ import annotations

import datetime as dt
import json
import sqlite3
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from sqlalchemy import (
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    delete,
    event,
    func,
    select,
    text,
    update,
)
from sqlalchemy.engine import Engine
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

from service.api import migrate

__all__ = [
    "ACTIVE",
    "RESUMABLE",
    "RUNNING",
    "STATUSES",
    "Catalogue",
    "metadata",
    "utcnow",
]

# queued → running ⇄ waiting → finished | failed | cancelled; resume puts cancelled/failed back in
# the queue. ``waiting``: running, but paused by an outage (the database or the disk; the reason
# in ``error``), retried with backoff until it goes on by itself.
STATUSES = ("queued", "running", "waiting", "finished", "failed", "cancelled")
ACTIVE = ("queued", "running", "waiting")  # can be cancelled; left by a stopped service: run again
RUNNING = ("running", "waiting")  # a process runs it (holding its lease)
RESUMABLE = ("cancelled", "failed")  # can be resumed


def utcnow() -> dt.datetime:
    """Timezone-aware UTC now (stored as UTC; SQLite drops the zone, so it is put back on read)."""
    return dt.datetime.now(dt.UTC)


def _iso(t: dt.datetime | None) -> str | None:
    if t is None:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.UTC)
    return t.isoformat(timespec="milliseconds")


class _Base(DeclarativeBase):
    pass


class StudyRow(_Base):
    __tablename__ = "studies"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    name: Mapped[str] = mapped_column(String(200), index=True)
    definition: Mapped[str] = mapped_column(Text)  # canonical JSON
    status: Mapped[str] = mapped_column(String(16), index=True)
    points_total: Mapped[int] = mapped_column(Integer)
    points_done: Mapped[int] = mapped_column(Integer, default=0)
    points_failed: Mapped[int] = mapped_column(Integer, default=0)
    points_irregular: Mapped[int] = mapped_column(Integer, default=0)
    # Added with solver version 2 (outcomes), before migrations: adopting an older catalogue
    # adds it (service.api.migrate).
    points_unsettled: Mapped[int] = mapped_column(Integer, default=0, server_default=text("0"))
    submitted_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True))
    started_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True))
    wall_s: Mapped[float | None] = mapped_column(Float)
    error: Mapped[str | None] = mapped_column(Text)
    failures: Mapped[str] = mapped_column(Text, default="[]")  # JSON: a sample of reasons
    seq: Mapped[int] = mapped_column(Integer, default=0)  # submission order (queue order)
    # Of the points of its last run: computed by it, and taken from the point store (0002).
    points_computed: Mapped[int] = mapped_column(Integer, default=0, server_default=text("0"))
    points_reused: Mapped[int] = mapped_column(Integer, default=0, server_default=text("0"))


class ResultFileRow(_Base):
    __tablename__ = "result_files"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    study_id: Mapped[str] = mapped_column(ForeignKey("studies.id", ondelete="CASCADE"), index=True)
    path: Mapped[str] = mapped_column(Text)
    size_bytes: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True))


class RegressionRow(_Base):
    __tablename__ = "regressions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    started_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True))
    ok: Mapped[bool | None] = mapped_column(Boolean)
    trigger: Mapped[str] = mapped_column(String(32))
    summary: Mapped[str] = mapped_column(Text, default="")
    report_json: Mapped[str] = mapped_column(Text, default="{}")
    report_md: Mapped[str] = mapped_column(Text, default="")
    error: Mapped[str | None] = mapped_column(Text)


class LeaseRow(_Base):
    __tablename__ = "leases"

    name: Mapped[str] = mapped_column(String(200), primary_key=True)
    holder: Mapped[str] = mapped_column(String(200))
    expires_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True))
    # The fencing token (0003): one more at every acquisition that is not a renewal.
    generation: Mapped[int] = mapped_column(Integer, default=0, server_default=text("0"))


class PointRow(_Base):
    """One computed point (service.api.points): its key, parameters (indexed), result."""

    __tablename__ = "points"
    __table_args__ = (
        # theta = …, gap = …, gamma_r in a range (the common cross-study question)
        Index("ix_points_version_theta_g1_gamma_r", "version", "theta", "g1", "gamma_r"),
    )

    key: Mapped[str] = mapped_column(String(32), primary_key=True)
    version: Mapped[str] = mapped_column(String(16))
    method: Mapped[str] = mapped_column(String(16))
    solver: Mapped[str] = mapped_column(ForeignKey("solvers.key"))
    start: Mapped[str] = mapped_column(String(40))  # rest | an initial kind | after:<key>
    coupling: Mapped[str] = mapped_column(String(16))
    modes: Mapped[int] = mapped_column(Integer)
    theta: Mapped[float] = mapped_column(Float)
    sigma: Mapped[float] = mapped_column(Float, index=True)
    gamma_s: Mapped[float] = mapped_column(Float)
    gamma_r: Mapped[float] = mapped_column(Float, index=True)
    xi: Mapped[float] = mapped_column(Float)
    xi_b: Mapped[float | None] = mapped_column(Float)
    g1: Mapped[float] = mapped_column(Float)
    g2: Mapped[float] = mapped_column(Float)
    e1: Mapped[float | None] = mapped_column(Float)  # NULL: stored before restitution (0)
    e2: Mapped[float | None] = mapped_column(Float)
    cells: Mapped[int | None] = mapped_column(Integer)  # a chain's N; NULL: the unit cell
    outcome: Mapped[str] = mapped_column(String(16))
    transmittance_db: Mapped[float | None] = mapped_column(Float)
    record: Mapped[str] = mapped_column(Text)  # JSON: the worker's whole record
    created_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True))


class SolverRow(_Base):
    """Solver settings, once per distinct set (points refer to them by key)."""

    __tablename__ = "solvers"

    key: Mapped[str] = mapped_column(String(32), primary_key=True)
    settings: Mapped[str] = mapped_column(Text)  # JSON


class StudyPointRow(_Base):
    """Which study uses which point, at which index of its work order."""

    __tablename__ = "study_points"

    study_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    idx: Mapped[int] = mapped_column(Integer, primary_key=True)
    key: Mapped[str] = mapped_column(String(32), index=True)


# The models' schema: what the migrations' head must create (and autogenerate compares with).
metadata = _Base.metadata


def _aware(t: dt.datetime | None) -> dt.datetime | None:
    if t is None or t.tzinfo is not None:
        return t
    return t.replace(tzinfo=dt.UTC)  # SQLite hands back naive datetimes (stored as UTC)


def _study_dict(r: StudyRow) -> dict[str, Any]:
    return {
        "id": r.id,
        "name": r.name,
        "status": r.status,
        "definition": json.loads(r.definition),
        "points_total": r.points_total,
        "points_done": r.points_done,
        "points_failed": r.points_failed,
        "points_irregular": r.points_irregular,
        "points_unsettled": r.points_unsettled,
        "submitted_at": _iso(r.submitted_at),
        "started_at": _iso(r.started_at),
        "finished_at": _iso(r.finished_at),
        "wall_s": r.wall_s,
        "error": r.error,
        "failures": json.loads(r.failures or "[]"),
        "points_computed": r.points_computed,
        "points_reused": r.points_reused,
    }


def _regression_dict(r: RegressionRow, full: bool) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": r.id,
        "started_at": _iso(r.started_at),
        "finished_at": _iso(r.finished_at),
        "ok": r.ok,
        "trigger": r.trigger,
        "summary": r.summary,
        "error": r.error,
    }
    if full:
        out["report"] = json.loads(r.report_json or "{}")
        out["markdown"] = r.report_md
    return out


class Catalogue:
    """Plain functions over the catalogue database (thread-safe: a session per call)."""

    def __init__(self, url: str) -> None:
        """Open the catalogue at ``url``, first upgrading its database to the newest revision.

        Raises
        ------
        service.api.migrate.CatalogueSchemaError
            The database is at a revision this code does not know (a newer impactcell's), or
            holds catalogue tables from before migrations that do not match their schema.
        """
        kwargs: dict[str, Any] = {"pool_pre_ping": True}
        if url.startswith("sqlite"):
            # The service's runner thread and request threads share the file.
            kwargs["connect_args"] = {"check_same_thread": False, "timeout": 30}
        self.url = url
        # Before any connection of ours: the schema this code reads and writes, or a clear error.
        migrate.upgrade(url)
        self.engine: Engine = migrate.create_catalogue_engine(url, **kwargs)
        if url.startswith("sqlite"):
            event.listen(self.engine, "connect", _sqlite_pragmas)
        self._session = sessionmaker(self.engine, expire_on_commit=False)

    def close(self) -> None:
        """Release the connection pool."""
        self.engine.dispose()

    @contextmanager
    def _tx(self) -> Iterator[Session]:
        with self._session.begin() as s:
            yield s

    # ------------------------------------------------------------------ studies

    def add_study(
        self, study_id: str, name: str, definition: str, points_total: int
    ) -> tuple[dict[str, Any], bool]:
        """Insert a queued study; returns (record, created). An existing id is returned as is."""
        with self._tx() as s:
            row = s.get(StudyRow, study_id)
            if row is not None:
                return _study_dict(row), False
        try:
            with self._tx() as s:
                seq = (s.scalar(select(func.max(StudyRow.seq))) or 0) + 1
                row = StudyRow(
                    id=study_id, name=name, definition=definition, status="queued",
                    points_total=points_total, points_done=0, points_failed=0,
                    points_irregular=0, points_unsettled=0, submitted_at=utcnow(),
                    failures="[]", seq=seq,
                )  # fmt: skip
                s.add(row)
                s.flush()
                return _study_dict(row), True
        except IntegrityError:  # another request inserted it first
            with self._tx() as s:
                row = s.get(StudyRow, study_id)
                assert row is not None
                return _study_dict(row), False

    def get_study(self, study_id: str) -> dict[str, Any] | None:
        """The study's record, or None."""
        with self._tx() as s:
            row = s.get(StudyRow, study_id)
            return None if row is None else _study_dict(row)

    def list_studies(
        self,
        *,
        status: str | None = None,
        name: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[dict[str, Any]], int]:
        """Studies newest first, filtered by status and name (substring); and the total."""
        q = select(StudyRow)
        cq = select(func.count()).select_from(StudyRow)
        if status:
            q, cq = q.where(StudyRow.status == status), cq.where(StudyRow.status == status)
        if name:  # a substring, with % and _ taken literally
            q = q.where(StudyRow.name.contains(name, autoescape=True))
            cq = cq.where(StudyRow.name.contains(name, autoescape=True))
        q = q.order_by(StudyRow.seq.desc()).limit(limit).offset(offset)
        with self._tx() as s:
            rows = s.scalars(q).all()
            total = int(s.scalar(cq) or 0)
            return [_study_dict(r) for r in rows], total

    def status_counts(self) -> dict[str, int]:
        """Number of studies in each state (every state listed, zeros included)."""
        q = select(StudyRow.status, func.count()).group_by(StudyRow.status)
        with self._tx() as s:
            found = {str(k): int(n) for k, n in s.execute(q).all()}
        return {st: found.get(st, 0) for st in STATUSES}

    def ids_with_status(self, statuses: Sequence[str]) -> list[str]:
        """Ids of studies in the given states, in submission order."""
        q = select(StudyRow.id).where(StudyRow.status.in_(statuses)).order_by(StudyRow.seq)
        with self._tx() as s:
            return list(s.scalars(q).all())

    def queue_positions(self) -> dict[str, int]:
        """1-based position of every queued study in the queue (submission order)."""
        q = select(StudyRow.id).where(StudyRow.status == "queued").order_by(StudyRow.seq)
        with self._tx() as s:
            return {sid: i + 1 for i, sid in enumerate(s.scalars(q).all())}

    def update_study(self, study_id: str, **fields: Any) -> None:
        """Set fields of a study (``failures`` may be given as a list)."""
        if "failures" in fields and not isinstance(fields["failures"], str):
            fields["failures"] = json.dumps(fields["failures"])
        with self._tx() as s:
            s.execute(update(StudyRow).where(StudyRow.id == study_id).values(**fields))

    def set_status_if(
        self, study_id: str, allowed: Sequence[str], status: str, **fields: Any
    ) -> bool:
        """Atomically move a study to ``status`` if it is in one of ``allowed``."""
        with self._tx() as s:
            res = s.execute(
                update(StudyRow)
                .where(StudyRow.id == study_id, StudyRow.status.in_(allowed))
                .values(status=status, **fields)
            )
            return bool(res.rowcount)

    def delete_study(self, study_id: str) -> None:
        """Remove a study's record, its files' records and its links to stored points (the
        points stay for other studies; ``impactcell gc`` removes those no study uses)."""
        with self._tx() as s:
            s.execute(delete(StudyPointRow).where(StudyPointRow.study_id == study_id))
            s.execute(delete(ResultFileRow).where(ResultFileRow.study_id == study_id))
            s.execute(delete(StudyRow).where(StudyRow.id == study_id))

    def add_result_file(self, study_id: str, path: str, size_bytes: int) -> None:
        """Record a results file of a study (replacing an earlier record of the same path)."""
        with self._tx() as s:
            s.execute(
                delete(ResultFileRow).where(
                    ResultFileRow.study_id == study_id, ResultFileRow.path == path
                )
            )
            s.add(
                ResultFileRow(
                    study_id=study_id, path=path, size_bytes=size_bytes, created_at=utcnow()
                )
            )

    def result_files(self, study_id: str) -> list[dict[str, Any]]:
        """Results files recorded for a study."""
        q = select(ResultFileRow).where(ResultFileRow.study_id == study_id)
        with self._tx() as s:
            return [
                {"path": r.path, "size_bytes": r.size_bytes, "created_at": _iso(r.created_at)}
                for r in s.scalars(q).all()
            ]

    # ------------------------------------------------------------------ regressions

    def add_regression(self, trigger: str) -> int:
        """Open a regression run; returns its id."""
        with self._tx() as s:
            row = RegressionRow(started_at=utcnow(), trigger=trigger, ok=None)
            s.add(row)
            s.flush()
            return int(row.id)

    def finish_regression(
        self,
        reg_id: int,
        *,
        ok: bool | None,
        summary: str,
        report: dict[str, Any] | None = None,
        markdown: str = "",
        error: str | None = None,
    ) -> None:
        """Store the outcome of a regression run."""
        with self._tx() as s:
            s.execute(
                update(RegressionRow)
                .where(RegressionRow.id == reg_id)
                .values(
                    finished_at=utcnow(), ok=ok, summary=summary,
                    report_json=json.dumps(report or {}, allow_nan=False, default=str),
                    report_md=markdown, error=error,
                )
            )  # fmt: skip

    def list_regressions(self, limit: int = 50, offset: int = 0) -> tuple[list[dict], int]:
        """Regression runs, newest first, and the total."""
        q = select(RegressionRow).order_by(RegressionRow.id.desc()).limit(limit).offset(offset)
        with self._tx() as s:
            rows = s.scalars(q).all()
            total = int(s.scalar(select(func.count()).select_from(RegressionRow)) or 0)
            return [_regression_dict(r, full=False) for r in rows], total

    def get_regression(self, reg_id: int) -> dict[str, Any] | None:
        """One regression run with its JSON and markdown report."""
        with self._tx() as s:
            row = s.get(RegressionRow, reg_id)
            return None if row is None else _regression_dict(row, full=True)

    def latest_regression(self) -> dict[str, Any] | None:
        """The newest finished regression run (summary only)."""
        q = (
            select(RegressionRow)
            .where(RegressionRow.finished_at.is_not(None))
            .order_by(RegressionRow.id.desc())
            .limit(1)
        )
        with self._tx() as s:
            row = s.scalars(q).first()
            return None if row is None else _regression_dict(row, full=False)

    # ------------------------------------------------------------------ leases

    def acquire_lease(self, name: str, holder: str, ttl_s: float) -> bool:
        """Take the named lease for ``ttl_s`` seconds if it is free or expired (or ours).

        Used so that, with several service processes on one catalogue, a scheduled job runs once:
        whoever inserts or takes over the row first wins; the others see it held.
        """
        now = utcnow()
        expires = now + dt.timedelta(seconds=ttl_s)
        try:
            with self._tx() as s:
                row = s.get(LeaseRow, name, with_for_update=True)
                if row is None:
                    s.add(LeaseRow(name=name, holder=holder, expires_at=expires))
                    return True
                held_until = _aware(row.expires_at)
                if row.holder != holder and held_until is not None and held_until > now:
                    return False
                # Compare-and-set on the values we read, so two takers of an expired lease
                # cannot both win (SQLite has no row locks).
                res = s.execute(
                    update(LeaseRow)
                    .where(
                        LeaseRow.name == name,
                        LeaseRow.holder == row.holder,
                        LeaseRow.expires_at == row.expires_at,
                    )
                    .values(holder=holder, expires_at=expires)
                )
                return bool(res.rowcount)
        except IntegrityError:  # a concurrent insert of the same lease won
            return False

    def acquire_fenced(
        self, name: str, holder: str, ttl_s: float, *, take_from: str | None = None
    ) -> int | None:
        """Take the named lease like :meth:`acquire_lease`; its new generation (the fencing
        token), or None when another holder's lease is alive.

        Every acquisition that is not the live holder renewing gets a new generation, also a
        holder taking back its own expired lease: writes checked against an older token
        (:meth:`fence_ok`) fail from then on. ``take_from``: a holder known to be gone, whose
        lease is taken even though it has not expired."""
        now = utcnow()
        expires = now + dt.timedelta(seconds=ttl_s)
        try:
            with self._tx() as s:
                row = s.get(LeaseRow, name, with_for_update=True)
                if row is None:
                    s.add(LeaseRow(name=name, holder=holder, expires_at=expires, generation=1))
                    return 1
                held_until = _aware(row.expires_at)
                alive = held_until is not None and held_until > now
                if alive and take_from is not None and row.holder == take_from:
                    alive = False
                if alive and row.holder != holder:
                    return None
                gen = int(row.generation or 0) + (0 if alive else 1)
                res = s.execute(  # compare-and-set, as in acquire_lease
                    update(LeaseRow)
                    .where(LeaseRow.name == name, LeaseRow.holder == row.holder,
                           LeaseRow.generation == row.generation,
                           LeaseRow.expires_at == row.expires_at)
                    .values(holder=holder, expires_at=expires, generation=gen)
                )  # fmt: skip
                return gen if res.rowcount else None
        except IntegrityError:  # a concurrent insert of the same lease won
            return None

    def renew_fenced(self, name: str, holder: str, token: int, ttl_s: float) -> bool:
        """Extend the lease held with ``token`` (even if it has just expired: nobody took it
        meanwhile, or its generation would differ); false when the token is stale."""
        expires = utcnow() + dt.timedelta(seconds=ttl_s)
        with self._tx() as s:
            res = s.execute(
                update(LeaseRow)
                .where(LeaseRow.name == name, LeaseRow.holder == holder,
                       LeaseRow.generation == token)
                .values(expires_at=expires)
            )  # fmt: skip
            return bool(res.rowcount)

    def release_fenced(self, name: str, holder: str, token: int) -> None:
        """Give a fenced lease back: it expires now and its generation moves on (so ``token``
        is stale from now on); the row stays, so the next holder's token is newer than every
        earlier one."""
        with self._tx() as s:
            s.execute(
                update(LeaseRow)
                .where(LeaseRow.name == name, LeaseRow.holder == holder,
                       LeaseRow.generation == token)
                .values(expires_at=utcnow(), generation=token + 1)
            )  # fmt: skip

    def fence_ok(self, name: str, holder: str, token: int) -> bool:
        """Whether ``holder`` still holds the lease with generation ``token``."""
        with self.engine.begin() as conn:
            return fence_ok(conn, name, holder, token)

    def update_fenced(
        self, study_id: str, fence: tuple[str, str, int], allowed: Sequence[str] | None = None,
        **fields: Any,
    ) -> bool:  # fmt: skip
        """Set fields of a study if ``fence`` (lease name, holder, token) is current and, with
        ``allowed``, its status is one of them: checked in the same transaction, the lease row
        locked (PostgreSQL), so no takeover commits in between. Whether it was written."""
        if "failures" in fields and not isinstance(fields["failures"], str):
            fields["failures"] = json.dumps(fields["failures"])
        with self._tx() as s:
            if not fence_ok(s, *fence):
                return False
            q = update(StudyRow).where(StudyRow.id == study_id)
            if allowed is not None:
                q = q.where(StudyRow.status.in_(allowed))
            return bool(s.execute(q.values(**fields)).rowcount)

    def lease_free(self, name: str) -> bool:
        """Whether nobody holds the named lease (never taken, given back, or expired)."""
        with self._tx() as s:
            row = s.get(LeaseRow, name)
            if row is None:
                return True
            held_until = _aware(row.expires_at)
            return held_until is None or held_until <= utcnow()

    def release_lease(self, name: str, holder: str) -> None:
        """Give the lease back if we hold it."""
        with self._tx() as s:
            s.execute(delete(LeaseRow).where(LeaseRow.name == name, LeaseRow.holder == holder))

    # ------------------------------------------------------------------ regression runs' state

    def unfinished_regressions(self) -> list[dict[str, Any]]:
        """Regression runs without an outcome yet (``finished_at`` unset), oldest first."""
        q = select(RegressionRow).where(RegressionRow.finished_at.is_(None))
        with self._tx() as s:
            rows = s.scalars(q.order_by(RegressionRow.id)).all()
            return [_regression_dict(r, full=False) for r in rows]

    def lease(self, name: str) -> dict[str, Any] | None:
        """The named lease's ``holder`` and ``expires_at`` (aware UTC datetime), or None."""
        with self._tx() as s:
            row = s.get(LeaseRow, name)
            if row is None:
                return None
            return {"holder": row.holder, "expires_at": _aware(row.expires_at)}

    def interrupt_regression(self, reg_id: int, *, summary: str, error: str, markdown: str) -> bool:
        """End a run that has no outcome as not ok (``ok`` false, ``finished_at`` now).

        Only while it is still unfinished, so a run that ends meanwhile keeps its own outcome;
        returns whether this call ended it.
        """
        with self._tx() as s:
            res = s.execute(
                update(RegressionRow)
                .where(RegressionRow.id == reg_id, RegressionRow.finished_at.is_(None))
                .values(finished_at=utcnow(), ok=False, summary=summary, error=error,
                        report_md=markdown)
            )  # fmt: skip
            return bool(res.rowcount)

    def add_finished_regression(
        self,
        trigger: str,
        *,
        started_at: dt.datetime,
        ok: bool,
        summary: str,
        report: dict[str, Any],
        markdown: str = "",
    ) -> int:
        """Store a regression run that ran elsewhere and has ended (a client's); returns its id."""
        with self._tx() as s:
            row = RegressionRow(
                started_at=started_at, finished_at=utcnow(), trigger=trigger, ok=ok,
                summary=summary, report_json=json.dumps(report, allow_nan=False, default=str),
                report_md=markdown,
            )  # fmt: skip
            s.add(row)
            s.flush()
            return int(row.id)


def fence_ok(conn: Any, name: str, holder: str, token: int) -> bool:
    """Whether ``holder`` holds lease ``name`` with generation ``token``, read on ``conn`` (a
    connection or session in the caller's transaction) with the row locked where the database
    can (``FOR UPDATE``), so that the caller's writes commit before any takeover does."""
    row = conn.execute(
        select(LeaseRow.holder, LeaseRow.generation).where(LeaseRow.name == name).with_for_update()
    ).first()
    return row is not None and row[0] == holder and int(row[1] or 0) == token


WAL_TRIES = 40  # switching to WAL: tries 20 ms, 40 ms, ... apart (~16 s in all)


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    # WAL lets readers (API requests) run while the runner thread writes progress.
    cur = dbapi_conn.cursor()
    for attempt in range(WAL_TRIES):
        try:
            cur.execute("PRAGMA journal_mode=WAL")
            break
        except sqlite3.OperationalError as exc:
            # Switching a new file to WAL needs an exclusive lock, and SQLite refuses a second
            # connection switching at the same moment at once ("database is locked"), without
            # its busy wait: processes that open a new catalogue together try again.
            if "locked" not in str(exc) or attempt == WAL_TRIES - 1:
                raise
            time.sleep(0.02 * (attempt + 1))
    # In WAL mode NORMAL syncs at checkpoints, not at every commit: a killed process loses
    # nothing committed (only a power cut may lose the last commits); the point store commits
    # once per finished chunk, and a sync each time was most of its cost.
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.close()
