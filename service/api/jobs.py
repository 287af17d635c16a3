"""The service's study queue: one runner thread sharing the dask cluster among studies.

Up to ``Settings.max_running_studies`` studies run at once; their chunks go to the cluster
round-robin through one :class:`~service.studies.runner.ChunkPool`, so a small study is never
held behind a large one. The rest wait in submission order (their ``queue_position``).

The catalogue is the source of truth for status. A running study belongs to one service
process: it holds the study's lease (``study:<id>``) in the catalogue and renews it every
``lease_ttl_s / 3`` seconds from a thread of its own (nothing a request or a big study does
delays it). Another process on the same catalogue never runs a study whose lease is alive; it
takes a study over only when its lease has expired (its process died or stalled) or its holder
is a process of this host that is gone. Each acquisition has a new generation, the fencing
token: every write for the study (chunk files, point rows, record updates) checks it at commit
(:mod:`service.studies.fence`), so a process that lost the lease and wakes up writes nothing
and stops running the study.

A study is prepared (its finished chunks read, the point store asked for known points) on a
thread of its own, so a huge grid never holds the runner thread. A chunk or results file that
cannot be stored for a passing reason (the database unreachable, the disk full or read-only)
is kept and stored again with backoff (at most ``outage_backoff_s`` apart) while the study
shows ``waiting`` with the reason; it goes on by itself when the resource is back.
Studies left ``queued`` or ``running`` by a stopped service are queued again on the next start
and resume from their finished chunks. Every process also picks up queued studies submitted
through the others, so several service processes share one queue.
"""

from __future__ import annotations

import contextlib
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
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.api.catalogue import ACTIVE, RESUMABLE, RUNNING, Catalogue, utcnow
from service.api.points import SqlPointStore
from service.api.settings import Settings
from service.studies.adaptive_run import AdaptiveRun
from service.studies.chunks import MissingPoints, StudyStore
from service.studies.dataset import json_text
from service.studies.fence import Backoff, Fence, FenceLost, is_transient
from service.studies.runner import (
    ChunkPool,
    RunSummary,
    StudyRun,
    make_client,
    make_run,
    warm_up,
)
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
    fence: tuple[str, str, int]  # (lease name, holder, token) its writes are checked against
    started: float = field(default_factory=time.monotonic)
    failures: list[dict[str, Any]] = field(default_factory=list)
    last_progress: float = 0.0
    shown: str | None = None  # the waiting reason its record shows (None: running)
    said: str | None = None  # the waiting reason last logged
    show_backoff: Backoff = field(default_factory=Backoff)  # writing that status
    finish_error: BaseException | None = None  # why its results file could not be written yet
    finish_backoff: Backoff | None = None
    collating: Future[Any] | None = None  # its results file being written (off the runner)
    summary: RunSummary | None = None  # its results file, once written

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
        # Leases this process holds (study → token), renewed by the heartbeat thread, which
        # puts a study whose token went stale in ``_lost`` (both under ``_lock``).
        self._tokens: dict[str, int] = {}
        self._lost: set[str] = set()
        self._beat_thread: threading.Thread | None = None
        # Studies being prepared (off the runner thread), and those waiting to be again.
        self._prep = ThreadPoolExecutor(2, thread_name_prefix="impactcell-prepare")
        # Results files are written off the runner thread too (a 2M-point study's takes long:
        # other studies' chunks go on meanwhile), each study's at once: a small study's file is
        # never written behind a big one's.
        self._collator = ThreadPoolExecutor(
            settings.max_running_studies, thread_name_prefix="impactcell-collate"
        )
        self._preparing: dict[str, Future[Any]] = {}
        self._prep_retry: dict[str, tuple[float, Backoff]] = {}

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Queue studies left unfinished (not those another live process runs), then start."""
        for sid in self.catalogue.ids_with_status(ACTIVE):
            self._queue.put(sid)
        self._thread = threading.Thread(target=self._loop, name="impactcell-runner", daemon=True)
        self._thread.start()
        self._beat_thread = threading.Thread(
            target=self._beat_loop, name="impactcell-heartbeat", daemon=True
        )
        self._beat_thread.start()

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
        if self._beat_thread is not None:
            self._beat_thread.join(timeout)
        self._prep.shutdown(wait=False, cancel_futures=True)
        # A results file being written is finished (collating removes the chunks it read); a
        # next start finds it, checked, and records it.
        self._collator.shutdown(wait=True, cancel_futures=True)
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
                in_pool = self._pool is not None and any(s in self._pool.runs for s in self._active)
                self._take_new(block=not in_pool)
                self._handle_drops()
                self._handle_lost()
                self._start_waiting()
                self._take_prepared()
                if self._pool is not None and in_pool:
                    for sid in self._pool.step(_STEP_S):
                        self._finish(sid)
                    self._handle_broken()
                self._retry_finishing()
                self._show_waiting()
                now = time.monotonic()
                if now >= next_beat:
                    next_beat = now + self.settings.lease_ttl_s / 3
                    self._heartbeat()
            except Exception:  # noqa: BLE001 - the thread must survive anything
                log.exception("runner loop")
                self._stopping.wait(_STEP_S)
        self._shutdown()

    def _beat_loop(self) -> None:
        """Renew the leases of the studies this process runs, every ``lease_ttl_s / 3`` s."""
        ttl = self.settings.lease_ttl_s
        while not self._stopping.wait(ttl / 3):
            with self._lock:
                tokens = dict(self._tokens)
            for sid, token in tokens.items():
                try:
                    ok = self.catalogue.renew_fenced(lease_name(sid), self.instance, token, ttl)
                except Exception:  # noqa: BLE001 - the catalogue is away: try at the next beat
                    log.warning("study %s: could not renew its lease", sid, exc_info=True)
                    continue
                if not ok:
                    with self._lock:
                        if self._tokens.get(sid) == token:
                            self._lost.add(sid)

    def _fence(self, sid: str, token: int) -> tuple[str, str, int]:
        return (lease_name(sid), self.instance, token)

    def _check_fence(self, sid: str, token: int) -> None:
        """Raise ``FenceLost`` unless this process still holds study ``sid`` with ``token``."""
        if not self.catalogue.fence_ok(*self._fence(sid, token)):
            raise FenceLost(f"study {sid}: another process runs it now")

    def _hold(self, sid: str, token: int) -> None:
        with self._lock:
            self._tokens[sid] = token
            self._lost.discard(sid)
        self.points.fences[sid] = self._fence(sid, token)

    def _unhold(self, sid: str, release: bool) -> None:
        """Stop holding a study's lease here (giving it back if ``release``)."""
        with self._lock:
            token = self._tokens.pop(sid, None)
            self._lost.discard(sid)
        self.points.fences.pop(sid, None)
        if release and token is not None:
            try:
                self.catalogue.release_fenced(lease_name(sid), self.instance, token)
            except Exception:  # noqa: BLE001 - an unreleased lease just expires
                log.warning("study %s: could not give its lease back", sid, exc_info=True)

    def _handle_lost(self) -> None:
        """Studies whose lease another process took: stop running them, writing nothing."""
        with self._lock:
            lost, self._lost = self._lost, set()
        for sid in lost:
            log.warning("study %s: lease lost to another process; stopping here", sid)
            self._forget(sid)

    def _handle_broken(self) -> None:
        """Runs the pool could not go on with: a lost fence (stop here), or a failure."""
        assert self._pool is not None
        for sid, exc in list(self._pool.broken.items()):
            if isinstance(exc, FenceLost):
                log.warning("study %s: %s; stopping here", sid, exc)
                self._forget(sid)
            else:
                self._fail(sid, exc)

    def _show_waiting(self) -> None:
        """Write ``waiting`` (with the reason) or ``running`` into the records of studies whose
        chunks or results file wait for the database or the disk, or no longer do."""
        for sid, act in list(self._active.items()):
            err = act.finish_error
            if err is None and self._pool is not None:
                err = self._pool.stalls.get(sid)
            want = None if err is None else _waiting_reason(err)
            if want != act.said:  # said once per change, even while the record cannot be
                act.said = want
                if want:
                    log.warning("study %s waits: %s", sid, want)
                else:
                    log.warning("study %s goes on: its chunks are stored again", sid)
            if want == act.shown or not act.show_backoff.due():
                continue
            fields: dict[str, Any] = {"status": "waiting", "error": want} if want else {
                "status": "running", "error": None}  # fmt: skip
            try:
                self.catalogue.update_fenced(sid, act.fence, RUNNING, **fields)
            except Exception as exc:  # noqa: BLE001 - the catalogue itself may be away
                act.show_backoff.failed()
                log.info("study %s: could not record %s: %s", sid, fields["status"], exc)
                continue
            # (not written: cancelled, or no longer ours; the heartbeat sees to it)
            act.show_backoff.ok()
            act.shown = want
            if want and err is not None and not isinstance(err, OSError):
                # The catalogue answered: the database is back, the chunks go at once.
                if self._pool is not None:
                    self._pool.retry_now(sid)
                if act.finish_backoff is not None:
                    act.finish_backoff.next_at = 0.0

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
            retrying = self._prep_retry.pop(sid, None) is not None
            if self._preparing.pop(sid, None) is not None or retrying:
                # A preparation still going finishes on its own; with the lease given back
                # (its token stale) nothing it would still write can commit.
                self._unhold(sid, release=True)
            self._drop_active(sid)
            ev.set()

    def _drop_active(self, sid: str) -> None:
        """Stop running a study here (its tasks told to stop) and give its lease back."""
        if sid in self._active:
            if self._pool is not None:
                self._pool.remove(sid)
            act = self._active.pop(sid)
            _settle(act)
            # the running time so far counts (a later resume continues from it)
            try:
                self.catalogue.update_fenced(
                    sid, act.fence, wall_s=act.wall_s(), failures=_json(act.failures)
                )
            finally:
                self._unhold(sid, release=True)

    def _busy(self) -> int:
        return len(self._active) + len(self._preparing) + len(self._prep_retry)

    def _start_waiting(self) -> None:
        now = time.monotonic()
        for sid, (at, _) in list(self._prep_retry.items()):
            if now >= at and sid in self._tokens:
                self._preparing[sid] = self._prep.submit(self._prepare, sid, self._tokens[sid])
                del self._prep_retry[sid]
        while self._waiting and self._busy() < self.settings.max_running_studies:
            sid = self._waiting.popleft()
            try:
                self._start(sid)
            except Exception as exc:  # noqa: BLE001 - recorded, the service carries on
                if is_transient(exc):  # the catalogue is away: try again later
                    log.warning("study %s: cannot start now: %s", sid, exc)
                    self._waiting.append(sid)
                    self._stopping.wait(_STEP_S)
                    return
                self._fail(sid, exc)

    def _start(self, sid: str) -> None:
        ttl = self.settings.lease_ttl_s
        name = lease_name(sid)
        token = self.catalogue.acquire_fenced(name, self.instance, ttl)
        if token is None:
            lease = self.catalogue.lease(name)
            if lease is None or not _holder_gone(lease["holder"]):
                return  # a live process runs it
            # Its process (of this host) is gone: no need to wait for the lease to expire.
            token = self.catalogue.acquire_fenced(
                name, self.instance, ttl, take_from=lease["holder"]
            )
            if token is None:
                return
        # Holding the lease, this process may start a queued study or take over a running one
        # whose process died.
        fence = self._fence(sid, token)
        if not self.catalogue.update_fenced(
            sid, fence, ACTIVE, status="running", started_at=utcnow(), error=None
        ):
            self.catalogue.release_fenced(*fence)
            return  # cancelled, deleted or finished meanwhile
        self._hold(sid, token)
        self._preparing[sid] = self._prep.submit(self._prepare, sid, token)

    def _prepare(
        self, sid: str, token: int
    ) -> tuple[dict[str, Any], Study, StudyRun | AdaptiveRun]:
        """Read a study's finished chunks and take known points (a thread of the preparation
        pool: a 2M-point grid takes minutes and must not hold the runner thread)."""
        rec = self.catalogue.get_study(sid)
        if rec is None:
            raise FenceLost(f"study {sid} was deleted")
        study = study_from_canonical(rec["definition"], source=f"study {sid}")
        run = make_run(
            study, self.settings.data_dir, workers=self._nworkers,
            progress=lambda done, total: self._progress(sid, done, total),
            points=self.points, fence=Fence(token, lambda: self._check_fence(sid, token)),
        )  # fmt: skip
        return rec, study, run

    def _take_prepared(self) -> None:
        """Start running the studies whose preparation ended."""
        for sid, fut in list(self._preparing.items()):
            if not fut.done():
                continue
            del self._preparing[sid]
            token = self._tokens.get(sid)
            if token is None:
                continue  # dropped meanwhile
            try:
                rec, study, run = fut.result()
            except FenceLost as exc:
                log.warning("study %s: %s; stopping here", sid, exc)
                self._unhold(sid, release=False)
                continue
            except Exception as exc:  # noqa: BLE001 - retried, or recorded
                if not is_transient(exc):
                    self._fail_token(sid, token, exc)
                    continue
                _, backoff = self._prep_retry.get(sid, (0.0, Backoff(cap=self._backoff_cap)))
                wait = backoff.failed()
                self._prep_retry[sid] = (time.monotonic() + wait, backoff)
                reason = _waiting_reason(exc)
                log.warning("study %s waits %.1f s: %s", sid, wait, reason)
                with contextlib.suppress(Exception):  # the catalogue itself may be away
                    self.catalogue.update_fenced(sid, self._fence(sid, token), RUNNING,
                                                 status="waiting", error=reason)  # fmt: skip
                continue
            failures: list[dict[str, Any]] = list(rec["failures"])
            run.on_chunk = lambda start, stop, records, run=run, failures=failures: _keep_failures(
                run.coords_of, failures, start, stop, records
            )
            act = _Active(study, run, float(rec["wall_s"] or 0.0), self._fence(sid, token),
                          failures=failures)  # fmt: skip
            act.shown = rec["error"] if rec["status"] == "waiting" else None
            self._active[sid] = act
            if act.run.cached or not act.run.pieces:
                self._finish(sid)
                continue
            try:
                pool = self._ensure_pool(study.solver.method)
                act.run.plan(self._nworkers)
            except Exception as exc:  # noqa: BLE001 - no cluster, or a plan it refuses: recorded
                self._fail(sid, exc)
                continue
            pool.add(sid, act.run)

    @property
    def _backoff_cap(self) -> float:
        return float(self.settings.outage_backoff_s)

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
                self._client, max(8, 4 * self._nworkers), self.settings.point_limits(),
                hold=True, backoff_cap=self._backoff_cap,
            )  # fmt: skip
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
        try:
            ok = self.catalogue.update_fenced(
                sid, act.fence, points_done=done, points_total=total, wall_s=act.wall_s(),
                failures=_json(act.failures),
            )  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - progress is a report: the next one catches up
            if not is_transient(exc):
                raise
            log.debug("study %s: progress not recorded: %s", sid, exc)
            return
        if not ok:
            self._check_fence(sid, act.fence[2])  # raises FenceLost if it is not ours any more

    def _finish(self, sid: str) -> None:
        act = self._active[sid]
        if act.finish_backoff is not None and not act.finish_backoff.due():
            return
        try:
            # Collated once: collating removes the chunks, so a retry (the catalogue was away)
            # records the results file written then.
            if act.summary is None:
                if act.collating is None:
                    if self._pool is not None:
                        self._pool.remove(sid)  # nothing of it runs any more
                    act.collating = self._collator.submit(act.run.collate, self._nworkers)
                    return  # looked at again by _retry_finishing
                if not act.collating.done():
                    return
                done, act.collating = act.collating, None
                try:
                    act.summary = done.result()
                except MissingPoints as exc:
                    self._run_again(sid, act, exc)
                    return
            summary = act.summary
            size = Path(summary.path).stat().st_size
            self._check_fence(sid, act.fence[2])
            self.catalogue.add_result_file(sid, str(summary.path), size)
            self.catalogue.update_fenced(
                sid, act.fence, RUNNING, status="finished", finished_at=utcnow(),
                wall_s=act.wall_s(), points_total=summary.points, points_done=summary.points,
                points_failed=summary.failed,
                points_irregular=summary.irregular, points_unsettled=summary.unsettled,
                points_computed=summary.computed, points_reused=summary.reused,
                failures=_json(act.failures), error=None,
            )  # fmt: skip
        except FenceLost as exc:
            log.warning("study %s: %s; stopping here", sid, exc)
            self._forget(sid)
            return
        except Exception as exc:  # noqa: BLE001 - retried, or recorded
            if is_transient(exc):
                # Its chunks stay: the results file is written again after a backoff.
                act.finish_error = exc
                if act.finish_backoff is None:
                    act.finish_backoff = Backoff(cap=self._backoff_cap)
                act.finish_backoff.failed()
                if self._pool is not None:
                    self._pool.remove(sid)
                log.warning("study %s: results file not written yet: %s", sid, exc)
                return
            self._fail(sid, exc)
            return
        self._active.pop(sid, None)
        if self._pool is not None:
            self._pool.remove(sid)
        self._unhold(sid, release=True)

    def _retry_finishing(self) -> None:
        """Write again the results files that could not be written (backed off)."""
        for sid, act in list(self._active.items()):
            if act.collating is not None or (
                act.finish_error is not None and act.finish_backoff is not None
            ):
                self._finish(sid)  # does nothing before its file or its backoff is due

    def _run_again(self, sid: str, act: _Active, exc: MissingPoints) -> None:
        """Queue a study again whose chunks were damaged (and set aside) while it ran: the
        next run computes their points (or takes them from the point store)."""
        log.warning("study %s: %s at collation (damaged chunks set aside); running it again",
                    sid, exc)  # fmt: skip
        self._active.pop(sid, None)
        if self._pool is not None:
            self._pool.remove(sid)
        queued = self.catalogue.update_fenced(
            sid, act.fence, RUNNING, status="queued", wall_s=act.wall_s(),
            failures=_json(act.failures),
        )  # fmt: skip
        self._unhold(sid, release=True)
        if queued:
            self._queue.put(sid)

    def _fail(self, sid: str, exc: BaseException) -> None:
        log.error("study %s failed: %s\n%s", sid, exc, traceback.format_exc())
        act = self._active.pop(sid, None)
        if act is not None and self._pool is not None:
            self._pool.remove(sid)
        token = self._tokens.get(sid)
        if token is None:
            self.catalogue.set_status_if(
                sid, ACTIVE, "failed", finished_at=utcnow(), error=f"{type(exc).__name__}: {exc}",
            )  # fmt: skip
            return
        self._fail_token(sid, token, exc)

    def _fail_token(self, sid: str, token: int, exc: BaseException) -> None:
        """Record a study as failed, if it is still ours, and give its lease back."""
        log.error("study %s failed: %s", sid, exc)
        try:
            self.catalogue.update_fenced(
                sid, self._fence(sid, token), ACTIVE, status="failed", finished_at=utcnow(),
                error=f"{type(exc).__name__}: {exc}",
            )  # fmt: skip
        finally:
            self._unhold(sid, release=True)

    def _heartbeat(self) -> None:
        """Drop studies cancelled or deleted elsewhere; adopt orphans (the runner thread;
        renewals are the heartbeat thread's)."""
        for sid in list(self._active):
            rec = self.catalogue.get_study(sid)
            if rec is None:  # deleted through another service process
                study = self._active[sid].study
                self._forget(sid)
                self._unhold(sid, release=True)
                _remove_files(StudyStore(self.settings.data_dir, study), [])
                continue
            if rec["status"] not in RUNNING:  # cancelled through another service process
                self._drop_active(sid)
        # Studies queued through another process, and running ones whose process died.
        known = set(self._active) | set(self._waiting) | set(self._preparing)
        known |= set(self._prep_retry)
        for sid in self.catalogue.ids_with_status(ACTIVE):
            if sid in known:
                continue
            lease = self.catalogue.lease(lease_name(sid))
            if lease is None or lease["expires_at"] <= utcnow() or _holder_gone(lease["holder"]):
                self._waiting.append(sid)

    def _forget(self, sid: str) -> None:
        """Drop a study's run here without touching its record (it is not ours any more)."""
        if self._pool is not None:
            self._pool.remove(sid)
        act = self._active.pop(sid, None)
        if act is not None:
            _settle(act)
        self._preparing.pop(sid, None)
        self._prep_retry.pop(sid, None)
        self._unhold(sid, release=False)

    def _shutdown(self) -> None:
        """Running studies go back to the queue (finished chunks kept) for the next start."""
        for sid in list(self._active):
            act = self._active[sid]
            if self._pool is not None:
                self._pool.remove(sid)
            try:
                self.catalogue.update_fenced(
                    sid, act.fence, RUNNING, status="queued", wall_s=act.wall_s(),
                    failures=_json(act.failures),
                )  # fmt: skip
            except Exception:  # noqa: BLE001 - stopping anyway: the next start sees it running
                log.warning("study %s: could not queue it again", sid, exc_info=True)
        for sid in list(self._tokens):
            if sid in self._active or sid in self._preparing or sid in self._prep_retry:
                with contextlib.suppress(Exception):  # as above
                    self.catalogue.set_status_if(sid, RUNNING, "queued")
            self._unhold(sid, release=True)
        self._active.clear()
        self._preparing.clear()
        self._prep_retry.clear()


def _waiting_reason(exc: BaseException) -> str:
    """What a waiting study's record says: what failed, and that it is retried."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, OSError):
        what = "the disk refused a write"
    else:
        what = "the catalogue database cannot be reached"
    return f"{what} ({type(exc).__name__}: {text[:300]}); retried until it succeeds"


def _holder_gone(holder: str) -> bool:
    """Whether a lease holder is another process of this host that is gone (a holder of this
    process, or of another host, is not: only its lease's expiry tells)."""
    host, _, rest = holder.partition(":")
    pid_text = rest.partition(":")[0]
    if host != socket.gethostname() or not pid_text.isdigit() or int(pid_text) == os.getpid():
        return False
    try:
        os.kill(int(pid_text), 0)
    except ProcessLookupError:
        return True
    except OSError:  # exists, owned by someone else
        return False
    return False


def _settle(act: _Active) -> None:
    """Wait for a results file being written for ``act`` (a cancel or delete must not race the
    writer; it is never long beside what the study took)."""
    if act.collating is not None:
        with contextlib.suppress(Exception):  # its outcome no longer matters here
            act.collating.result()
        act.collating = None


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
