"""The point store in the catalogue database: every computed point once, queries across studies.

One row per point (``points``), keyed by its content hash (``service.studies.points``), with
its cell's parameters as columns (the common questions indexed) and the worker's record as JSON;
solver settings once per distinct set (``solvers``); which study uses which point at which index
(``study_points``). Points are written in one transaction per finished chunk, so a killed run
loses at most its chunks in flight. A point stays until ``gc`` finds no study that uses it;
deleting a study only drops its links. Points of an older solver version stay queryable by
version; new studies never see them (the version is part of the key).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import and_, delete, exists, func, select
from sqlalchemy.engine import Engine

from service.api.catalogue import (
    PointRow,
    SolverRow,
    StudyPointRow,
    StudyRow,
    fence_ok,
    utcnow,
)
from service.studies.chunks import CHUNK_FIELDS, record_columns, with_transient_flag
from service.studies.fence import FenceLost
from service.studies.points import KEY_LENGTH, PARAM_COLUMNS, cell_of, solver_key
from service.studies.variables import AXES, STOP_VARIABLES, result_values, stop_coordinate
from worker.simulate import SOLVER_VERSION

__all__ = [
    "FLOAT_PARAMS",
    "MAX_PAGE",
    "PointQuery",
    "SqlPointStore",
    "points_csv",
    "points_dataset",
]

#: Parameters a query may give as a value or a range (``gap`` means g1 = g2 = gap).
FLOAT_PARAMS = ("theta", "sigma", "gamma_s", "gamma_r", "xi", "xi_b", "g1", "g2", "gap")
#: Rows per page at most.
MAX_PAGE = 100_000
# A value matches a stored float within this relative tolerance (grid values are computed:
# 0.1 + 0.2 is not 0.3).
MATCH_RTOL = 1e-9
_BATCH = 500  # keys per IN (...) list: well under every database's parameter limit


@dataclass
class PointQuery:
    """What ``GET /points`` (and ``impactcell points``) asks for.

    ``values``: parameter → value (matched within ``MATCH_RTOL``); ``ranges``: parameter →
    (min or None, max or None), both ends included. ``cells``: chains of N cells only (1: the
    unit cell); None: every point. ``version``: a solver version, or ``"all"``.
    ``after``: the last key of the previous page (pages are in key order).
    """

    values: dict[str, float] = field(default_factory=dict)
    ranges: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)
    modes: int | None = None
    coupling: str | None = None
    method: str | None = None
    outcome: str | None = None
    cells: int | None = None
    version: str = SOLVER_VERSION
    study: str | None = None
    after: str | None = None
    limit: int = 1000


def _columns(name: str) -> list[Any]:
    return [PointRow.g1, PointRow.g2] if name == "gap" else [getattr(PointRow, name)]


def _start(point: Mapping[str, Any], key_after: str | None) -> str:
    if key_after:
        return f"after:{key_after}"
    init = point.get("initial")
    return str(init.get("kind", "initial")) if isinstance(init, Mapping) else "rest"


class SqlPointStore:
    """The point store over a catalogue's SQLAlchemy engine (thread-safe: a connection per
    call). Implements ``service.studies.points.PointStore`` for the runner.

    ``fences`` maps a study id to its fence (lease name, holder, token): a save or link for
    that study commits only while the fence is current, else raises ``FenceLost``."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self._solvers: set[str] = set()  # solver keys known to be stored
        self.fences: dict[str, tuple[str, str, int]] = {}

    def _check_fence(self, conn: Any, study_id: str | None) -> None:
        fence = self.fences.get(study_id) if study_id is not None else None
        if fence is not None and not fence_ok(conn, *fence):
            raise FenceLost(f"study {study_id}: lease {fence[0]} is no longer ours")

    # ------------------------------------------------------------------ the runner's side

    def lookup(self, keys: Sequence[str]) -> dict[str, dict[str, Any]]:
        """The stored records of those ``keys`` that are known."""
        out: dict[str, dict[str, Any]] = {}
        uniq = list(dict.fromkeys(keys))
        with self.engine.connect() as conn:
            for i in range(0, len(uniq), _BATCH):
                part = uniq[i : i + _BATCH]
                rows = conn.execute(
                    select(PointRow.key, PointRow.record).where(PointRow.key.in_(part))
                )
                for k, rec in rows:
                    out[k] = json.loads(rec)
        return out

    def save(
        self,
        rows: Sequence[tuple[str, Mapping[str, Any], Mapping[str, Any]]],
        solver: Mapping[str, Any],
        link: tuple[str, Sequence[tuple[int, str]]] | None = None,
    ) -> None:
        """Store ``(key, point, record)`` rows computed with ``solver`` and, with ``link`` =
        ``(study_id, pairs)``, the study's links, in one transaction; keys already stored are
        left as they are (the same point gives the same record)."""
        if not rows:
            if link:
                self.link(*link)
            return
        skey = solver_key(solver)
        now = utcnow()
        by_key: dict[str, dict[str, Any]] = {}
        for key, point, record in rows:
            if len(key) != KEY_LENGTH:
                raise ValueError(f"a point key has {KEY_LENGTH} hex digits, got {key!r}")
            try:
                cell = cell_of(point)
            except (KeyError, TypeError, ValueError):
                continue  # not a cell (a parameter missing): nothing to index it by
            after = point.get("_after")
            by_key[key] = {
                "key": key,
                "version": SOLVER_VERSION,
                "method": str(record.get("method") or solver.get("method")),
                "solver": skey,
                "start": _start(point, after),
                **{c: cell[c] for c in PARAM_COLUMNS},
                "cells": cell.get("cells"),
                "outcome": str(record.get("outcome") or ""),
                "transmittance_db": _finite(record.get("transmittance_db")),
                "record": _record_json(record),
                "created_at": now,
            }
        with self.engine.begin() as conn:
            self._check_fence(conn, link[0] if link else None)
            if skey not in self._solvers:
                if conn.execute(select(SolverRow.key).where(SolverRow.key == skey)).first() is None:
                    conn.execute(
                        SolverRow.__table__.insert(),
                        [{"key": skey, "settings": json.dumps(dict(solver), sort_keys=True)}],
                    )
                self._solvers.add(skey)
            _insert_new(conn, PointRow.__table__, list(by_key.values()), ["key"])
            if link:
                _link(conn, *link)

    def link(self, study_id: str, pairs: Sequence[tuple[int, str]]) -> None:
        """Record that ``study_id`` uses the points ``(index, key)`` (idempotent)."""
        if not pairs:
            return
        with self.engine.begin() as conn:
            self._check_fence(conn, study_id)
            _link(conn, study_id, pairs)

    # ------------------------------------------------------------------ housekeeping

    def gc(self, data_dir: Path | None = None, *, dry_run: bool = False) -> dict[str, int]:
        """Remove points no study uses. A study counts while the catalogue lists it or (a study
        run from the command line) its folder exists under ``data_dir``/studies; links of other
        studies are dropped first. Returns the counts (what would go, with ``dry_run``)."""
        with self.engine.begin() as conn:
            linked = list(conn.execute(select(StudyPointRow.study_id).distinct()).scalars())
            listed = set(conn.execute(select(StudyRow.id)).scalars())
            on_disk = (lambda s: (data_dir / "studies" / s).is_dir()) if data_dir else None
            gone = [s for s in linked if s not in listed and not (on_disk and on_disk(s))]
            links = 0
            if gone:
                links = int(
                    conn.execute(
                        select(func.count())
                        .select_from(StudyPointRow)
                        .where(StudyPointRow.study_id.in_(gone))
                    ).scalar_one()
                )
            orphan = ~exists().where(
                and_(StudyPointRow.key == PointRow.key, StudyPointRow.study_id.not_in(gone))
                if gone
                else StudyPointRow.key == PointRow.key
            )
            points = int(
                conn.execute(select(func.count()).select_from(PointRow).where(orphan)).scalar_one()
            )
            if not dry_run:
                if gone:
                    conn.execute(delete(StudyPointRow).where(StudyPointRow.study_id.in_(gone)))
                conn.execute(delete(PointRow).where(orphan))
                used = select(PointRow.solver).distinct()
                conn.execute(delete(SolverRow).where(SolverRow.key.not_in(used)))
        return {"points": points, "links": links, "studies": len(gone)}

    def count(self, version: str | None = None) -> int:
        """Points stored (of one solver version, or all)."""
        q = select(func.count()).select_from(PointRow)
        if version is not None:
            q = q.where(PointRow.version == version)
        with self.engine.connect() as conn:
            return int(conn.execute(q).scalar_one())

    # ------------------------------------------------------------------ queries

    def query(self, q: PointQuery) -> tuple[list[dict[str, Any]], str | None]:
        """One page of points matching ``q`` (key order) and the key to ask ``after`` for the
        next page (None: this was the last)."""
        if not 1 <= q.limit <= MAX_PAGE:
            raise ValueError(f"limit must be 1..{MAX_PAGE}, got {q.limit}")
        stmt = select(*PointRow.__table__.c, SolverRow.settings).join(
            SolverRow, SolverRow.key == PointRow.solver
        )
        conds: list[Any] = []
        for name, v in q.values.items():
            if name not in FLOAT_PARAMS:
                raise ValueError(f"unknown parameter {name!r}; allowed: {', '.join(FLOAT_PARAMS)}")
            tol = MATCH_RTOL * max(1.0, abs(v))
            conds += [c.between(v - tol, v + tol) for c in _columns(name)]
        for name, (lo, hi) in q.ranges.items():
            if name not in FLOAT_PARAMS:
                raise ValueError(f"unknown parameter {name!r}; allowed: {', '.join(FLOAT_PARAMS)}")
            for c in _columns(name):
                if lo is not None:
                    conds.append(c >= lo - MATCH_RTOL * max(1.0, abs(lo)))
                if hi is not None:
                    conds.append(c <= hi + MATCH_RTOL * max(1.0, abs(hi)))
        if "gap" in q.values or "gap" in q.ranges:
            conds.append(PointRow.g1 == PointRow.g2)
        for col, v in (
            (PointRow.modes, q.modes),
            (PointRow.coupling, q.coupling),
            (PointRow.method, q.method),
            (PointRow.outcome, q.outcome),
        ):
            if v is not None:
                conds.append(col == v)
        if q.cells is not None:
            conds.append(PointRow.cells.is_(None) if q.cells == 1 else PointRow.cells == q.cells)
        if q.version != "all":
            conds.append(PointRow.version == q.version)
        if q.study is not None:
            conds.append(
                PointRow.key.in_(select(StudyPointRow.key).where(StudyPointRow.study_id == q.study))
            )
        if q.after is not None:
            conds.append(PointRow.key > q.after)
        stmt = stmt.where(*conds).order_by(PointRow.key).limit(q.limit + 1)
        with self.engine.connect() as conn:
            rows = conn.execute(stmt).all()
        more = len(rows) > q.limit
        rows = rows[: q.limit]
        out = [_row_dict(r._mapping) for r in rows]
        return out, (out[-1]["key"] if more and out else None)

    def iter_query(self, q: PointQuery) -> Iterator[dict[str, Any]]:
        """Every point matching ``q``, page by page."""
        after = q.after
        while True:
            page, nxt = self.query(PointQuery(**{**q.__dict__, "after": after}))
            yield from page
            if nxt is None:
                return
            after = nxt


def _insert_new(
    conn: Any,
    table: Any,
    rows: Sequence[Mapping[str, Any]],
    conflict: list[str],
    update: list[str] | None = None,
) -> None:
    """Insert ``rows``; a row whose ``conflict`` columns exist already is left as it is (or,
    with ``update``, has those columns replaced). One statement per batch on SQLite and
    PostgreSQL (``ON CONFLICT``), a look-up first elsewhere."""
    if not rows:
        return
    name = conn.dialect.name
    if name in ("sqlite", "postgresql"):
        if name == "sqlite":
            from sqlalchemy.dialects.sqlite import insert
        else:
            from sqlalchemy.dialects.postgresql import insert
        stmt = insert(table)
        if update:
            stmt = stmt.on_conflict_do_update(
                index_elements=conflict, set_={c: stmt.excluded[c] for c in update}
            )
        else:
            stmt = stmt.on_conflict_do_nothing(index_elements=conflict)
        for i in range(0, len(rows), _BATCH):
            conn.execute(stmt, list(rows[i : i + _BATCH]))
        return
    cols = [table.c[c] for c in conflict]
    for i in range(0, len(rows), _BATCH):
        part = rows[i : i + _BATCH]
        if len(cols) == 1:
            have = set(
                conn.execute(
                    select(cols[0]).where(cols[0].in_([r[conflict[0]] for r in part]))
                ).scalars()
            )
            new = [r for r in part if r[conflict[0]] not in have]
        else:  # (study_id, idx) of one study: replace
            for r in part:
                conn.execute(delete(table).where(*(c == r[c.name] for c in cols)))
            new = list(part)
        if new:
            conn.execute(table.insert(), new)


def _link(conn: Any, study_id: str, pairs: Sequence[tuple[int, str]]) -> None:
    rows = [{"study_id": study_id, "idx": int(a), "key": k} for a, k in pairs]
    _insert_new(conn, StudyPointRow.__table__, rows, ["study_id", "idx"], update=["key"])


def _record_json(record: Mapping[str, Any]) -> str:
    """A record as JSON text; the worker's records are plain JSON values, so the slower
    :func:`_clean` is needed only for one that is not."""
    try:
        return json.dumps(record, allow_nan=False)
    except (TypeError, ValueError):
        return json.dumps(_clean(record), allow_nan=False)


def _row_dict(m: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {c: m[c] for c in (*_ID_COLUMNS, *PARAM_COLUMNS)}
    out["cells"] = m["cells"] or 1  # a chain's N; 1: the unit cell
    for e in ("e1", "e2"):
        if out[e] is None:  # stored before restitution: a plastic impact
            out[e] = 0.0
    for k, v in with_transient_flag(json.loads(m["record"])).items():
        if k not in out:
            out[k] = v
    out["solver"] = json.loads(m["settings"])
    return out


def _finite(v: Any) -> float | None:
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _clean(v: Any) -> Any:
    """A record as plain JSON values: numpy values as Python ones, a non-finite float as None
    (the JSON the API serves never holds NaN)."""
    if isinstance(v, Mapping):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if hasattr(v, "tolist"):
        return _clean(v.tolist())
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


# --------------------------------------------------------------------------- exports

_ID_COLUMNS = ("key", "version", "method", "start")


def points_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    """Points as CSV: identity, parameters, then every result variable (impacts per stop as
    two columns); missing values empty."""
    import csv
    import io

    head = [*_ID_COLUMNS, *PARAM_COLUMNS, "cells"]
    fields = [f for f in CHUNK_FIELDS if f not in STOP_VARIABLES]
    # a per-stop variable as two columns (impacts_per_period: impacts_stop1, impacts_stop2)
    stops = [(v, "impacts" if v == "impacts_per_period" else v) for v in STOP_VARIABLES]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*head, *fields, *(f"{c}_stop{k}" for _, c in stops for k in (1, 2))])
    for r in rows:
        per = [v for name, _ in stops for v in (r.get(name) or [None, None])]
        w.writerow([_cell(r.get(c)) for c in (*head, *fields)] + [_cell(v) for v in per])
    return buf.getvalue()


def _cell(v: Any) -> Any:
    return "" if v is None else v


def points_dataset(rows: Sequence[Mapping[str, Any]]) -> Any:
    """Points as an xarray Dataset along ``point``: identity and parameters as coordinates,
    results as variables with their CF attributes (``outcome`` a flag variable)."""
    import numpy as np
    import xarray as xr

    cols = record_columns(rows)
    data_vars: dict[str, Any] = {}
    failed = np.asarray(cols["failed"], dtype=bool) if "failed" in cols else None
    for name, arr in cols.items():
        a, attrs = result_values(name, arr, failed)
        dims: tuple[str, ...] = ("point", "stop") if name in STOP_VARIABLES else ("point",)
        data_vars[name] = (dims, a, attrs)
    coords: dict[str, Any] = {
        c: ("point", np.array([str(r.get(c, "")) for r in rows], dtype=object)) for c in _ID_COLUMNS
    }
    for c in PARAM_COLUMNS:
        vals = [r.get(c) for r in rows]
        if c in ("coupling",):
            coords[c] = ("point", np.array([str(v) for v in vals], dtype=object))
        elif c == "modes":
            coords[c] = ("point", np.array(vals, dtype=np.int64))
        else:
            arr = np.array([np.nan if v is None else float(v) for v in vals], dtype=np.float64)
            info = AXES.get(c)
            attrs = {"units": info.units, "long_name": info.long_name} if info else {}
            coords[c] = ("point", arr, attrs)
    info = AXES["cells"]
    coords["cells"] = ("point", np.array([int(r.get("cells") or 1) for r in rows], dtype=np.int64),
                       {"units": info.units, "long_name": info.long_name})  # fmt: skip
    coords["stop"] = stop_coordinate()
    return xr.Dataset(
        data_vars,
        coords=coords,
        attrs={
            "Conventions": "CF-1.8",
            "title": "impactcell points (a query of the point store)",
            "points": len(rows),
        },
    )
