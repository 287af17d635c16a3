"""The nightly suite run by the service itself, through its own job queue.

When the service runs the suite (its cron schedule, :mod:`service.api.schedule`, or
``POST /regressions``), every study of the suite is submitted to the service's job queue
(:class:`service.api.jobs.JobManager`) like any user's study: it runs on the service's dask
cluster, is listed by ``GET /studies`` (the suite's study names start with ``nightly-``) and can
be followed, or cancelled, like any other. Each study carries the run's tag
(``nightly-<UTC time>``, part of the study id), so every run computes afresh while a user who
submits the same definition untagged still gets the cached study. When every study has ended,
the finished datasets are compared with the baselines; a study that was cancelled or failed is
reported as such (the run is not ok), never skipped.

The suite is the shipped one (``studies/nightly`` with ``studies/baselines``) or
``IMPACTCELL_NIGHTLY_DIR`` with the ``baselines`` folder beside it.

A runner made at service start first ends the runs that an earlier process left without an
outcome (it died mid-run) as ``interrupted`` (:func:`service.api.schedule.recover_interrupted`),
looking again later for runs whose heartbeat lease had not expired yet.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import threading
import time
from pathlib import Path
from typing import Any

from service.api.catalogue import Catalogue
from service.api.jobs import JobManager, StateError
from service.api.schedule import (
    PROCESS_HOLDER,
    RUN_LEASE_TTL_S,
    Heartbeat,
    record_run,
    recover_interrupted,
)
from service.api.settings import Settings
from service.regression.compare import StudyComparison
from service.regression.run import (
    check_baselines,
    evaluate,
    make_report,
    new_run_dir,
    not_run,
    tagged,
)
from service.regression.suite import SuiteEntry, load_suite, suite_folders
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.schema import Study

__all__ = ["NightlyBusy", "NightlyRunner"]

log = logging.getLogger("impactcell.nightly")

_ENDED = ("finished", "failed", "cancelled")


#: Held (and renewed) by the process whose nightly run goes on: one run at a time across every
#: service process on the catalogue.
SUITE_LEASE = "nightly-suite"


class NightlyBusy(RuntimeError):
    """A nightly run cannot start now (one is in progress, or the job runner is off)."""


class NightlyRunner:
    """Runs the nightly suite through the service's job queue, one run at a time."""

    def __init__(
        self, settings: Settings, catalogue: Catalogue, jobs: JobManager, *, poll: float = 0.5
    ) -> None:
        self.settings = settings
        self.catalogue = catalogue
        self.jobs = jobs
        self.poll = poll
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._recheck: threading.Timer | None = None
        self.recover_interrupted()

    def recover_interrupted(self) -> list[int]:
        """End runs left without an outcome by a dead process; returns their ids.

        Runs whose heartbeat lease is still alive are looked at again when it expires (a
        process that has just died keeps its lease that long).
        """
        try:
            ended, again = recover_interrupted(self.catalogue)
        except Exception:  # noqa: BLE001 - never keep the service from starting over this
            log.exception("could not check for interrupted nightly runs")
            return []
        if again is not None and not self._stop.is_set():
            wait = (again - dt.datetime.now(dt.UTC)).total_seconds() + 1.0
            self._recheck = threading.Timer(max(wait, 1.0), self.recover_interrupted)
            self._recheck.daemon = True
            self._recheck.start()
        return ended

    @property
    def busy(self) -> bool:
        """Whether a run is in progress in this process."""
        return self._lock.locked()

    def run(self) -> dict[str, Any]:
        """Run the suite and wait for it (after a run in progress); the cron schedule's run.

        Returns ``{"ok", "report", "markdown"}`` (:func:`service.api.schedule.record_run`).

        Raises
        ------
        SuiteError
            The suite, its baseline folder or a baseline is bad or missing (nothing was
            submitted).
        """
        with self._lock:
            self._take_suite_lease()
            with Heartbeat(self.catalogue, SUITE_LEASE):
                return self._run()

    def _take_suite_lease(self) -> None:
        if not self.catalogue.acquire_lease(SUITE_LEASE, PROCESS_HOLDER, RUN_LEASE_TTL_S):
            raise NightlyBusy(
                "a nightly run is in progress in another service process; see GET /regressions"
            )

    def start(self, trigger: str = "api") -> int:
        """Start a run in a background thread; returns its regression id (``GET /regressions``).

        Raises
        ------
        NightlyBusy
            A run is in progress in this process, or the job runner is off.
        """
        if not self.jobs.running:
            raise NightlyBusy("the service's job runner is not running; no study would run")
        if not self._lock.acquire(blocking=False):
            raise NightlyBusy("a nightly run is in progress; see GET /regressions")
        try:
            self._take_suite_lease()
            reg_id = self.catalogue.add_regression(trigger)

            def work() -> None:
                try:
                    with Heartbeat(self.catalogue, SUITE_LEASE):
                        record_run(self.catalogue, reg_id, self._run)
                finally:
                    self._lock.release()

            self._thread = threading.Thread(target=work, name="impactcell-nightly-run", daemon=True)
            self._thread.start()
        except BaseException:
            with contextlib.suppress(Exception):  # else it just expires
                self.catalogue.release_lease(SUITE_LEASE, PROCESS_HOLDER)
            self._lock.release()
            raise
        return reg_id

    def stop(self, timeout: float = 30.0) -> None:
        """Stop waiting: a run in progress cancels its unfinished studies and reports that."""
        self._stop.set()
        if self._recheck is not None:
            self._recheck.cancel()
        if self._thread is not None:
            self._thread.join(timeout)

    # ------------------------------------------------------------------ one run

    def _run(self) -> dict[str, Any]:
        t0 = time.perf_counter()
        started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
        suite_dir, base_dir = suite_folders(self.settings.nightly_dir)
        entries = load_suite(suite_dir, max_points=self.settings.max_points)
        check_baselines(entries, base_dir, update=False)  # before any study is queued
        run_dir = new_run_dir(self.settings.data_dir)
        tag = f"nightly-{run_dir.name}"
        log.info("nightly run %s: %d studies through the job queue", tag, len(entries))

        submitted: list[tuple[SuiteEntry, Study]] = []
        for entry in entries:
            study = tagged(entry.study, tag)
            self.jobs.submit(study)
            submitted.append((entry, study))
        results = [self._result(entry, study, base_dir) for entry, study in submitted]

        report = make_report(
            entries, results, suite_dir, base_dir, mode=f"service job queue (tag {tag})",
            update=False, started=started, wall_s=time.perf_counter() - t0, report_dir=run_dir,
        )  # fmt: skip
        log.info("nightly run %s: %s", tag, report.summary())
        return {"ok": report.ok, "report": report.to_json(), "markdown": report.to_markdown()}

    def _result(self, entry: SuiteEntry, study: Study, base_dir: Path) -> StudyComparison:
        """Wait for one study to end, then compare it (or say why it cannot be)."""
        rec = self._wait(study.id)
        sid = study.id
        if rec is None:
            self._cancel(sid)
            cmp = not_run(
                entry,
                f"the service stopped before study {sid} finished; it was cancelled and this run "
                "is incomplete",
                status="cancelled",
            )
        elif rec["status"] == "finished":
            store = StudyStore(self.settings.data_dir, study)
            try:
                if store.results_status() != "ok":  # missing, or damaged and set aside
                    raise ValueError("its results file is missing or failed its SHA-256 check")
                ds = open_results(store.results_path)
            except Exception as exc:  # noqa: BLE001 - reported in the run's report
                why = str(exc).replace(str(store.results_path), "results.nc")  # no server path
                cmp = not_run(entry, f"cannot read the results of study {sid}: {why}")
            else:
                cmp = evaluate(entry, ds, f"service study {sid}", base_dir)
        elif rec["status"] == "cancelled":
            cmp = not_run(
                entry,
                f"study {sid} was cancelled before it finished ({rec['points_done']} of "
                f"{rec['points_total']} points); nothing compared",
                status="cancelled",
            )
        else:
            cmp = not_run(entry, f"study {sid} failed on the service: {rec['error']}")
        cmp.study_id = sid
        if rec is not None and rec.get("wall_s") is not None:
            cmp.wall_s = round(float(rec["wall_s"]), 3)
        return cmp

    def _wait(self, sid: str) -> dict[str, Any] | None:
        """The study's record once it has ended; ``None`` when the service is stopping."""
        while True:
            rec = self.catalogue.get_study(sid)
            if rec is None:
                raise RuntimeError(f"study {sid} vanished from the catalogue")
            if rec["status"] in _ENDED:
                return rec
            if self._stop.wait(self.poll):
                return None

    def _cancel(self, sid: str) -> None:
        with contextlib.suppress(KeyError, StateError):  # ended meanwhile
            self.jobs.cancel(sid)
