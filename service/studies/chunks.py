"""The results store: every file path of a study, its chunk files, atomic writes.

Layout under the data root (``--out``, ``--data-dir``, ``IMPACTCELL_DATA_DIR`` or ``./data``,
resolved by the caller's :class:`~service.api.settings.Settings`)::

    studies/<id>/study.json            canonical definition (written once)
    studies/<id>/chunks/<start>-<stop>.npz   one finished chunk of points
    studies/<id>/chunks/<start>-<stop>.g<token>.npz   one written by the service's runner
    studies/<id>/results.nc            the collated dataset (NetCDF4, zlib)
    studies/<id>/results.nc.sha256     its SHA-256 (``sha256sum`` format)
    studies/<id>/damaged/              files that failed their check, set aside

Chunk ranges are in the study's work order (:meth:`~service.studies.schema.Study.work_indices`:
the grid's C order unless the study has a sweep, whose chunks are whole lines).

Ids are content hashes (:attr:`service.studies.schema.Study.id`), never user-chosen names. Every
file is written to a temporary name in the same folder, flushed, and renamed into place, so a
crash (even SIGKILL) never leaves a file that looks complete but is not.

Every file is checked when it is read. A chunk file holds the SHA-256 of its arrays
(``_sha256``); one that cannot be read, fails that digest, or does not hold the range its name
says is moved to ``damaged/`` (kept for inspection, logged) and its points count as missing, so
the next run computes them again (or takes them from the point store). The results file's
SHA-256 is kept beside it; one that fails it is moved to ``damaged/`` too and the study is run
again to rebuild it (:meth:`StudyStore.results_status`).

A store given a fence (:class:`~service.studies.fence.Fence`: the service's lease generation of
the study) names its chunk files with the token and checks the token just before each rename,
so a process that lost the study to another cannot publish a chunk. Should a stale process pass
that check and publish a chunk afterwards, its file has an older token than the chunks of the
process that took over: where chunk files overlap, the one with the newest token counts and the
others are removed (:meth:`StudyStore.chunks`); the new holder computes every point it did not
find at its start, so nothing the older file held is lost.
"""

from __future__ import annotations

import bisect
import hashlib
import json
import logging
import os
import re
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from service.studies.dataset import FILL_INT, PENDING, encoding, open_results, write_netcdf
from service.studies.fence import Fence
from service.studies.schema import Study
from service.studies.variables import (
    CHAIN_VARIABLES,
    OUTCOMES,
    STOP_VARIABLES,
    SWEEP_VARIABLES,
    VARIABLES,
    outcome_codes,
)
from worker.simulate import SOLVER_VERSION
from worker.solvers.settings import TRANSIENT_NOTE

__all__ = [
    "CHUNK_FIELDS",
    "DAMAGED_DIR",
    "DEFAULT_DATA_DIR",
    "RESULTS_FILE",
    "STUDY_ID",
    "MissingPoints",
    "PartialState",
    "record_columns",
    "StudyStore",
    "atomic_write",
    "chunk_digest",
    "chunk_name",
    "file_sha256",
    "data_root",
    "is_study_id",
    "iter_chunk_ranges",
    "study_folder",
    "with_transient_flag",
]

log = logging.getLogger("impactcell.store")

DEFAULT_DATA_DIR = Path("data")
#: Where a study's files that failed their check are kept (inside the study's folder).
DAMAGED_DIR = "damaged"
#: The name of a finished study's collated results file, in its folder (:func:`study_folder`).
RESULTS_FILE = "results.nc"
_RESULTS_SUM = RESULTS_FILE + ".sha256"
#: A study id: a hex content hash (the only text a study's file paths are built from).
STUDY_ID = re.compile(r"^[0-9a-f]{8,64}$")
# <start>-<stop>.npz, or <start>-<stop>.g<token>.npz (written under a fencing token)
_CHUNK = re.compile(r"^(\d+)-(\d+)(?:\.g(\d+))?\.npz$")
# Fields kept in chunk files (everything simulate_chunk reports that a dataset may hold).
CHUNK_FIELDS = tuple(VARIABLES)
# Fields kept besides in the chunk files of a sweep (simulate_line reports them).
LINE_FIELDS = ("started_from",)
# Points of the chunks a store wrote that it also keeps in memory, so that collating the run
# that wrote them does not read them back (Figure 5's 182 chunk files took ~0.7 s to read).
# 250,000 points are ~90 MB of columns; beyond, chunks are read from their files.
HOLD_POINTS = 250_000


def is_study_id(text: str) -> bool:
    """Whether ``text`` has the form of a study id (a hex digest)."""
    return bool(STUDY_ID.match(text))


def data_root(out: str | os.PathLike[str] | None = None) -> Path:
    """The data root: ``out``, else ``./data`` (callers pass ``Settings.data_dir``)."""
    return DEFAULT_DATA_DIR if out is None else Path(out)


def study_folder(root: str | os.PathLike[str] | None, study_id: str) -> Path:
    """The folder of a study's files under a data root (``results.nc`` is there once it
    finishes)."""
    return data_root(root) / "studies" / study_id


def atomic_write(
    path: Path, write: Callable[[Path], None], before_publish: Callable[[], None] | None = None
) -> None:
    """Call ``write(tmp)`` on a temporary file next to ``path``, fsync it, rename into place.

    ``before_publish`` runs just before the rename (a fencing check): if it raises, the
    temporary file is removed and nothing is published."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        if before_publish is not None:
            before_publish()
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


def chunk_name(start: int, stop: int, token: int | None = None) -> str:
    """The file name of chunk ``start:stop`` (written under fencing ``token``, if any)."""
    return f"{start}-{stop}.npz" if token is None else f"{start}-{stop}.g{token}.npz"


def _stamp(st: os.stat_result) -> tuple[int, int, int]:
    """What identifies a chunk file's content: (inode, mtime, size). Every write is the rename
    of a new file, so a rewritten chunk has a new inode even where timestamps are coarse."""
    return (st.st_ino, st.st_mtime_ns, st.st_size)


class MissingPoints(ValueError):
    """Points of a study without a stored result at collation (their chunk files were damaged
    and set aside, or removed, after the run planned its work): a run computes them again."""


def chunk_digest(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 (hex) of a chunk's arrays: each one's name, dtype, shape and bytes, by name.
    The same for the arrays written and for the arrays ``np.load`` gives back."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# Results files this process has checked: path -> the stamp it had. A file is hashed again
# only when it changed (every write renames a new file; an edit in place changes its mtime).
_VERIFIED: dict[str, tuple[int, int, int]] = {}
_VERIFIED_LOCK = threading.Lock()


def iter_chunk_ranges(ranges: Iterable[tuple[int, int]], size: int) -> list[tuple[int, int]]:
    """Split (start, stop) runs into pieces of at most ``size`` points."""
    if size < 1:
        raise ValueError(f"chunk size must be >= 1, got {size}")
    out = []
    for a, b in ranges:
        for s in range(a, b, size):
            out.append((s, min(s + size, b)))
    return out


# --------------------------------------------------------------------------- records -> arrays


def with_transient_flag(record: Mapping[str, Any]) -> Mapping[str, Any]:
    """``record`` with ``may_be_transient`` and ``impacting_periods``. A record without them
    (the point store keeps every record of a solver version, whichever code wrote it) gets them
    from what the same engine decision wrote there too: the reason's note ``TRANSIENT_NOTE`` and
    the period of the claim, ``steady_period``."""
    if "may_be_transient" in record:
        return record
    flagged = record.get("outcome") == "irregular" and TRANSIENT_NOTE in str(
        record.get("reason") or ""
    )
    periods = record.get("steady_period") if flagged else None
    return {**record, "may_be_transient": flagged, "impacting_periods": periods}


def _unit_cell(record: Mapping[str, Any], name: str) -> list[Any] | None:
    """A per-cell field of a unit cell's record (N = 1 of a chain study): its own Γ, proven
    (linear, periodic) or not given, and its Γ_lin."""
    if name == "cell_transmittance_linear_db":
        return [record.get("transmittance_linear_db")]
    if record.get("outcome") in ("linear", "periodic"):
        return [record.get("transmittance_db")]
    return None


def record_columns(
    records: Sequence[Mapping[str, Any]], fields: Sequence[str] = CHUNK_FIELDS, cells: int = 1
) -> dict[str, np.ndarray]:
    """Per-field arrays of result records (chunk files, the point store's exports); ``None``
    becomes NaN (floats) or -1 (ints), the ``outcome`` string its flag value; a record without
    ``may_be_transient`` gets it from :func:`with_transient_flag`. A chain's per-cell fields
    (``CHAIN_VARIABLES``) are ``cells`` columns wide, NaN beyond a point's own N."""
    if "may_be_transient" in fields or "impacting_periods" in fields:
        records = [with_transient_flag(r) for r in records]
    n = len(records)
    cols: dict[str, np.ndarray] = {}
    for name in fields:
        if name in CHAIN_VARIABLES:
            arr = np.full((n, cells), np.nan)
            for i, r in enumerate(records):
                v = r.get(name) if "cells" in r else _unit_cell(r, name)
                if v is not None:
                    arr[i, : len(v)] = [np.nan if x is None else float(x) for x in v[:cells]]
            cols[name] = arr
            continue
        var = VARIABLES[name] if name in VARIABLES else SWEEP_VARIABLES[name]
        if name in STOP_VARIABLES:
            arr = np.full((n, 2), np.nan)
            for i, r in enumerate(records):
                v = r.get(name)
                if v is not None:
                    arr[i] = [np.nan if x is None else x for x in v]
        elif var.kind == "float":
            arr = np.array(
                [np.nan if r.get(name) is None else float(r[name]) for r in records],
                dtype=np.float64,
            )
        elif var.kind in ("int", "maskint"):
            arr = np.array(
                [FILL_INT if r.get(name) is None else int(r[name]) for r in records],
                dtype=np.int64,
            )
        elif var.kind == "bool":
            arr = np.array([bool(r.get(name)) for r in records], dtype=bool)
        elif var.kind == "flag":
            arr = outcome_codes(r.get(name) for r in records)
        else:
            arr = np.array([str(r.get(name) or "") for r in records], dtype=np.str_)
            if arr.dtype.itemsize == 0:
                arr = arr.astype("<U1")
        cols[name] = arr
    return cols


def _no_path(exc: BaseException, path: Path) -> str:
    """An error's text with ``path`` shortened to its name (messages never show the data
    root)."""
    return str(exc).replace(str(path), path.name)


def _chunk_column(data: Mapping[str, np.ndarray], name: str, n: int) -> np.ndarray:
    """Column ``name`` of a loaded chunk of ``n`` points. Chunk files written before a float
    variable existed (``transmittance_linear_db``, ``impact_effect_db``) lack it: missing
    (NaN) there, so a study resumed across the change still collates. Without
    ``may_be_transient`` and ``impacting_periods``, they are read from the reason's note and
    ``steady_period`` (:func:`with_transient_flag`)."""
    if name in data:
        return data[name]
    if name in ("may_be_transient", "impacting_periods"):  # as with_transient_flag reads them
        flagged = (np.asarray(data["outcome"]) == OUTCOMES.index("irregular")) & np.array(
            [TRANSIENT_NOTE in str(r) for r in data["reason"]], dtype=bool
        )
        if name == "may_be_transient":
            return flagged
        return np.where(flagged, np.asarray(data["steady_period"], dtype=np.int64), FILL_INT)
    if name in STOP_VARIABLES:  # a per-stop variable added since
        return np.full((n, 2), np.nan)
    if name in VARIABLES and VARIABLES[name].kind == "float":
        return np.full(n, np.nan)
    if name in LINE_FIELDS:  # a line's task that failed: where it started from is unknown
        return np.full(n, "", dtype="<U1")
    raise KeyError(name)


# --------------------------------------------------------------------------- the store


@dataclass
class PartialState:
    """The chunks of a study read so far (:meth:`StudyStore.update_partial`).

    ``cols`` holds every point (pending ones as failed with reason ``pending``), ``filled``
    marks the points read from chunks, ``seen`` maps each chunk file read to its
    (inode, mtime_ns, size, retry) so that an unchanged file is never read twice.
    """

    cols: dict[str, np.ndarray]
    filled: np.ndarray
    seen: dict[str, tuple[int, int, int, bool]] = field(default_factory=dict)
    files_read: int = 0  # chunk files read by the last update (0: nothing new)

    @property
    def key(self) -> frozenset[tuple[str, int, int, int]]:
        """Identifies the chunk files the state holds (equal keys: the same data)."""
        return frozenset((k, *v[:3]) for k, v in self.seen.items())

    @property
    def has_retry(self) -> bool:
        """Whether a chunk read failed as a task (its points will be computed again)."""
        return any(v[3] for v in self.seen.values())


class StudyStore:
    """Files of one study under a data root."""

    def __init__(
        self, root: str | os.PathLike[str] | None, study: Study, *, fence: Fence | None = None
    ) -> None:
        self.study = study
        #: The fencing token its chunk files carry, and the check before each is published.
        self.fence = fence
        self.id = study.id
        if not is_study_id(self.id):
            raise ValueError(f"study id must be a hex digest, got {self.id!r}")
        self.folder = study_folder(root, self.id)
        self.chunk_dir = self.folder / "chunks"
        #: The fields its chunk files keep (a sweep's also say where each point started).
        self.fields = CHUNK_FIELDS + (LINE_FIELDS if study.sweep is not None else ())
        #: A chain study's longest chain: its per-cell columns' width (1: no such columns).
        self.cells = study.max_cells()
        if self.cells > 1:
            self.fields += tuple(CHAIN_VARIABLES)
        # Chunk files this store wrote: name -> (the file's stamp when written, its columns as
        # np.load gives them); used only while the file on disk is still that file.
        self._held: dict[str, tuple[tuple[int, int, int], dict[str, np.ndarray]]] = {}
        self._held_points = 0

    @property
    def results_path(self) -> Path:
        """Where the collated NetCDF file goes."""
        return self.folder / RESULTS_FILE

    @property
    def definition_path(self) -> Path:
        """Where the canonical definition goes."""
        return self.folder / "study.json"

    def prepare(self) -> None:
        """Create the folder and record the definition (refusing a hash collision)."""
        self.chunk_dir.mkdir(parents=True, exist_ok=True)
        text = self.study.canonical_json()
        if self.definition_path.exists():
            on_disk = json.loads(self.definition_path.read_text(encoding="utf-8"))
            if on_disk.get("definition") != self.study.canonical():
                # the folder under the data root: never the server's path
                raise ValueError(
                    f"study folder studies/{self.id} holds a different definition; remove it"
                )
            return
        payload = json.dumps(
            {"id": self.id, "solver_version": SOLVER_VERSION, "definition": json.loads(text)},
            indent=1,
            sort_keys=True,
        )
        atomic_write(self.definition_path, lambda p: p.write_text(payload, encoding="utf-8"))
        for stale in self.chunk_dir.glob(".*.tmp"):  # left by a crash mid-write
            stale.unlink(missing_ok=True)

    # ---------------------------------------------------------------- chunks

    def write_chunk(
        self, start: int, stop: int, records: Sequence[Mapping[str, Any]], *, retry: bool = False
    ) -> Path:
        """Write one finished chunk atomically; ``retry`` marks results to recompute on resume."""
        if len(records) != stop - start:
            raise ValueError(
                f"chunk {start}-{stop} needs {stop - start} records, got {len(records)}"
            )
        cols = record_columns(records, self.fields, self.cells)
        token = None if self.fence is None else self.fence.token
        path = self.chunk_dir / chunk_name(start, stop, token)
        data = {"_start": np.array(start), "_stop": np.array(stop), "_retry": np.array(retry),
                **cols}  # fmt: skip
        digest = np.array(chunk_digest(data))  # checked by every read (_load_chunk)

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, _sha256=digest, **data)

        atomic_write(path, write, None if self.fence is None else self.fence.check)
        self._forget(path.name)
        if self._held_points + stop - start <= HOLD_POINTS:
            self._held[path.name] = (_stamp(path.stat()), data)
            self._held_points += stop - start
        return path

    def _forget(self, name: str) -> None:
        held = self._held.pop(name, None)
        if held is not None:
            self._held_points -= int(held[1]["_stop"]) - int(held[1]["_start"])

    def chunks(self) -> list[tuple[int, int, Path]]:
        """Finished chunk files as (start, stop, path), by start.

        Where files overlap (a process that lost the study published a chunk after another
        took it over), the newest token's count and the others are removed."""
        if not self.chunk_dir.is_dir():
            return []
        found = []
        for p in self.chunk_dir.iterdir():
            m = _CHUNK.match(p.name)
            if m:
                found.append((int(m.group(3) or 0), int(m.group(1)), int(m.group(2)), p))
        found.sort(key=lambda f: (-f[0], f[1]))
        kept: list[tuple[int, int, Path]] = []
        taken: list[tuple[int, int]] = []  # ranges of kept files, by start
        for _token, start, stop, p in found:
            i = bisect.bisect_left(taken, (start, stop))
            clash = (i > 0 and taken[i - 1][1] > start) or (i < len(taken) and taken[i][0] < stop)
            if clash:  # superseded by a newer holder's chunk
                p.unlink(missing_ok=True)
                self._forget(p.name)
                continue
            taken.insert(i, (start, stop))
            kept.append((start, stop, p))
        return sorted(kept)

    def _load_chunk(self, path: Path) -> dict[str, np.ndarray] | None:
        """A chunk file's arrays, checked; ``None`` if it vanished, or if it is damaged (then
        it is set aside in ``damaged/`` and its points count as missing)."""
        held = self._held_chunk(path)
        if held is not None:
            return held
        try:
            st = path.stat()
        except FileNotFoundError:
            return None
        except OSError as exc:
            self._set_aside(path, None, f"cannot be read ({exc.strerror})")
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except FileNotFoundError:  # renamed away meanwhile (a run tidying up)
            return None
        except Exception as exc:  # noqa: BLE001 - BadZipFile, zlib.error, ValueError, EOFError…
            problem = f"cannot be read ({type(exc).__name__}: {_no_path(exc, path)})"
        else:
            problem = self._chunk_problem(path.name, data)
        if problem is not None:
            self._set_aside(path, _stamp(st), problem)
            return None
        return data

    def _chunk_problem(self, name: str, data: Mapping[str, np.ndarray]) -> str | None:
        """What is wrong with a chunk file's arrays (``None``: nothing): the digest it holds,
        the range its name says, one row per point in every column, every field there."""
        m = _CHUNK.match(name)
        assert m is not None  # only chunk names are listed
        start, stop = int(m.group(1)), int(m.group(2))
        digest = data.get("_sha256")
        body = {k: v for k, v in data.items() if k != "_sha256"}
        if digest is not None and str(digest) != chunk_digest(body):
            return "its content does not match its SHA-256"
        try:  # a chunk file written before digests has none: its shape is checked
            if (int(data["_start"]), int(data["_stop"])) != (start, stop):
                return f"it holds points {int(data['_start'])}-{int(data['_stop'])}"
            bool(data["_retry"])
        except (KeyError, TypeError, ValueError) as exc:
            return f"its header is incomplete ({type(exc).__name__}: {exc})"
        n = stop - start
        for col in self.fields:
            try:
                a = _chunk_column(data, col, n)
            except (KeyError, IndexError, ValueError):
                return f"it lacks the column {col}"
            if a.ndim == 0 or a.shape[0] != n:
                return f"its column {col} has shape {a.shape}, not {n} rows"
        return None

    def _set_aside(self, path: Path, stamp: tuple[int, int, int] | None, problem: str) -> None:
        """Move a damaged file to ``damaged/`` (kept for inspection) and log why; ``stamp``:
        move it only while it is still the file that was checked (not one written since)."""
        self._forget(path.name)
        dest = self.folder / DAMAGED_DIR / f"{path.name}.{time.time_ns()}"
        try:
            if stamp is not None and _stamp(path.stat()) != stamp:
                return  # replaced since it was read: the new file is checked when read
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, dest)
        except FileNotFoundError:
            return
        except OSError as exc:
            log.error("study %s: %s is damaged (%s) and cannot be set aside: %s",
                      self.id, path, problem, exc)  # fmt: skip
            return
        log.warning("study %s: %s is damaged: %s; set aside as %s", self.id, path.name,
                    problem, dest)  # fmt: skip

    def _held_chunk(self, path: Path) -> dict[str, np.ndarray] | None:
        """The columns of a chunk file this store wrote, if ``path`` is still that file (a
        file written since, by another run of the study, has another stamp: every write is
        the rename of a new file)."""
        held = self._held.get(path.name)
        if held is None or path.parent != self.chunk_dir:
            return None
        try:
            same = _stamp(path.stat()) == held[0]
        except OSError:
            same = False
        if not same:
            self._forget(path.name)
            return None
        return held[1]

    def done_mask(self) -> np.ndarray:
        """Boolean mask of points whose results are stored (and need no retry).

        Chunk files that hold retry-later failures are removed, and damaged ones (or ones
        outside the study) set aside in ``damaged/``, so that their points are computed again.
        """
        done = np.zeros(self.study.size, dtype=bool)
        for start, stop, path in self.chunks():
            if not 0 <= start < stop <= self.study.size:
                self._set_aside(path, None, f"the study has points 0-{self.study.size}")
                continue
            data = self._load_chunk(path)
            if data is None:  # vanished, or damaged and set aside
                continue
            if bool(data["_retry"]):
                path.unlink(missing_ok=True)
                self._forget(path.name)
                continue
            done[start:stop] = True
        return done

    def has_retry_chunks(self) -> bool:
        """Whether some stored chunk failed as a task and should be computed again (or cannot
        be read). Reads only each file's ``_retry`` flag: a whole chunk costs ~10× more, and a
        collation asks this of every chunk after reading them all."""
        for _, _, path in self.chunks():
            held = self._held_chunk(path)
            if held is not None:
                if bool(held["_retry"]):
                    return True
                continue
            try:
                with np.load(path, allow_pickle=False) as z:
                    if bool(z["_retry"]):
                        return True
            except FileNotFoundError:
                continue
            except Exception:  # noqa: BLE001 - damaged (BadZipFile, …): computed again too
                return True
        return False

    def missing_ranges(self) -> list[tuple[int, int]]:
        """Maximal runs of points with no stored result, as (start, stop)."""
        done = self.done_mask()
        edges = np.flatnonzero(np.diff(np.r_[1, done.view(np.int8), 1]))
        return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]

    def collect(self) -> dict[str, np.ndarray]:
        """Every point's stored results as flat arrays.

        Raises
        ------
        MissingPoints
            Some point has no result (its chunk was never written, or was damaged and set
            aside): a run of the study computes it.
        """
        cols, filled = self._gather()
        if not filled.all():
            n = filled.size
            raise MissingPoints(f"{int((~filled).sum())} of {n} points have no results yet")
        return cols

    def collect_partial(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Results stored so far, and the mask of points that have them.

        Points without results are filled as failed with reason ``pending``. Chunk files that
        vanish while reading (a run finishing and tidying up) are treated as not there.
        """
        state = self.update_partial(None)
        return state.cols, state.filled

    def update_partial(self, state: PartialState | None) -> PartialState:
        """``state`` brought up to date with the chunk files on disk, reading only new ones.

        A chunk file seen before is not read again; when one that was read has vanished or
        changed (a retry chunk removed for recomputation, the run tidying up), the state is
        built afresh. ``state`` is updated in place (callers hold a lock around it).
        """
        listing = {path.name: (start, stop, path) for start, stop, path in self.chunks()}
        stamps: dict[str, tuple[int, int, int]] = {}
        for name, (_, _, path) in listing.items():
            try:
                st = path.stat()
            except OSError:
                continue
            stamps[name] = _stamp(st)
        if state is None or any(stamps.get(k) != v[:3] for k, v in state.seen.items()):
            state = self._empty_partial()
        state.files_read = 0
        n = state.filled.size  # not study.size: that expands the grid on every call
        for name, stamp in stamps.items():
            if name in state.seen:
                continue
            start, stop, path = listing[name]
            data = self._load_chunk(path) if 0 <= start < stop <= n else None
            if data is None:  # vanished, or damaged and set aside
                continue
            if state.filled[start:stop].any():  # never written so; not shown twice
                log.warning("study %s: chunk file %s overlaps another chunk; not read",
                            self.id, name)  # fmt: skip
                continue
            for col in self.fields:
                state.cols[col][start:stop] = _chunk_column(data, col, stop - start)
            state.filled[start:stop] = True
            state.seen[name] = (*stamp, bool(data["_retry"]))
            state.files_read += 1
        return state

    def _empty_partial(self) -> PartialState:
        """Every point pending: the fill record of a failed point with reason ``pending``."""
        from worker.simulate import SolverSettings, failed_result

        rec = failed_result(SolverSettings(**self.study.solver.model_dump()), PENDING)
        n = self.study.size
        cols: dict[str, np.ndarray] = {}
        for name, arr in record_columns([rec], self.fields, self.cells).items():
            dtype = object if arr.dtype.kind == "U" else arr.dtype
            cols[name] = np.empty((n, *arr.shape[1:]), dtype=dtype)
            cols[name][:] = arr[0]
        return PartialState(cols=cols, filled=np.zeros(n, dtype=bool))

    def _gather(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        n = self.study.size
        filled = np.zeros(n, dtype=bool)
        cols: dict[str, np.ndarray] = {}
        for start, stop, path in self.chunks():
            if not 0 <= start < stop <= n:
                self._set_aside(path, None, f"the study has points 0-{n}")
                continue
            data = self._load_chunk(path)
            if data is None:  # vanished, or damaged and set aside: its points are missing
                continue
            if filled[start:stop].any():  # never written so: its points are computed again
                self._set_aside(path, None, "it overlaps another chunk")
                continue
            for name in self.fields:
                a = _chunk_column(data, name, stop - start)
                if name not in cols:
                    dtype = object if a.dtype.kind == "U" else a.dtype
                    cols[name] = np.empty((n, *a.shape[1:]), dtype=dtype)
                cols[name][start:stop] = a
            filled[start:stop] = True
        return cols, filled

    # ---------------------------------------------------------------- results

    @property
    def results_sum_path(self) -> Path:
        """Where the results file's SHA-256 is kept (``sha256sum`` format)."""
        return self.folder / _RESULTS_SUM

    def write_results(self, ds: xr.Dataset) -> Path:
        """Write the collated dataset atomically (NetCDF4, zlib), then its SHA-256."""
        enc = encoding(ds)

        def write(tmp: Path) -> None:
            write_netcdf(ds, tmp, enc)
            # The sum goes first: a reader never finds the new file with the old sum (it would
            # set a good file aside). A crash before the rename leaves the old file with the
            # new sum: checked as damaged and rebuilt, never trusted.
            self._write_sum(file_sha256(tmp))

        atomic_write(self.results_path, write)
        return self.results_path

    def _write_sum(self, digest: str) -> None:
        text = f"{digest}  {RESULTS_FILE}\n"
        atomic_write(self.results_sum_path, lambda p: p.write_text(text, encoding="ascii"))

    def _recorded_sum(self) -> str | None:
        """The SHA-256 kept for the results file (``None``: none; ``""``: unreadable)."""
        try:
            text = self.results_sum_path.read_text(encoding="ascii")
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError):
            return ""
        digest = text.split(maxsplit=1)[0] if text.strip() else ""
        return digest if re.fullmatch(r"[0-9a-f]{64}", digest) else ""

    def results_status(self) -> str:
        """``ok``, ``missing`` or ``damaged``: whether the results file is there and is what
        was written (its SHA-256 matches the one kept beside it).

        A damaged file (and its sum) is moved to ``damaged/`` and logged, so it is never read
        or served; a run of the study writes it again. A results file without a sum (written
        before sums were kept) is taken if it reads as this study's results, and its sum is
        written then. Each file is hashed once per process while it is unchanged.
        """
        path = self.results_path
        try:
            st = path.stat()
        except FileNotFoundError:
            return "missing"
        except OSError as exc:
            problem = f"cannot be read ({exc.strerror})"
            st = None
        else:
            with _VERIFIED_LOCK:
                if _VERIFIED.get(str(path)) == _stamp(st):
                    return "ok"
            problem = self._results_problem(path)
        if problem is not None:
            with _VERIFIED_LOCK:
                _VERIFIED.pop(str(path), None)
            checked = None if st is None else _stamp(st)
            self._set_aside(path, checked, problem)
            try:
                now: tuple[int, int, int] | None = _stamp(path.stat())
            except FileNotFoundError:  # set aside: its sum goes with it
                self._set_aside(self.results_sum_path, None, "its results file is damaged")
                return "damaged"
            except OSError:
                return "damaged"
            # Still there: it could not be moved (damaged), or a run wrote a new one meanwhile.
            return "damaged" if now == checked or st is None else self.results_status()
        with _VERIFIED_LOCK:
            _VERIFIED[str(path)] = _stamp(st)
        return "ok"

    def _results_problem(self, path: Path) -> str | None:
        """What is wrong with the results file (``None``: nothing)."""
        try:
            digest = file_sha256(path)
        except OSError as exc:
            return f"cannot be read ({exc.strerror})"
        want = self._recorded_sum()
        if want is None:  # written before sums were kept: taken if it reads as this study's
            try:
                attrs = open_results(path).attrs
            except Exception as exc:  # noqa: BLE001 - any reader error: not a results file
                return f"it has no SHA-256 and cannot be read ({type(exc).__name__})"
            if attrs.get("study_id") != self.id:
                return "it has no SHA-256 and is not this study's results"
            self._write_sum(digest)
            return None
        if digest != want:
            return "its content does not match its SHA-256" if want else "its SHA-256 is unreadable"
        return None

    def remove_chunks(self) -> None:
        """Delete the chunk files once the results file holds them."""
        for _, _, path in self.chunks():
            path.unlink(missing_ok=True)
        self._held.clear()
        self._held_points = 0
