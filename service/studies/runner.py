"""Run a study on dask.distributed: chunking, submission with retries, progress, resume.

The runner owns the dask client. By default it starts an embedded ``LocalCluster`` (one
single-threaded worker process per core); given a scheduler address (``Settings.scheduler``:
``--scheduler`` or ``IMPACTCELL_SCHEDULER``) it uses that cluster instead. Points go out in
chunks of consecutive grid points (one ``worker.simulate.simulate_chunk`` call per task); each
finished chunk is written to the store as soon as it arrives, so a rerun after a crash computes
only what is missing. Results do not depend on the chunk size: each point is computed on its own.

A sweep (``sweep:`` in the study) is computed line by line: a line is one initial state × one
direction × one combination of the other axes, its points along the swept axis in sweep order,
each starting from the previous one's final state. Lines are contiguous in the runner's flat
index ("work order", :meth:`~service.studies.schema.Study.work_indices`), so a chunk is exactly
one line (one ``worker.simulate.simulate_line`` call per task) and a killed run resumes line by
line; lines run in parallel like chunks.

A :class:`StudyRun` is one study's side of a run (its store, the chunks still to compute, what
came back); a :class:`ChunkPool` keeps a bounded window of tasks on the cluster and fills it
round-robin over every study added to it, so several studies share the cluster fairly (the
service runs all its running studies through one pool; ``run_study`` runs one). Cancel reaches
running tasks: each task polls its study's ``distributed.Event`` between points and inside each
point, and every point has a wall-time and step budget (``worker.simulate.PointLimits``).

Workers never compile the same kernel twice: before an embedded cluster starts (and before the
workers warm up) this process compiles the method's numba kernels, or loads them from numba's
on-disk cache, so the worker processes load that cache instead of each compiling the same
kernels in parallel.
"""

from __future__ import annotations

import itertools
import math
import os
import time
import uuid
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from service.studies.chunks import StudyStore, iter_chunk_ranges
from service.studies.dataset import open_results, results_from_records, summarize
from service.studies.schema import Study
from service.studies.variables import OUTCOMES, outcome_names
from worker import simulate
from worker.simulate import (
    PointLimits,
    SolverSettings,
    failed_result,
    simulate_chunk,
    simulate_line,
)
from worker.solvers.settings import DEFAULT_METHOD

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "Cancelled",
    "ChunkPool",
    "RunSummary",
    "StudyRun",
    "default_chunk_size",
    "make_client",
    "run_study",
    "warm_up",
]

DEFAULT_CHUNK_SIZE = 32  # points per task: ~0.1–0.6 s at 2–20 ms a point, ≫ dask's ~1 ms
TASK_RETRIES = 2
CONNECT_TIMEOUT = "10s"  # an unreachable scheduler is an error within seconds, not minutes
CANCEL_POLL_S = 1.0  # how often a running task asks whether its study was cancelled
# Single-threaded BLAS in worker processes: dask's ``distributed.nanny.pre-spawn-environ``
# default already sets these to 1 before a worker process starts; only missing ones are added.
_ONE_BLAS_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

Progress = Callable[[int, int], None]  # (points done, total points)
ChunkDone = Callable[[int, int, list[dict[str, Any]]], None]  # (start, stop, records)


class Cancelled(Exception):
    """Raised inside the runner when its ``cancel`` callback says stop."""


@dataclass
class RunSummary:
    """What a run did."""

    study_id: str
    path: Path
    points: int
    computed: int  # points computed by this run (the rest came from earlier, interrupted runs)
    failed: int
    irregular: int  # outcome irregular: converged statistics of a non-periodic response
    unsettled: int  # outcome unsettled: the period budget ran out before the point ended
    wall_s: float
    kernel_s: float  # sum of per-point kernel times of the points computed now
    workers: int
    chunk_size: int
    reused: bool = False  # the results file already existed
    cancelled: bool = False  # stopped on request: finished chunks kept, no results file yet
    # points by outcome (linear, periodic, irregular, unsettled, failed); empty when unknown
    outcomes: dict[str, int] = field(default_factory=dict)


def default_chunk_size(points: int, workers: int) -> int:
    """``DEFAULT_CHUNK_SIZE``, smaller for small studies so every worker gets several tasks."""
    return max(1, min(DEFAULT_CHUNK_SIZE, math.ceil(points / max(1, 4 * workers))))


def warm_up(client: Any, method: str = DEFAULT_METHOD) -> None:
    """Compile/load a method's numba kernels in every worker before timing anything."""
    client.run(simulate.warm_up, method)


def _is_local(client: Any) -> bool:
    """Whether the client's workers run on this machine (a LocalCluster: they share its
    numba cache)."""
    from dask.distributed import LocalCluster

    return isinstance(getattr(client, "cluster", None), LocalCluster)


def _worker_environ() -> None:
    """Make sure worker processes start with one BLAS thread (only what dask does not set)."""
    import dask

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    missing = {k: 1 for k in _ONE_BLAS_THREAD if k not in env}
    if missing:
        dask.config.set({"distributed.nanny.pre-spawn-environ": {**env, **missing}})


def make_client(
    scheduler: str | None, workers: int | None, *, method: str | None = DEFAULT_METHOD
) -> tuple[Any, Any]:
    """A dask client on ``scheduler`` if given, else on a new LocalCluster of ``workers``.

    Before a LocalCluster starts, ``method``'s kernels (``None``: every method's) are compiled
    or loaded here, so its workers find them in numba's on-disk cache.
    """
    from dask.distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler, timeout=CONNECT_TIMEOUT), None
    simulate.warm_up(method)
    _worker_environ()
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(
        n_workers=n,
        threads_per_worker=1,  # the kernels hold the GIL: parallelism comes from processes
        processes=True,
        dashboard_address=":0",  # a free port: never clash with a running dask
        silence_logs=40,  # logging.ERROR
    )
    return Client(cluster), cluster


def _nthreads(client: Any) -> int:
    info = client.scheduler_info()
    return max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))


class StudyRun:
    """One study's side of a run: its store, the chunks still to compute and what came back.

    Made by :func:`run_study` and by the service's job manager; the chunks go to a
    :class:`ChunkPool` (or run serially). ``reused`` is true when the results file already
    exists and nothing is left to compute.
    """

    def __init__(
        self,
        study: Study,
        root: str | os.PathLike[str] | None,
        *,
        chunk_size: int | None = None,
        workers: int = 1,
        progress: Progress | None = None,
        on_chunk: ChunkDone | None = None,
    ) -> None:
        self.t0 = time.perf_counter()
        self.study = study
        self.store = StudyStore(root, study)
        self.total = study.size
        self.progress = progress
        self.on_chunk = on_chunk
        self.kernel_s = 0.0
        self.in_flight = 0
        self.submitted = 0  # chunks handed to a pool (its fairness: fewer goes first)
        self.reused = self.store.results_path.exists() and not self.store.has_retry_chunks()
        missing: list[tuple[int, int]] = []
        if not self.reused:
            self.store.prepare()
            missing = self.store.missing_ranges()
        self.n_missing = sum(b - a for a, b in missing)
        self.done = self.total - self.n_missing
        self._missing = missing
        self._chunk_size = chunk_size
        self.chunk = 0
        self.pieces: deque[tuple[int, int]] = deque()
        self.plan(workers)
        self.solver = study.solver.settings().__dict__.copy()
        if progress and not self.reused:
            progress(self.done, self.total)

    @property
    def lines(self) -> bool:
        """Whether chunks are sweep lines (``simulate_line``), not independent points."""
        return self.study.sweep is not None

    def plan(self, workers: int) -> None:
        """Cut the missing points into chunks for ``workers`` (before any chunk went out); a
        sweep's chunks are its whole lines, whatever ``chunk_size`` says."""
        n = self.n_missing
        if self.lines:
            self.chunk = self.study.line_length
            for a, b in self._missing:
                if a % self.chunk or b % self.chunk:
                    raise ValueError(
                        f"study {self.study.id}: stored chunks cover part of a sweep line "
                        f"(points {a}-{b} missing, lines of {self.chunk}); remove its chunks"
                    )
        else:
            self.chunk = (
                default_chunk_size(n, workers) if self._chunk_size is None else self._chunk_size
            )
        self.pieces = deque(iter_chunk_ranges(self._missing, self.chunk))  # refuses chunk < 1

    @property
    def complete(self) -> bool:
        """Every chunk computed and stored (nothing queued, nothing in flight)."""
        return not self.pieces and self.in_flight == 0

    def finished(self, start: int, stop: int, records: list[dict[str, Any]], retry: bool) -> None:
        """Store a chunk's records (``retry``: failed tasks, for a later run to try again)."""
        self.store.write_chunk(start, stop, records, retry=retry)
        self.kernel_s += sum(r["wall_s"] for r in records)
        self.done += stop - start
        if self.on_chunk:
            self.on_chunk(start, stop, records)
        if self.progress:
            self.progress(self.done, self.total)

    def run_serial(self, cancel: Callable[[], bool], limits: PointLimits) -> None:
        """Compute the remaining chunks in this process (reference runs, debugging)."""
        budget = asdict(limits)
        while self.pieces:
            if cancel():
                raise Cancelled
            start, stop = self.pieces.popleft()
            run = simulate_line if self.lines else simulate_chunk
            records = run(self.study.points(start, stop), self.solver, budget, cancel)
            if len(records) < stop - start:  # cancelled inside the chunk
                raise Cancelled
            self.finished(start, stop, records, False)

    def collate(self, workers: int) -> RunSummary:
        """Collate the stored chunks into the results file (or reuse it) and summarise."""
        if self.reused:
            ds = open_results(self.store.results_path)
            return _summary(self, ds, computed=0, workers=0, reused=True)
        cols = self.store.collect()
        ds = results_from_records(self.study, cols)
        self.store.write_results(ds)
        if not self.store.has_retry_chunks():  # keep task failures around for the next run
            self.store.remove_chunks()
        return _summary(
            self, ds, computed=self.n_missing, workers=workers,
            outcomes=outcome_names(cols["outcome"]),
        )  # fmt: skip

    def cancelled_summary(self, workers: int) -> RunSummary:
        """The summary of a run stopped on request: finished chunks kept, no results file."""
        return RunSummary(
            study_id=self.study.id, path=self.store.results_path, points=self.total,
            computed=self.done - (self.total - self.n_missing), failed=0, irregular=0,
            unsettled=0, wall_s=time.perf_counter() - self.t0, kernel_s=self.kernel_s,
            workers=workers, chunk_size=self.chunk, cancelled=True,
        )  # fmt: skip


class _CancelProbe:
    """Runs inside a task: whether the task's study was cancelled (a ``distributed.Event``),
    asked at most every ``CANCEL_POLL_S`` seconds so the scheduler is not flooded."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._event: Any = None
        self._next = 0.0
        self._set = False

    def __call__(self) -> bool:
        now = time.monotonic()
        if self._set or now < self._next:
            return self._set
        self._next = now + CANCEL_POLL_S
        try:
            if self._event is None:
                from distributed import Event

                self._event = Event(self.name)
            self._set = bool(self._event.is_set())
        except Exception:  # noqa: BLE001 - no scheduler to ask (a local call): not cancelled
            self._set = False
        return self._set

    def __getstate__(self) -> dict[str, Any]:
        return {"name": self.name}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["name"])  # type: ignore[misc]


def _chunk_task(
    points: list[dict[str, Any]],
    solver: dict[str, Any],
    limits: dict[str, Any],
    cancel_event: str,
    line: bool = False,
) -> list[dict[str, Any]]:
    """One dask task: ``simulate_chunk`` (``line``: ``simulate_line``, one sweep line) with the
    study's cancel event polled inside."""
    run = simulate_line if line else simulate_chunk
    return run(points, solver, limits, _CancelProbe(cancel_event))


class ChunkPool:
    """A bounded window of chunk tasks on a dask cluster, filled round-robin over studies.

    ``add`` a :class:`StudyRun` under a key; ``step`` submits until the window is full (one
    chunk per study in turn, so a small study is never stuck behind a large one), waits up to
    ``timeout`` for tasks to finish and hands their records to their runs; ``remove`` drops a
    study: its queued tasks are cancelled and its running tasks stop at their next poll.
    """

    def __init__(self, client: Any, window: int, limits: PointLimits | None = None) -> None:
        self.client = client
        self.window = window
        self.limits = asdict(limits or PointLimits())
        self.runs: dict[str, StudyRun] = {}
        self._order: deque[str] = deque()  # round-robin order of the runs with chunks left
        self._futures: dict[Any, tuple[str, int, int]] = {}  # future → (run key, start, stop)
        self._events: dict[str, str] = {}  # run key → name of its cancel event
        self._tag = uuid.uuid4().hex[:8]  # a resumed run must not reuse keys of a cancelled one
        self._count = itertools.count()

    def add(self, key: str, run: StudyRun) -> None:
        """Take a study's remaining chunks into the rotation."""
        self.runs[key] = run
        self._events[key] = f"impactcell-cancel-{key}-{self._tag}-{next(self._count)}"
        self._order.append(key)

    def remove(self, key: str) -> StudyRun | None:
        """Drop a study: queued tasks cancelled, running ones told to stop; its run returned."""
        run = self.runs.pop(key, None)
        if key in self._order:
            self._order.remove(key)
        mine = [f for f, (k, _, _) in self._futures.items() if k == key]
        for f in mine:
            del self._futures[f]
        name = self._events.pop(key, None)
        if mine:
            try:
                from distributed import Event

                Event(name, client=self.client).set()  # running tasks see it within a second
                self.client.cancel(mine, force=True)
            except Exception:  # noqa: BLE001 - the cluster may be going away; nothing to save
                pass
        if run is not None:
            run.in_flight = 0
        return run

    @property
    def idle(self) -> bool:
        """No task in flight."""
        return not self._futures

    def _fill(self) -> None:
        while len(self._futures) < self.window and self._order:
            key = self._order.popleft()
            run = self.runs[key]
            if not run.pieces:
                continue  # out of the rotation until removed or complete
            start, stop = run.pieces.popleft()
            fut = self.client.submit(
                _chunk_task,
                run.study.points(start, stop),
                run.solver,
                self.limits,
                self._events[key],
                run.lines,
                key=f"impactcell-{run.study.id}-{start}-{stop}-{self._tag}",
                retries=TASK_RETRIES,
                pure=False,
                # The scheduler runs higher priorities first: a study's n-th chunk waits behind
                # every other study's earlier chunks, so a new small study starts at once.
                priority=-run.submitted,
            )
            self._futures[fut] = (key, start, stop)
            run.in_flight += 1
            run.submitted += 1
            if run.pieces:
                self._order.append(key)

    def step(self, timeout: float) -> list[str]:
        """Fill the window, wait up to ``timeout`` s, store what finished; keys of the runs
        that are now complete."""
        from distributed import wait

        self._fill()
        if not self._futures:
            return [k for k, r in self.runs.items() if r.complete]
        try:
            done = wait(list(self._futures), timeout=timeout, return_when="FIRST_COMPLETED").done
        except TimeoutError:  # distributed ≥ 2024 raises the builtin on timeout
            done = set()
        for fut in done:
            if fut not in self._futures:
                continue
            key, start, stop = self._futures.pop(fut)
            run = self.runs[key]
            run.in_flight -= 1
            # Not ``fut.status``: a finished future whose worker died before we fetched the
            # result is "lost" until dask has computed it again, and ``result()`` waits for it.
            try:
                records = fut.result()
            except Exception as exc:  # noqa: BLE001 - whatever the task raised, or KilledWorker
                # Failed even after its retries (or its workers kept dying): record the points
                # as failed with the reason, and mark the chunk so a rerun tries them again.
                reason = f"task failed after {TASK_RETRIES} retries: {type(exc).__name__}: {exc}"
                rec = failed_result(SolverSettings(**run.solver), reason)
                run.finished(start, stop, [dict(rec) for _ in range(stop - start)], True)
            else:
                if len(records) < stop - start:  # stopped by a cancel: recomputed on resume
                    run.pieces.appendleft((start, stop))
                else:
                    run.finished(start, stop, records, False)
            fut.release()
        self._fill()
        return [k for k, r in self.runs.items() if r.complete]


def run_study(
    study: Study,
    root: str | os.PathLike[str] | None = None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    chunk_size: int | None = None,
    client: Any = None,
    serial: bool = False,
    progress: Progress | None = None,
    max_in_flight: int | None = None,
    cancel: Callable[[], bool] | None = None,
    on_chunk: ChunkDone | None = None,
    limits: PointLimits | None = None,
) -> RunSummary:
    """Run (or resume) a study and collate its results file.

    Parameters
    ----------
    study : Study
        A validated study.
    root : path, optional
        Data root of the store (see :func:`service.studies.chunks.data_root`).
    scheduler : str, optional
        ``tcp://host:port`` of an existing scheduler (else an embedded ``LocalCluster``).
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    chunk_size : int, optional
        Points per task (default :func:`default_chunk_size`); a sweep's tasks are its lines.
    client : distributed.Client, optional
        Use this client (not closed here); overrides ``scheduler``/``workers``.
    serial : bool
        Run in this process without dask (reference runs, debugging).
    progress : callable, optional
        ``progress(done, total)`` after every chunk (and once at the start).
    max_in_flight : int, optional
        Tasks submitted ahead of completion (default ``4 ×`` worker threads, at least 8).
    cancel : callable, optional
        Polled while the run waits (at least twice a second); when it returns true, queued
        tasks are cancelled, running ones stop at their next point or batch of periods,
        finished chunks are kept and the run returns with ``cancelled=True`` (no results file).
    on_chunk : callable, optional
        ``on_chunk(start, stop, records)`` after each chunk is stored.
    limits : PointLimits, optional
        Wall-time and step budget of every point (default ``PointLimits()``).

    Returns
    -------
    RunSummary
    """
    stop_now = cancel or (lambda: False)
    limits = limits or PointLimits()
    own_client = own_cluster = None
    nworkers = 1
    run = StudyRun(study, root, chunk_size=chunk_size, progress=progress, on_chunk=on_chunk)
    if run.reused:
        return run.collate(0)
    try:
        if not serial and run.pieces:
            if client is None:
                own_client, own_cluster = make_client(
                    scheduler, workers, method=study.solver.method
                )
                client = own_client
            nworkers = _nthreads(client)
            run.plan(nworkers)
        try:
            if serial or not run.pieces:
                run.run_serial(stop_now, limits)
                return run.collate(0 if serial else nworkers)
            if _is_local(client):
                simulate.warm_up(study.solver.method)  # fill numba's cache before the workers
            warm_up(client, study.solver.method)
            pool = ChunkPool(client, max_in_flight or max(8, 4 * nworkers), limits)
            pool.add(study.id, run)
            while not run.complete:
                if stop_now():
                    pool.remove(study.id)
                    raise Cancelled
                pool.step(0.5)
        except Cancelled:
            return run.cancelled_summary(0 if serial else nworkers)
        return run.collate(nworkers)
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()


def _summary(
    run: StudyRun,
    ds: Any,
    *,
    computed: int,
    workers: int,
    reused: bool = False,
    outcomes: Mapping[str, int] | Any = None,
) -> RunSummary:
    """The summary of a finished run; outcomes (names) from the records, else from the dataset
    (a reused results file stored without the ``response`` group has no ``outcome``: no
    counts)."""
    counts = summarize(ds, outcomes)
    found = {k: counts[k] for k in OUTCOMES if k in counts}
    return RunSummary(
        study_id=run.study.id,
        path=run.store.results_path,
        points=counts["points"],
        computed=computed,
        failed=counts["failed"],
        irregular=found.get("irregular", 0),
        unsettled=found.get("unsettled", 0),
        wall_s=time.perf_counter() - run.t0,
        kernel_s=run.kernel_s,
        workers=workers,
        chunk_size=0 if reused else run.chunk,
        reused=reused,
        outcomes=found,
    )
