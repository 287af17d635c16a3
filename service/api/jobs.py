"""The service's study queue: one runner thread feeding the dask cluster, cancel and resume.

Studies run one after another in submission order (each one already spreads over every dask
worker). The catalogue is the source of truth for status, so a restarted service picks up where
the last one stopped: studies left ``queued`` or ``running`` are queued again and resume from
their finished chunks.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import traceback
from pathlib import Path
from typing import Any

from service.api.catalogue import ACTIVE, RESUMABLE, Catalogue, utcnow
from service.api.settings import Settings
from service.studies.dataset import json_text
from service.studies.runner import RunSummary, make_client, run_study
from service.studies.schema import Study, study_from_canonical

__all__ = ["JobManager", "StateError"]

log = logging.getLogger("impactcell.jobs")

_MAX_FAILURES_KEPT = 20  # sample of failed points (coordinates + reason) kept in the catalogue
_PROGRESS_EVERY_S = 0.5


class StateError(ValueError):
    """An action that the study's current state does not allow (HTTP 409)."""


class JobManager:
    """Owns the runner thread and the dask client of the service."""

    def __init__(self, settings: Settings, catalogue: Catalogue) -> None:
        self.settings = settings
        self.catalogue = catalogue
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._cancel: dict[str, threading.Event] = {}
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._client: Any = None
        self._cluster: Any = None
        self.current: str | None = None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Re-queue studies a previous process left unfinished, then start the runner thread."""
        for sid in self.catalogue.ids_with_status(ACTIVE):
            self.catalogue.update_study(sid, status="queued")
            self._enqueue(sid)
        self._thread = threading.Thread(target=self._loop, name="impactcell-runner", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        """Whether the runner thread is taking studies from the queue (started, not stopping)."""
        alive = self._thread is not None and self._thread.is_alive()
        return alive and not self._stopping.is_set()

    def stop(self, timeout: float = 60.0) -> None:
        """Stop after the chunks in flight; an interrupted study stays queued for the next start."""
        self._stopping.set()
        with self._lock:
            for ev in self._cancel.values():
                ev.set()
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
        self._client = self._cluster = None

    # ------------------------------------------------------------------ actions

    def submit(self, study: Study) -> tuple[dict[str, Any], bool]:
        """Queue a study unless the catalogue has it already; returns (record, created)."""
        rec, created = self.catalogue.add_study(
            study.id, study.name, study.canonical_json(), study.size
        )
        if created:
            self._enqueue(study.id)
        return rec, created

    def cancel(self, study_id: str) -> dict[str, Any]:
        """Cancel a queued or running study; finished chunks are kept."""
        with self._lock:
            ok = self.catalogue.set_status_if(study_id, ACTIVE, "cancelled", finished_at=utcnow())
            ev = self._cancel.get(study_id)
            if ok and ev is not None:
                ev.set()
        rec = self.catalogue.get_study(study_id)
        if rec is None:
            raise KeyError(study_id)
        if not ok:
            raise StateError(
                f"study {study_id} is {rec['status']}; only queued or running "
                "studies can be cancelled"
            )
        return rec

    def resume(self, study_id: str) -> dict[str, Any]:
        """Queue a cancelled or failed study again; it continues from its finished chunks."""
        ok = self.catalogue.set_status_if(
            study_id, RESUMABLE, "queued", error=None, finished_at=None
        )
        rec = self.catalogue.get_study(study_id)
        if rec is None:
            raise KeyError(study_id)
        if not ok:
            raise StateError(
                f"study {study_id} is {rec['status']}; only cancelled or failed "
                "studies can be resumed"
            )
        if ok:
            self._enqueue(study_id)
        return rec

    def _enqueue(self, study_id: str) -> None:
        with self._lock:
            self._cancel[study_id] = threading.Event()
        self._queue.put(study_id)

    # ------------------------------------------------------------------ the runner thread

    def _loop(self) -> None:
        while not self._stopping.is_set():
            sid = self._queue.get()
            if sid is None or self._stopping.is_set():
                break
            try:
                self._run_one(sid)
            except Exception:  # noqa: BLE001 - the thread must survive any one study
                log.exception("study %s", sid)
            finally:
                self.current = None

    def _dask_client(self, method: str) -> Any:
        if self._client is None:
            # An embedded cluster starts after ``method``'s kernels are in numba's cache here.
            self._client, self._cluster = make_client(
                self.settings.scheduler, self.settings.workers, method=method
            )
        return self._client

    def _run_one(self, sid: str) -> None:
        with self._lock:
            ev = self._cancel.setdefault(sid, threading.Event())
        if not self.catalogue.set_status_if(
            sid, ("queued",), "running", started_at=utcnow(), error=None
        ):
            return  # cancelled (or already done) while it waited
        self.current = sid
        rec = self.catalogue.get_study(sid)
        assert rec is not None
        failures: list[dict[str, Any]] = list(rec["failures"])
        try:
            study = study_from_canonical(rec["definition"], source=f"study {sid}")
            summary = self._execute(sid, study, ev, failures)
        except Exception as exc:  # noqa: BLE001 - recorded, the service carries on
            log.error("study %s failed: %s\n%s", sid, exc, traceback.format_exc())
            self.catalogue.set_status_if(
                sid, ("running",), "failed", finished_at=utcnow(),
                error=f"{type(exc).__name__}: {exc}",
            )  # fmt: skip
            return
        if summary.cancelled:
            if self._stopping.is_set() and not _user_cancelled(self.catalogue, sid):
                # Service shutting down: leave it queued so the next start resumes it.
                self.catalogue.set_status_if(sid, ("running",), "queued")
            return
        size = Path(summary.path).stat().st_size
        self.catalogue.add_result_file(sid, str(summary.path), size)
        self.catalogue.set_status_if(
            sid, ("running",), "finished", finished_at=utcnow(), wall_s=summary.wall_s,
            points_done=summary.points, points_failed=summary.failed,
            points_irregular=summary.irregular, points_unsettled=summary.unsettled,
            failures=_json(failures),
        )  # fmt: skip

    def _execute(
        self, sid: str, study: Study, ev: threading.Event, failures: list[dict[str, Any]]
    ) -> RunSummary:
        last = [0.0]

        def on_chunk(start: int, stop: int, records: list[dict[str, Any]]) -> None:
            bad = [i for i, r in enumerate(records) if r.get("failed")]
            if bad and len(failures) < _MAX_FAILURES_KEPT:
                coords = study.coords_at(start, stop)
                for i in bad[: _MAX_FAILURES_KEPT - len(failures)]:
                    failures.append({
                        "index": start + i,
                        "coords": {k: float(v[i]) for k, v in coords.items()},
                        "reason": str(records[i].get("reason", "")),
                    })  # fmt: skip

        def progress(done: int, total: int) -> None:
            now = time.monotonic()
            if now - last[0] >= _PROGRESS_EVERY_S or done >= total:
                last[0] = now
                self.catalogue.update_study(sid, points_done=done, failures=_json(failures))

        client = None if study.size == 0 else self._dask_client(study.solver.method)
        return run_study(
            study,
            self.settings.data_dir,
            client=client,
            progress=progress,
            on_chunk=on_chunk,
            cancel=ev.is_set,
        )


def _json(items: list[dict[str, Any]]) -> str:
    return json_text(items)


def _user_cancelled(catalogue: Catalogue, sid: str) -> bool:
    rec = catalogue.get_study(sid)
    return rec is not None and rec["status"] == "cancelled"
