"""Point identity and the point store's interface (docs/points.md).

A point's result is determined by its cell (``CellParams``: every field, defaults filled in),
the solver settings (``SolverSettings``: every field, defaults filled in; they all change the
numbers), its start and the solver version (``SOLVER_VERSION``; on a CPU that does not run the
pinned targets, with that CPU's target appended, :func:`key_version`, since its last bits
differ: such points are never reused as the pinned machines' or theirs as its). Its key is a
content hash of exactly these, so a study's name, description, output switches, chunking or
place in a grid do not change it, and two studies that ask for the same point ask for the same
key.

The start is ``"rest"``, the point's ``initial`` entry (kind, seed, index: the worker's), or,
inside a sweep line, the key of the point before it (``{"after": key}``): a sweep point is the
same point only if its whole line up to it is the same.

Which records are kept: every record except those whose numbers depend on the run rather than
the point (a failure by the point's wall-time or step budget, a task that failed on the cluster):
those are recomputed when asked for again.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, Protocol

from service.studies.schema import Study
from worker.cpu import on_pinned_target, target_label
from worker.model import CellParams
from worker.simulate import CHAIN_POINT_KEYS, POINT_KEYS, SOLVER_VERSION, SolverSettings
from worker.solvers.settings import OVER_STEPS, OVER_TIME

__all__ = [
    "KEY_LENGTH",
    "key_version",
    "PARAM_COLUMNS",
    "TASK_FAILED",
    "PointStore",
    "cell_of",
    "digest",
    "is_storable",
    "point_key",
    "save_chunk",
    "solver_document",
    "solver_key",
    "study_keys",
]

#: Hex digits of a point key (128 bits of SHA-256: no collision among any number of points a
#: database can hold, at half the index size of the full digest).
KEY_LENGTH = 32
#: The cell's parameters as stored (and queried) per point, in ``CellParams`` order.
PARAM_COLUMNS = tuple(f.name for f in dataclasses.fields(CellParams))
#: How the reason of a point whose task failed on the cluster begins (the runner's).
TASK_FAILED = "task failed after "
# Failures that depend on the run, not the point: never stored (recomputed when asked again).
_RUN_DEPENDENT = (OVER_TIME, OVER_STEPS, TASK_FAILED)


_DEFAULTS = {
    f.name: f.default
    for f in dataclasses.fields(CellParams)
    if f.default is not dataclasses.MISSING
}
_TYPES = {"modes": int, "coupling": str}


def cell_of(point: Mapping[str, Any]) -> dict[str, Any]:
    """The full parameter set of a point dict: every ``CellParams`` field, defaults filled in,
    floats as floats (a study's points are already checked cells; this only normalises them,
    some fifty times faster than building ``CellParams``). Raises ``KeyError`` for a point
    without a required parameter."""
    out = dict(_DEFAULTS)
    for k in POINT_KEYS:
        if k in point:
            out[k] = point[k]
    for k in PARAM_COLUMNS:
        v = out[k]  # KeyError: a required parameter is missing
        if v is not None:
            out[k] = _TYPES.get(k, float)(v)
    if "cells" in point:  # a chain (N > 1): its length and graded lists are part of its key
        out["cells"] = int(point["cells"])
        for k in CHAIN_POINT_KEYS[1:]:
            if point.get(k) is not None:
                out[k] = [float(v) for v in point[k]]
    return out


#: Cell parameters added after the store's first points, left out of a key while they are at
#: their default (plastic impacts), so that every key stored before stays the same point's.
_LATER_PARAMS = ("e1", "e2")
#: Solver settings added after the store's first points, left out of a document while they
#: are at their default, so that every key stored before stays the key of the same settings.
_LATER_SETTINGS = ("max_events_per_period", "transient_guard")
_SOLVER_DEFAULTS = {f.name: f.default for f in dataclasses.fields(SolverSettings)}


def solver_document(solver: Mapping[str, Any]) -> dict[str, Any]:
    """Every solver setting of ``solver`` (defaults filled), as hashed and stored."""
    doc = dataclasses.asdict(SolverSettings(**solver))
    for name in _LATER_SETTINGS:
        if doc[name] == _SOLVER_DEFAULTS[name]:
            del doc[name]
    return doc


def _dumps(doc: Any) -> str:
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)


def digest(text: str) -> str:
    """The key of a canonical JSON text (points, solver settings): 128 bits of SHA-256."""
    return hashlib.sha256(text.encode()).hexdigest()[:KEY_LENGTH]


def solver_key(solver: Mapping[str, Any]) -> str:
    """The key of a :func:`solver_document` (the point store keeps each set once)."""
    return digest(_dumps(dict(solver)))


@functools.cache
def _off_pin() -> str:
    """``""`` on the pinned CPU targets, else ``@<target>`` (asked once per process)."""
    return "" if on_pinned_target() else f"@{target_label()}"


def key_version() -> str:
    """The solver version a point's key hashes: ``SOLVER_VERSION`` where this process (and so
    every worker it lets compute, ``worker.cpu.check_target``) runs the pinned CPU targets,
    else ``SOLVER_VERSION@<target>`` (``worker.cpu.target_label``)."""
    return SOLVER_VERSION + _off_pin()


def point_key(
    point: Mapping[str, Any],
    solver: Mapping[str, Any],
    after: str | None = None,
    *,
    version: str | None = None,
) -> str:
    """The key of one point: its cell, ``solver`` (a :func:`solver_document`), its start
    (``after``: the previous point's key in a sweep line, else the point's ``initial`` or rest)
    and the solver ``version`` (default: this impactcell's).

    A point whose parameters are not a valid cell (its record is a failure) is keyed by its
    parameters as given.
    """
    return _key(point, _dumps(solver), after, key_version() if version is None else version)


def _key(point: Mapping[str, Any], solver_json: str, after: str | None, version: str) -> str:
    """:func:`point_key` with the solver's JSON text made once (a study's points share it).
    The hashed text is the sorted, compact JSON of ``{cell, solver, start, version}``."""
    try:
        cell: Any = cell_of(point)
        for k in _LATER_PARAMS:  # at its default: the key every point had before it
            if cell[k] == _DEFAULTS[k]:
                del cell[k]
    except (KeyError, TypeError, ValueError):
        cell = {k: point[k] for k in sorted(point) if k != "initial"}  # not a cell: as given
    start: Any = {"after": after} if after is not None else (point.get("initial") or "rest")
    text = (
        f'{{"cell":{_dumps(cell)},"solver":{solver_json},"start":{_dumps(start)},'
        f'"version":{_dumps(version)}}}'
    )
    return digest(text)


def _iter_keys(study: Study, start: int, stop: int, solver: Mapping[str, Any]) -> Iterator[str]:
    solver_json = _dumps(solver)
    lines = study.sweep is not None
    length = study.line_length if lines else 0
    if lines and start % length:
        raise ValueError(f"sweep keys start at a line's first point, not at {start}")
    prev: str | None = None
    for i, p in enumerate(study.points(start, stop)):
        if lines and (start + i) % length == 0:
            prev = None
        key = _key(p, solver_json, prev if lines else None, key_version())
        prev = key
        yield key


def study_keys(
    study: Study,
    start: int = 0,
    stop: int | None = None,
    *,
    solver: Mapping[str, Any] | None = None,
) -> list[str]:
    """Keys of a study's points ``start:stop`` in work order (a sweep's: whole lines);
    ``solver``: the study's :func:`solver_document`, if the caller has it."""
    doc = solver_document(study.solver.settings().__dict__) if solver is None else solver
    return list(_iter_keys(study, start, study.size if stop is None else stop, doc))


def is_storable(record: Mapping[str, Any]) -> bool:
    """Whether a record is the point's own result (not a failure of this run's budget)."""
    reason = str(record.get("reason") or "")
    return not (record.get("failed") and reason.startswith(_RUN_DEPENDENT))


class PointStore(Protocol):
    """What the runner needs of a point store (``service.api.points.SqlPointStore``)."""

    def lookup(self, keys: Sequence[str]) -> dict[str, dict[str, Any]]:
        """The stored records of those ``keys`` that are known (key → record)."""
        ...

    def save(
        self,
        rows: Sequence[tuple[str, Mapping[str, Any], Mapping[str, Any]]],
        solver: Mapping[str, Any],
        link: tuple[str, Sequence[tuple[int, str]]] | None = None,
    ) -> None:
        """Store ``(key, point, record)`` rows computed with ``solver`` (known keys are left
        as they are) and, given ``link = (study_id, pairs)``, the study's links to its points,
        in one transaction."""
        ...

    def link(self, study_id: str, pairs: Sequence[tuple[int, str]]) -> None:
        """Record that study ``study_id`` uses the points ``(index, key)`` (idempotent)."""
        ...


def save_chunk(
    store: PointStore,
    study_id: str,
    solver: Mapping[str, Any],
    start: int,
    keys: Sequence[str],
    points: Sequence[dict[str, Any]],
    records: Sequence[Mapping[str, Any]],
) -> None:
    """Store a finished chunk (points ``start…``): the records that are their points' own
    result, and the study's links to every one, in one transaction. A point dict may carry
    ``"_after"``: the key of the sweep point it started from (its stored start)."""
    store.save(
        [(k, p, r) for k, p, r in zip(keys, points, records, strict=True) if is_storable(r)],
        solver,
        link=(study_id, list(enumerate(keys, start=start))),
    )
