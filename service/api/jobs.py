"""The service's study queue: one runner thread sharing the dask cluster among studies.

Up to ``Settings.max_running_studies`` studies run at once; their chunks go to the cluster
round-robin through one :class:`~service.studies.runner.ChunkPool`, so a small study is never
held behind a large one. The rest wait in submission order (their ``queue_position``).

The catalogue is the source of truth for status. A running study belongs to one service
process: it holds the study's lease (``study:<id>``) in the catalogue and renews it every
``lease_ttl_s / 3`` seconds. Another process on the same catalogue never runs a study whose
lease is alive; it takes a study over only when its lease has expired (its process died).
Studies left ``queued`` or ``running`` by a stopped service are queued again on the next start
and resume from their finished chunks. Every process also picks up queued studies submitted
through the others, so several service processes share one queue.
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import socket
import threading
import time
import traceback
import uuid
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.api.catalogue import ACTIVE, RESUMABLE, Catalogue, utcnow
from service.api.points import SqlPointStore
from service.api.settings import Settings
from service.studies.adaptive_run import AdaptiveRun
from service.studies.chunks import MissingPoints, StudyStore
from service.studies.dataset import json_text
from service.studies.runner import ChunkPool, StudyRun, make_client, make_run, warm_up
from service.studies.schema import Study, study_from_canonical

__all__ = ["JobManager", "StateError"]

log = logging.getLogger("impactcell.jobs")

_MAX_FAILURES_KEPT = 20  # sample of failed points (coordinates + reason) kept in the catalogue
_PROGRESS_EVERY_S = 0.5
_STEP_S = 0.25  # the runner thread's longest wait: how fast it sees cancels and new studies


class StateError(ValueError):
    """An action that the study's current state does not allow (HTTP 409)."""


def lease_name(study_id: str) -> str:
    """The catalogue lease that makes one process the runner of a study."""
    return f"study:{study_id}"


@dataclass
class _Active:
    """A study this process is running."""

    study: Study
    run: StudyRun | AdaptiveRun
    prior_wall_s: float  # running time of earlier runs (a resumed or taken-over study)
    started: float = field(default_factory=time.monotonic)
    failures: list[dict[str, Any]] = field(default_factory=list)
    last_progress: float = 0.0

    def wall_s(self) -> float:
        return self.prior_wall_s + time.monotonic() - self.started


class JobManager:
    """Owns the runner thread and the dask client of the service."""

    def __init__(self, settings: Settings, catalogue: Catalogue) -> None:
        self.settings = settings
        self.catalogue = catalogue
        self.points = SqlPointStore(catalogue.engine)
        self.instance = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._waiting: deque[str] = deque()  # runner thread only
        self._active: dict[str, _Active] = {}  # runner thread only
        self._drop: dict[str, threading.Event] = {}  # cancel/delete requests → runner's ack
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._client: Any = None
        self._cluster: Any = None
        self._pool: ChunkPool | None = None
        self._warm: set[str] = set()
        self._nworkers = 1
        self._dask_lock = threading.Lock()  # the runner thread and requests both may start it

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Queue studies left unfinished (not those another live process runs), then start."""
        for sid in self.catalogue.ids_with_status(ACTIVE):
            self._queue.put(sid)
        self._thread = threading.Thread(target=self._loop, name="impactcell-runner", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        """Whether the runner thread is taking studies from the queue (started, not stopping)."""
        alive = self._thread is not None and self._thread.is_alive()
        return alive and not self._stopping.is_set()

    def stop(self, timeout: float = 60.0) -> None:
        """Stop: running studies go back to ``queued`` (finished chunks kept) for the next start."""
        self._stopping.set()
        self._queue.put(None)
        if self._thread is not None:
            self._thread.join(timeout)
        self._close_dask()

    def _close_dask(self) -> None:
        for obj in (self._client, self._cluster):
            if obj is not None:
                try:
                    obj.close()
                except Exception:  # noqa: BLE001 - shutting down anyway
                    log.exception("closing dask")
        self._client = self._cluster = self._pool = None

    # ------------------------------------------------------------------ actions

    def submit(self, study: Study, *, resume: bool = False) -> tuple[dict[str, Any], bool]:
        """Queue a study unless the catalogue has it already; returns (record, created).

        With ``resume``, an existing cancelled or failed study is queued again (it continues
        from its finished chunks)."""
        rec, created = self.catalogue.add_study(
            study.id, study.name, study.canonical_json(), study.size
        )
        if created:
            self._queue.put(study.id)
        elif resume and rec["status"] in RESUMABLE:
            rec = self.resume(study.id)
        return rec, created

    def cancel(self, study_id: str, wait: float = 10.0) -> dict[str, Any]:
        """Cancel a queued or running study: its running tasks stop within seconds; finished
        chunks are kept."""
        rec = self._move(study_id, ACTIVE, "cancelled", "cancelled", finished_at=utcnow())
        self._request_drop(study_id, wait)
        return rec

    def delete(self, study_id: str, wait: float = 10.0) -> dict[str, Any]:
        """Remove a study: stop it if it runs, then delete its files and its record."""
        rec = self.catalogue.get_study(study_id)
        if rec is None:
            raise KeyError(study_id)
        if rec["status"] in ACTIVE:
            self.catalogue.set_status_if(study_id, ACTIVE, "cancelled", finished_at=utcnow())
            self._request_drop(study_id, wait)
        study = study_from_canonical(rec["definition"], source=f"study {study_id}")
        files = [Path(f["path"]) for f in self.catalogue.result_files(study_id)]
        self.catalogue.delete_study(study_id)
        _remove_files(StudyStore(self.settings.data_dir, study), files)
        return rec

    def resume(self, study_id: str) -> dict[str, Any]:
        """Queue a cancelled or failed study again; it continues from its finished chunks."""
        rec = self._move(study_id, RESUMABLE, "queued", "resumed", error=None, finished_at=None)
        self._queue.put(study_id)
        return rec

    def _move(
        self, study_id: str, allowed: tuple[str, ...], status: str, verb: str, **fields: Any
    ) -> dict[str, Any]:
        """Move a study to ``status`` if it is in ``allowed``: its record, or ``KeyError`` /
        :class:`StateError` (naming the states that allow it)."""
        ok = self.catalogue.set_status_if(study_id, allowed, status, **fields)
        rec = self.catalogue.get_study(study_id)
        if rec is None:
            raise KeyError(study_id)
        if not ok:
            raise StateError(
                f"study {study_id} is {rec['status']}; only {' or '.join(allowed)} studies "
                f"can be {verb}"
            )
        return rec

    def _request_drop(self, study_id: str, wait: float) -> None:
        """Ask the runner thread to drop a study and wait (bounded) until it has."""
        ev = threading.Event()
        with self._lock:
            self._drop[study_id] = ev
        if self.running:
            self._queue.put("")  # wake the runner thread
            ev.wait(wait)

    # ------------------------------------------------------------------ the runner thread

    def _loop(self) -> None:
        next_beat = 0.0
        while not self._stopping.is_set():
            try:
                self._take_new(block=not self._active)
                self._handle_drops()
                self._start_waiting()
                if self._pool is not None and self._active:
                    for sid in self._pool.step(_STEP_S):
                        self._finish(sid)
                now = time.monotonic()
                if now >= next_beat:
                    next_beat = now + self.settings.lease_ttl_s / 3
                    self._heartbeat()
            except Exception:  # noqa: BLE001 - the thread must survive anything
                log.exception("runner loop")
                time.sleep(_STEP_S)
        self._shutdown()

    def _take_new(self, block: bool) -> None:
        try:
            item = self._queue.get(timeout=_STEP_S) if block else self._queue.get_nowait()
        except queue.Empty:
            return
        while True:
            if item is None:
                self._stopping.set()
                return
            if item and item not in self._active and item not in self._waiting:
                self._waiting.append(item)
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return

    def _handle_drops(self) -> None:
        with self._lock:
            drops, self._drop = self._drop, {}
        for sid, ev in drops.items():
            if sid in self._waiting:
                self._waiting.remove(sid)
            self._drop_active(sid)
            ev.set()

    def _drop_active(self, sid: str) -> None:
        """Stop running a study here (its tasks told to stop) and give its lease back."""
        if sid in self._active:
            if self._pool is not None:
                self._pool.remove(sid)
            act = self._active.pop(sid)
            # the running time so far counts (a later resume continues from it)
            self.catalogue.update_study(sid, wall_s=act.wall_s(), failures=_json(act.failures))
            self.catalogue.release_lease(lease_name(sid), self.instance)

    def _start_waiting(self) -> None:
        while self._waiting and len(self._active) < self.settings.max_running_studies:
            sid = self._waiting.popleft()
            try:
                self._start(sid)
            except Exception as exc:  # noqa: BLE001 - recorded, the service carries on
                self._fail(sid, exc)

    def _start(self, sid: str) -> None:
        ttl = self.settings.lease_ttl_s
        if not self.catalogue.acquire_lease(lease_name(sid), self.instance, ttl):
            return  # a live process runs it
        # Holding the lease, this process may start a queued study or take over a running one
        # whose process died.
        if not self.catalogue.set_status_if(
            sid, ACTIVE, "running", started_at=utcnow(), error=None
        ):
            self.catalogue.release_lease(lease_name(sid), self.instance)
            return  # cancelled, deleted or finished meanwhile
        rec = self.catalogue.get_study(sid)
        assert rec is not None
        study = study_from_canonical(rec["definition"], source=f"study {sid}")
        failures: list[dict[str, Any]] = list(rec["failures"])
        run = make_run(
            study, self.settings.data_dir, workers=self._nworkers,
            progress=lambda done, total: self._progress(sid, done, total),
            points=self.points,
        )  # fmt: skip
        run.on_chunk = lambda start, stop, records: _keep_failures(
            run.coords_of, failures, start, stop, records
        )
        act = _Active(study, run, float(rec["wall_s"] or 0.0), failures=failures)
        self._active[sid] = act
        if act.run.cached or not act.run.pieces:
            self._finish(sid)
            return
        pool = self._ensure_pool(study.solver.method)
        act.run.plan(self._nworkers)
        pool.add(sid, act.run)

    def compute(self, fn: Any, *args: Any, method: str, timeout: float) -> Any:
        """Run ``fn(*args)`` on the service's dask cluster and wait up to ``timeout`` s for it
        (recomputations for requests: never in the API process, never holding its GIL).

        Raises
        ------
        TimeoutError
            The result did not come back in time (the task is released).
        """
        pool = self._ensure_pool(method)
        fut = pool.client.submit(fn, *args, pure=False, priority=10)  # ahead of study chunks
        try:
            return fut.result(timeout=timeout)
        finally:
            fut.release()

    def _ensure_pool(self, method: str) -> ChunkPool:
        with self._dask_lock:
            return self._ensure_pool_locked(method)

    def _ensure_pool_locked(self, method: str) -> ChunkPool:
        if self._client is None:
            # An embedded cluster's workers load ``method``'s kernels from numba's cache as they
            # start, or, on a cache without them, after this process compiled them
            # (``make_client``).
            self._client, self._cluster = make_client(
                self.settings.scheduler, self.settings.workers, method=method
            )
            info = self._client.scheduler_info()
            self._nworkers = max(1, sum(w.get("nthreads", 1) for w in info["workers"].values()))
            self._pool = ChunkPool(
                self._client, max(8, 4 * self._nworkers), self.settings.point_limits()
            )
        if method not in self._warm:
            warm_up(self._client, method)
            self._warm.add(method)
        assert self._pool is not None
        return self._pool

    def _progress(self, sid: str, done: int, total: int) -> None:
        act = self._active.get(sid)
        now = time.monotonic()
        if act is None or (now - act.last_progress < _PROGRESS_EVERY_S and done < total):
            return
        act.last_progress = now
        # An adaptive study's total is the most it may take, shrinking as its lines finish.
        self.catalogue.update_study(
            sid, points_done=done, points_total=total, wall_s=act.wall_s(),
            failures=_json(act.failures),
        )  # fmt: skip

    def _finish(self, sid: str) -> None:
        act = self._active.pop(sid)
        if self._pool is not None:
            self._pool.remove(sid)
        try:
            try:
                summary = act.run.collate(self._nworkers)
            except MissingPoints as exc:
                self._run_again(sid, act, exc)
                return
            size = Path(summary.path).stat().st_size
            self.catalogue.add_result_file(sid, str(summary.path), size)
            self.catalogue.set_status_if(
                sid, ("running",), "finished", finished_at=utcnow(), wall_s=act.wall_s(),
                points_total=summary.points, points_done=summary.points,
                points_failed=summary.failed,
                points_irregular=summary.irregular, points_unsettled=summary.unsettled,
                points_computed=summary.computed, points_reused=summary.reused,
                failures=_json(act.failures),
            )  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - recorded, the service carries on
            self._fail(sid, exc)
        finally:
            self.catalogue.release_lease(lease_name(sid), self.instance)

    def _run_again(self, sid: str, act: _Active, exc: MissingPoints) -> None:
        """Queue a study again whose chunks were damaged (and set aside) while it ran: the
        next run computes their points (or takes them from the point store)."""
        log.warning("study %s: %s at collation (damaged chunks set aside); running it again",
                    sid, exc)  # fmt: skip
        if self.catalogue.set_status_if(sid, ("running",), "queued", wall_s=act.wall_s(),
                                         failures=_json(act.failures)):  # fmt: skip
            self._queue.put(sid)

    def _fail(self, sid: str, exc: BaseException) -> None:
        log.error("study %s failed: %s\n%s", sid, exc, traceback.format_exc())
        act = self._active.pop(sid, None)
        if act is not None and self._pool is not None:
            self._pool.remove(sid)
        self.catalogue.set_status_if(
            sid, ACTIVE, "failed", finished_at=utcnow(), error=f"{type(exc).__name__}: {exc}",
        )  # fmt: skip
        self.catalogue.release_lease(lease_name(sid), self.instance)

    def _heartbeat(self) -> None:
        """Renew our leases; drop studies cancelled or deleted elsewhere; adopt orphans."""
        ttl = self.settings.lease_ttl_s
        for sid in list(self._active):
            rec = self.catalogue.get_study(sid)
            if rec is None:  # deleted through another service process
                study = self._active[sid].study
                self._forget(sid)
                self.catalogue.release_lease(lease_name(sid), self.instance)
                _remove_files(StudyStore(self.settings.data_dir, study), [])
                continue
            if rec["status"] != "running":  # cancelled through another service process
                self._drop_active(sid)
                continue
            if not self.catalogue.acquire_lease(lease_name(sid), self.instance, ttl):
                # Our lease lapsed and another process took the study over: it runs it now.
                log.warning("study %s: lease lost to another process; stopping here", sid)
                self._forget(sid)
        # Studies queued through another process, and running ones whose process died.
        known = set(self._active) | set(self._waiting)
        for sid in self.catalogue.ids_with_status(ACTIVE):
            if sid not in known and self.catalogue.lease_free(lease_name(sid)):
                self._waiting.append(sid)

    def _forget(self, sid: str) -> None:
        """Drop a study's run here without touching its record (it is not ours any more)."""
        if self._pool is not None:
            self._pool.remove(sid)
        self._active.pop(sid, None)

    def _shutdown(self) -> None:
        """Running studies go back to the queue (finished chunks kept) for the next start."""
        for sid in list(self._active):
            act = self._active[sid]
            if self._pool is not None:
                self._pool.remove(sid)
            self.catalogue.set_status_if(sid, ("running",), "queued", wall_s=act.wall_s(),
                                         failures=_json(act.failures))  # fmt: skip
            self.catalogue.release_lease(lease_name(sid), self.instance)
        self._active.clear()


def _keep_failures(
    coords_of: Callable[[int, int], Mapping[str, Any]], failures: list[dict[str, Any]],
    start: int, stop: int, records: list[dict[str, Any]],
) -> None:  # fmt: skip
    """Keep a sample of failed points (coordinates and reason) for the study record."""
    bad = [i for i, r in enumerate(records) if r.get("failed")]
    room = _MAX_FAILURES_KEPT - len(failures)
    if bad and room > 0:
        coords = coords_of(start, stop)
        for i in bad[:room]:
            failures.append({
                "index": start + i,
                "coords": {k: float(v[i]) for k, v in coords.items()},
                "reason": str(records[i].get("reason", "")),
            })  # fmt: skip


def _remove_files(store: StudyStore, files: list[Path]) -> None:
    """Delete a study's folder in the store and any results file recorded elsewhere."""
    shutil.rmtree(store.folder, ignore_errors=True)
    for f in files:
        f.unlink(missing_ok=True)


def _json(items: list[dict[str, Any]]) -> str:
    return json_text(items)
