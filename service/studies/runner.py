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

Workers never compile the same kernel twice: when numba's on-disk cache lacks the method's
kernels, this process compiles them while an embedded cluster's worker processes start, and
before they are asked to load any kernel, so the worker processes load that cache instead of
each compiling the same kernels in parallel; when the cache has them, each worker loads them as
it starts and this process loads none (:func:`make_client`). A task is
``service.studies.tasks.chunk_task``: a worker imports only the simulator to run it.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
import os
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from typing import Any

from service.studies import forkserver
from service.studies.adaptive_run import AdaptiveRun
from service.studies.chunks import MissingPoints, StudyStore, iter_chunk_ranges
from service.studies.dask_settings import user_set
from service.studies.dataset import open_results, results_from_records, summarize
from service.studies.fence import Backoff, Fence, FenceLost, is_transient
from service.studies.limits import DEFAULT_CHUNK_SIZE
from service.studies.points import (
    TASK_FAILED,
    PointStore,
    save_chunk,
    solver_document,
    study_keys,
)
from service.studies.schema import Study
from service.studies.summary import Cancelled, RunSummary
from service.studies.tasks import Points, chunk_task, compute_chunk
from service.studies.variables import OUTCOMES, outcome_names
from worker import cpu, simulate
from worker.simulate import (
    PointLimits,
    SolverSettings,
    failed_result,
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
    "make_run",
    "run_study",
    "warm_up",
]

log = logging.getLogger("impactcell.runner")

# Runs again of a study whose chunks were found damaged at collation (run_study).
_RERUNS = 2
# Points per task. Whatever its size, a task costs ~15 ms of CPU in dask (half in the command's
# process, half in the worker) and ~5.5 ms to store its chunk (benchmarks/task_overhead.py). At
# Figure 5's ~4 ms a point, 32 points a task added ~15 %; 96 (61 tasks instead of 182) made its
# run ~3 s shorter (benchmarks/run_command.py --chunk-size 32, 10 interleaved pairs); 192 no more.
TASK_RETRIES = 2
# Studies with at most this many points to compute keep their keys from the start to their
# chunks' submission (``StudyRun.keys``): Figure 5's made them twice, 0.09 s of 0.5 s storing.
_KEPT_KEYS = 200_000
CONNECT_TIMEOUT = "10s"  # an unreachable scheduler is an error within seconds, not minutes
# What an embedded cluster's servers (scheduler, nannies, workers) do on their event loops
# only for a dashboard, done less often or not at all (``_quiet_embedded_cluster``): a 2-core
# machine's cores are the bound, and these ran all the time, also on an idle service's cluster.
_EMBEDDED_CONFIG: dict[str, object] = {
    # the statistical profiler: every 10 ms a sample of each worker thread's stack
    "distributed.worker.profile.enabled": False,
    # the event-loop health check (a log line when a loop was blocked over 3 s): every 20 ms
    "distributed.admin.tick.interval": "1s",
    # memory (pause, spill, restart: limits a point never nears) and system statistics
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
}

Progress = Callable[[int, int], None]  # (points done, total points)
ChunkDone = Callable[[int, int, list[dict[str, Any]]], None]  # (start, stop, records)


def default_chunk_size(points: int, workers: int) -> int:
    """``DEFAULT_CHUNK_SIZE``, smaller for small studies so every worker gets several tasks."""
    return max(1, min(DEFAULT_CHUNK_SIZE, math.ceil(points / max(1, 4 * workers))))


def warm_up(client: Any, method: str = DEFAULT_METHOD) -> None:
    """Load a method's numba kernels in every worker before timing anything. Local workers
    share this process's numba cache: it is filled here first (if it is not), so no two
    workers compile the same kernel."""
    if _is_local(client):
        simulate.fill_cache(method)
    client.run(simulate.warm_up, method)


def _load_at_start(method: str | None) -> str:
    """The preload of a LocalCluster's workers (the text of a module, which dask runs in each
    worker as it starts, before it joins the cluster): load ``method``'s kernels from numba's
    cache, in every worker at once, while the cluster is still starting."""
    return (
        "from worker.simulate import warm_up\n\n\n"
        f"def dask_setup(worker):\n    warm_up({method!r})\n"
    )


def _is_local(client: Any) -> bool:
    """Whether the client's workers run on this machine (a LocalCluster: they share its
    numba cache)."""
    from dask.distributed import LocalCluster

    return isinstance(getattr(client, "cluster", None), LocalCluster)


def _worker_environ() -> None:
    """Make sure worker processes start with one BLAS thread (``worker.cpu``: another count sums
    in another order) before they import anything: dask's ``distributed.nanny.pre-spawn-environ``
    default already sets these; only missing ones are added."""
    import dask

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    missing = {k: 1 for k in cpu.THREAD_ENVS if k not in env}
    if missing:
        dask.config.set({"distributed.nanny.pre-spawn-environ": {**env, **missing}})


def _quiet_embedded_cluster() -> None:
    """Start an embedded cluster with ``_EMBEDDED_CONFIG``. A setting the user made stands:
    one whose environment variable is set (e.g. ``$DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED``)
    or whose value is not dask's shipped default (a dask config file).

    Measured on this 2-core machine: the workers' profiler cost them 1.1 s of CPU over Figure 5
    (``benchmarks/run_command.py``, 5 interleaved pairs: 7.3 → 6.2 s outside their task
    threads); with dask's default intervals an idle 2-worker cluster used 1.1 s of CPU every
    10 s (the command's process, which holds the scheduler and the nannies, 0.63 s; each worker
    0.25 s), 0.2 s with these."""
    import dask

    dask.config.set({k: v for k, v in _EMBEDDED_CONFIG.items() if not user_set(k)})


def make_client(
    scheduler: str | None, workers: int | None, *, method: str | None = DEFAULT_METHOD
) -> tuple[Any, Any]:
    """A dask client on ``scheduler`` if given, else on a new LocalCluster of ``workers``.

    The workers are forked from a process that has imported the simulator and loaded the
    default method's kernels (:mod:`service.studies.forkserver`), unless the user chose how
    dask starts them. When numba's on-disk cache holds ``method``'s kernels (``None``: every
    method's), each worker loads them as it starts if it has not (``_load_at_start``) and this
    process loads nothing. Else the worker processes start while the kernels are compiled
    here, and this returns once both are done, so the workers, which then load kernels only
    when asked (:func:`warm_up`, or their first point), find them in the cache.
    """
    from dask.distributed import Client, LocalCluster

    # Never dask's default client: xarray would then take a lock on the scheduler for every
    # NetCDF write of this process, and a results file written while the cluster shuts down
    # (run_study collates meanwhile) failed with "ConnectionPool is closed". Every call here
    # names its client.
    if scheduler:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        try:
            check_workers(client)
        except BaseException:
            client.close()
            raise
        return client, None
    _worker_environ()
    _quiet_embedded_cluster()
    forkserver.start()  # workers forked from a process that has loaded them (if not done yet)
    n = workers or os.cpu_count() or 1
    ready = simulate.cache_ready(method)
    with ThreadPoolExecutor(1, thread_name_prefix="impactcell-cluster-start") as pool:
        starting = pool.submit(
            LocalCluster,
            n_workers=n,
            threads_per_worker=1,  # the kernels hold the GIL: parallelism comes from processes
            processes=True,
            dashboard_address=":0",  # a free port: never clash with a running dask
            silence_logs=40,  # logging.ERROR
            preload=[_load_at_start(method)] if ready else [],
        )
        try:
            if not ready:
                simulate.warm_up(method)
            else:
                # While the cluster starts (its forked workers leave this core mostly idle):
                # xarray imports dask.array at the first variable it builds when dask is
                # installed (its duck-array check), which was 0.45-0.55 s of collating
                # Figure 5 at the run's end, when nothing else runs. (Without it, xarray's
                # check finds no dask arrays: nothing to import early.)
                with contextlib.suppress(ImportError):
                    import dask.array  # noqa: F401
            # The results file's writer (dataset.write_netcdf): a library that cannot be
            # imported then stops the run before any point is computed, not at its end. (Twice
            # in CI rehearsals the import at the end failed, "No module named 'certifi'", in an
            # environment where it is installed: not explained.)
            import netCDF4  # noqa: F401
        except BaseException:
            with contextlib.suppress(Exception):  # a cluster that failed too: nothing to close
                starting.result().close()
            raise
        cluster = starting.result()  # a cluster that cannot start raises here
    try:
        return Client(cluster, set_as_default=False), cluster
    except BaseException:
        cluster.close()
        raise


def check_workers(client: Any) -> None:
    """Refuse a cluster whose workers would compute other bits than this process (another CPU
    target or library stack: ``worker.cpu.fingerprint``), naming each worker and difference.
    Workers that join later are checked by every task they run (``tasks.chunk_task``)."""
    want = cpu.fingerprint()
    found = client.run(cpu.fingerprint)
    bad = [f"{addr}: {'; '.join(d)}" for addr, fp in sorted(found.items())
           if (d := cpu.differences(want, fp))]  # fmt: skip
    if bad:
        raise cpu.TargetMismatch(
            f"{len(bad)} of {len(found)} workers compute otherwise than this service "
            f"({'; '.join(bad)}); {cpu.REMEDY}"
        )


def _nthreads(client: Any) -> int:
    info = client.scheduler_info()
    return max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))


class StudyRun:
    """One study's side of a run: its store, the chunks still to compute and what came back.

    Made by :func:`run_study` and by the service's job manager; the chunks go to a
    :class:`ChunkPool` (or run serially). ``cached`` is true when the results file already
    exists and nothing is left to compute. Given a point store (``points``), points it knows
    are taken from it, not computed (``service.studies.points``).
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
        points: PointStore | None = None,
        fence: Fence | None = None,
    ) -> None:
        self.t0 = time.perf_counter()
        self.study = study
        self.store = StudyStore(root, study, fence=fence)
        self.points = points
        # A tagged study is a fresh run of its definition (the nightly suite's): it computes
        # every point itself (and stores what it computes).
        self.reuse = points is not None and study.tag is None
        self.solver = study.solver.settings().__dict__.copy()
        self._solver_doc = solver_document(self.solver)
        self.total = study.size
        self.progress = progress
        self.on_chunk = on_chunk
        self.kernel_s = 0.0
        self.in_flight = 0
        self.shared = 0  # points of its chunks another run's task computed (ChunkPool)
        self.shared_pool = False  # another run was in its pool at the same time (ChunkPool)
        self.submitted = 0  # chunks handed to a pool (its fairness: fewer goes first)
        # Keys of the points to compute, made once at the start (``_take_known``) and asked
        # again as their chunks go out (``keys``); kept for studies of up to _KEPT_KEYS points
        # still to compute (~90 bytes a key).
        self._kept_keys: dict[int, str] = {}
        # A results file that fails its check is set aside here, and rebuilt by this run.
        self.cached = self.store.results_status() == "ok" and not self.store.has_retry_chunks()
        missing: list[tuple[int, int]] = []
        if not self.cached:
            self.store.prepare()
            missing = self.store.missing_ranges()
            if self.reuse:
                missing = self._take_known(missing)
        self.n_missing = sum(b - a for a, b in missing)
        self.done = self.total - self.n_missing
        self._missing = missing
        self._chunk_size = chunk_size
        self.chunk = 0
        self.pieces: deque[tuple[int, int]] = deque()
        self.plan(workers)
        if progress and not self.cached:
            progress(self.done, self.total)

    def points_of(self, start: int, stop: int) -> list[dict[str, Any]]:
        """The points ``start:stop`` in work order (what a task computes)."""
        return self.study.points(start, stop)

    def coords_of(self, start: int, stop: int) -> dict[str, Any]:
        """Axis values of the points ``start:stop`` (failed points' coordinates)."""
        return self.study.coords_at(start, stop)

    def keys(self, start: int, stop: int) -> list[str]:
        """Point keys of ``start:stop`` (work order; a sweep's: whole lines)."""
        kept = self._kept_keys
        if kept and start in kept and stop - 1 in kept:
            try:
                return [kept[i] for i in range(start, stop)]
            except KeyError:  # a gap (points the store had): made anew
                pass
        return study_keys(self.study, start, stop, solver=self._solver_doc)

    def _take_known(self, missing: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """Take the points the point store knows into the study's chunks (and link them to
        the study); the ranges still to compute. A sweep takes only whole known lines (a
        line's later points start from its earlier ones' states, which are not stored)."""
        assert self.points is not None
        block = self.study.line_length * max(1, 2048 // self.study.line_length) if self.lines \
            else 2048  # fmt: skip
        out: list[tuple[int, int]] = []
        keep = sum(b - a for a, b in missing) <= _KEPT_KEYS
        for a, b in missing:
            for s in range(a, b, block):
                if self.store.fence is not None:  # a huge grid takes minutes: stop once not ours
                    self.store.fence.check()
                e = min(s + block, b)
                keys = self.keys(s, e)
                known = self.points.lookup(keys)
                have = [k in known for k in keys]
                if self.lines:
                    n = self.study.line_length
                    for i in range(0, e - s, n):
                        whole = all(have[i : i + n])
                        have[i : i + n] = [whole] * n
                if keep:  # those of the points to compute, for their chunks (``keys``)
                    self._kept_keys.update((s + i, k) for i, k in enumerate(keys) if not have[i])
                self.points.link(self.study.id, [(s + i, k) for i, k in enumerate(keys) if have[i]])
                i = 0
                while i < e - s:
                    j = i
                    while j < e - s and have[j] == have[i]:
                        j += 1
                    if have[i]:
                        self.store.write_chunk(s + i, s + j, [known[k] for k in keys[i:j]])
                    elif out and out[-1][1] == s + i:
                        out[-1] = (out[-1][0], s + j)
                    else:
                        out.append((s + i, s + j))
                    i = j
        return out

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

    def finished(
        self,
        start: int,
        stop: int,
        records: list[dict[str, Any]],
        retry: bool,
        keys: list[str] | None = None,
    ) -> None:
        """Store a chunk's records (``retry``: failed tasks, for a later run to try again):
        its points into the point store (those that are the point's own result) and linked to
        the study, then its chunk file."""
        if self.points is not None and not retry:
            keys = keys or self.keys(start, stop)
            pts = self.study.points(start, stop)
            if self.lines:  # a sweep point starts from the one before it in its line
                n = self.study.line_length
                for i, p in enumerate(pts):
                    if (start + i) % n:
                        p["_after"] = keys[i - 1]
            save_chunk(self.points, self.study.id, self._solver_doc, start, keys, pts, records)
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
            records = compute_chunk(
                self.study.points(start, stop), self.solver, budget, cancel, self.lines
            )
            if len(records) < stop - start:  # cancelled inside the chunk
                raise Cancelled
            self.finished(start, stop, records, False)

    def collate(self, workers: int) -> RunSummary:
        """Collate the stored chunks into the results file (or reuse it) and summarise."""
        if self.cached:
            ds = open_results(self.store.results_path)
            return _summary(self, ds, computed=0, workers=0, cached=True)
        cols = self.store.collect()
        ds = results_from_records(self.study, cols)
        self.store.write_results(ds)
        if not self.store.has_retry_chunks():  # keep task failures around for the next run
            self.store.remove_chunks()
        return _summary(
            self, ds, computed=self.n_missing - self.shared, workers=workers,
            outcomes=outcome_names(cols["outcome"]),
        )  # fmt: skip

    def cancelled_summary(self, workers: int) -> RunSummary:
        """The summary of a run stopped on request: finished chunks kept, no results file."""
        computed = self.done - (self.total - self.n_missing) - self.shared
        return RunSummary(
            study_id=self.study.id, path=self.store.results_path, points=self.total,
            computed=computed, reused=self.done - computed, failed=0, irregular=0,
            unsettled=0, wall_s=time.perf_counter() - self.t0, kernel_s=self.kernel_s,
            workers=workers, chunk_size=self.chunk, cancelled=True,
        )  # fmt: skip


def make_run(
    study: Study, root: str | os.PathLike[str] | None, **kwargs: Any
) -> StudyRun | AdaptiveRun:
    """The run of a study: an :class:`AdaptiveRun` for an adaptive study, else a
    :class:`StudyRun` (same keyword arguments)."""
    if study.is_adaptive:
        return AdaptiveRun(study, root, **kwargs)
    return StudyRun(study, root, **kwargs)


@dataclass(eq=False)
class _Piece:
    """One chunk of a run on its way: its records fill in from its own task, from tasks of
    other runs that compute the same points, or from the point store."""

    run: str  # the run's key in the pool
    start: int
    stop: int
    keys: list[str] | None  # point keys (None: the run has no point store)
    records: list[dict[str, Any] | None]
    left: int  # records still missing
    retry: bool = False  # some record is a task failure
    shared: int = 0  # records not computed by its own task (the store's, another run's task)
    dead: bool = False  # dropped (its run removed, or a point it waited for was not delivered)


class ChunkPool:
    """A bounded window of chunk tasks on a dask cluster, filled round-robin over studies.

    ``add`` a :class:`StudyRun` under a key; ``step`` submits until the window is full (one
    chunk per study in turn, so a small study is never stuck behind a large one), waits up to
    ``timeout`` for tasks to finish and hands their records to their runs; ``remove`` drops a
    study: its queued tasks are cancelled and its running tasks stop at their next poll.

    Runs with a point store compute each point once: a point the store has gained since the
    run started is taken from it, and a point another run's task is computing now is not
    submitted again; that task's record is handed to both (a claim per point key). A sweep line
    waits only when every point of it is being computed already (its points depend on each
    other); otherwise it is computed whole.

    Storing a chunk may fail. Without ``hold``, the error is raised (the command line's run
    ends). With ``hold`` (the service), a chunk that cannot be stored for a passing reason
    (:func:`~service.studies.fence.is_transient`: the database or the disk) is kept in memory
    and stored again with backoff (at most ``backoff_cap`` s apart), its run takes no new
    chunks meanwhile and ``stalls`` names the error; a run whose fence is lost, or whose chunk
    failed otherwise, is listed in ``broken`` (the caller drops or fails it).
    """

    def __init__(
        self,
        client: Any,
        window: int,
        limits: PointLimits | None = None,
        *,
        hold: bool = False,
        backoff_cap: float = 30.0,
    ) -> None:
        self.client = client
        self.hold = hold
        self.backoff_cap = backoff_cap
        #: run key → the error its chunks' storing fails with now (they are kept and retried)
        self.stalls: dict[str, BaseException] = {}
        #: run key → why it cannot go on here (``FenceLost``, or a chunk it could not store)
        self.broken: dict[str, BaseException] = {}
        self._unsaved: dict[str, deque[tuple[_Piece, list[dict[str, Any]]]]] = {}
        self._backoff: dict[str, Backoff] = {}
        self.window = window
        self.limits = asdict(limits or PointLimits())
        self.runs: dict[str, StudyRun] = {}
        self._order: deque[str] = deque()  # round-robin order of the runs with chunks left
        self._futures: dict[Any, tuple[_Piece, list[int]]] = {}  # future → (piece, positions)
        # point key → [(piece, position)]: the first computes it, the rest wait for its record
        self._claims: dict[str, list[tuple[_Piece, int]]] = {}
        self._events: dict[str, str] = {}  # run key → name of its cancel event
        self._tag = uuid.uuid4().hex[:8]  # a resumed run must not reuse keys of a cancelled one
        self.target = cpu.fingerprint()  # every task's worker must compute the same bits
        self._count = itertools.count()
        # Set by every task's completion (distributed.wait would need dask's default client,
        # which make_client's never is).
        self._wake = threading.Event()

    def add(self, key: str, run: StudyRun) -> None:
        """Take a study's remaining chunks into the rotation."""
        self.runs[key] = run
        self._events[key] = f"impactcell-cancel-{key}-{self._tag}-{next(self._count)}"
        self._order.append(key)
        if len(self.runs) > 1:  # from now on each may find points the others stored
            for r in self.runs.values():
                r.shared_pool = True

    def remove(self, key: str) -> StudyRun | None:
        """Drop a study: queued tasks cancelled, running ones told to stop; its run returned.
        Another study's chunks that waited for points of its tasks are queued again."""
        run = self.runs.pop(key, None)
        if key in self._order:
            self._order.remove(key)
        for d in (self._unsaved, self._backoff, self.stalls, self.broken):
            d.pop(key, None)
        mine = [f for f, (p, _) in self._futures.items() if p.run == key]
        for f in mine:
            piece, positions = self._futures.pop(f)
            self._undelivered(piece, positions)
        for k, claims in list(self._claims.items()):
            if claims[0][0].run == key:  # no task of it will deliver: the waiters go again
                del self._claims[k]
                for p, _ in claims[1:]:
                    if p.run != key:
                        self._requeue(p)
            for p, _ in claims:
                if p.run == key:
                    p.dead = True
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

    # ------------------------------------------------------------------ submission

    def _fill(self) -> None:
        while len(self._futures) < self.window and self._order:
            # A run whose chunks wait to be stored, or that cannot go on, takes no new ones.
            key = next((k for k in self._order if k not in self._unsaved
                        and k not in self.broken), None)  # fmt: skip
            if key is None:
                return
            self._order.remove(key)
            run = self.runs[key]
            if not run.pieces:
                continue  # out of the rotation until removed or complete
            start, stop = run.pieces.popleft()
            if run.pieces:
                self._order.append(key)
            self._launch(key, run, start, stop)

    def _launch(self, key: str, run: StudyRun, start: int, stop: int) -> None:
        n = stop - start
        keys = run.keys(start, stop) if run.points is not None else None
        piece = _Piece(key, start, stop, keys, [None] * n, n)
        run.in_flight += 1
        compute = list(range(n))
        if keys is not None and run.reuse:
            assert run.points is not None
            # The store may have gained points since the run started: another study's in
            # this pool (a look-up per chunk only then; alone, its start-up look-up saw all).
            known = (
                run.points.lookup([k for k in keys if k not in self._claims])
                if run.shared_pool
                else {}
            )
            if run.lines:
                if all(k in known for k in keys):
                    compute = []
                    piece.shared = n
                    for i, k in enumerate(keys):
                        self._fill_record(piece, i, known[k])
                elif all(k in self._claims for k in keys):
                    compute = []  # the same line is on its way for another study
                    piece.shared = n
                    for i, k in enumerate(keys):
                        self._claims[k].append((piece, i))
                else:
                    for i, k in enumerate(keys):
                        self._claims.setdefault(k, [(piece, i)])
            else:
                compute = []
                piece.shared = n
                for i, k in enumerate(keys):
                    if k in known:
                        self._fill_record(piece, i, known[k])
                    elif k in self._claims:
                        self._claims[k].append((piece, i))
                    else:
                        piece.shared -= 1
                        self._claims[k] = [(piece, i)]
                        compute.append(i)
        if compute:
            pts = run.points_of(start, stop)
            fut = self.client.submit(
                chunk_task,
                Points([pts[i] for i in compute]),
                run.solver,
                self.limits,
                self._events[key],
                run.lines,
                self.target,
                key=f"impactcell-{run.study.id}-{start}-{stop}-{self._tag}",
                retries=TASK_RETRIES,
                pure=False,
                # The scheduler runs higher priorities first: a study's n-th chunk waits behind
                # every other study's earlier chunks, so a new small study starts at once.
                priority=-run.submitted,
            )
            fut.add_done_callback(lambda _: self._wake.set())
            self._futures[fut] = (piece, compute)
            run.submitted += 1
        if piece.left == 0:
            self._complete(piece)

    # ------------------------------------------------------------------ delivery

    def _fill_record(self, piece: _Piece, pos: int, record: dict[str, Any]) -> None:
        if piece.dead or piece.records[pos] is not None:
            return
        piece.records[pos] = record
        piece.left -= 1
        if str(record.get("reason") or "").startswith(TASK_FAILED):
            piece.retry = True
        if piece.left == 0:
            self._complete(piece)

    def _complete(self, piece: _Piece) -> None:
        run = self.runs.get(piece.run)
        if run is None or piece.dead:
            return
        piece.dead = True  # delivered: nothing more goes to it
        records = [dict(r) for r in piece.records if r is not None]
        # Stored in the order they completed: behind any that wait for a retry.
        self._unsaved.setdefault(piece.run, deque()).append((piece, records))
        backoff = self._backoff.get(piece.run)
        if backoff is None or backoff.due():
            self._flush(piece.run)

    def _flush(self, key: str) -> None:
        """Store the chunks of run ``key`` that wait to be, oldest first, until one fails."""
        waiting = self._unsaved.get(key)
        run = self.runs.get(key)
        while waiting and run is not None and key not in self.broken:
            piece, records = waiting[0]
            try:
                run.finished(piece.start, piece.stop, records, piece.retry, piece.keys)
            except Exception as exc:  # noqa: BLE001 - kept, retried, or the run is broken
                if not self.hold:
                    waiting.popleft()
                    raise
                if isinstance(exc, FenceLost) or not is_transient(exc):
                    self.broken[key] = exc
                    return
                self.stalls[key] = exc
                self._backoff.setdefault(key, Backoff(cap=self.backoff_cap)).failed()
                return
            waiting.popleft()
            run.in_flight -= 1
            run.shared += piece.shared
            if key in self._backoff:
                self._backoff[key].ok()
            self.stalls.pop(key, None)
        if not waiting:
            self._unsaved.pop(key, None)
            if run is not None and run.pieces and key not in self._order:
                self._order.append(key)  # an adaptive run asked for more, or a stall ended

    def retry_now(self, key: str) -> None:
        """Store run ``key``'s waiting chunks at the next step, not after its backoff (the
        caller has seen the resource come back)."""
        if key in self._backoff:
            self._backoff[key].next_at = 0.0

    def _retry_unsaved(self) -> float | None:
        """Store again the chunks whose retry is due; seconds until the next retry (if any)."""
        nxt: float | None = None
        for key in list(self._unsaved):
            b = self._backoff.get(key)
            if b is None or b.due():
                self._flush(key)
            b = self._backoff.get(key)
            if key in self._unsaved and key not in self.broken and b is not None:
                left = max(0.0, b.next_at - b.clock())
                nxt = left if nxt is None else min(nxt, left)
        return nxt

    def _deliver(self, piece: _Piece, positions: list[int], records: list[dict[str, Any]]) -> None:
        """Records of ``positions`` of ``piece`` (its task's), to it and to their waiters."""
        for pos, rec in zip(positions, records, strict=False):
            waiters: list[tuple[_Piece, int]] = []
            if piece.keys is not None:
                # The claim goes first: storing a completed chunk may fail, and a claim left
                # behind would hold every later chunk of the same points for ever.
                claims = self._claims.get(piece.keys[pos])
                if claims and claims[0] == (piece, pos):
                    del self._claims[piece.keys[pos]]
                    waiters = claims[1:]
            self._fill_record(piece, pos, rec)
            for other, opos in waiters:
                self._fill_record(other, opos, rec)
        if len(records) < len(positions):
            self._undelivered(piece, positions[len(records) :])

    def _requeue(self, piece: _Piece) -> None:
        """Queue a piece's range again (its run recomputes it, or finds it in the store)."""
        if piece.dead:
            return
        piece.dead = True
        run = self.runs.get(piece.run)
        if run is None:
            return
        run.in_flight -= 1
        run.pieces.appendleft((piece.start, piece.stop))
        if piece.run not in self._order:
            self._order.append(piece.run)

    def _undelivered(self, piece: _Piece, positions: list[int]) -> None:
        """A task stopped before these positions (cancelled, or its run removed): the piece,
        and every piece that waited for one of them, is queued again."""
        self._requeue(piece)
        if piece.keys is None:
            return
        for pos in positions:
            claims = self._claims.get(piece.keys[pos])
            if claims and claims[0] == (piece, pos):
                del self._claims[piece.keys[pos]]
                for other, _ in claims[1:]:
                    self._requeue(other)

    def step(self, timeout: float) -> list[str]:
        """Fill the window, wait up to ``timeout`` s, store what finished; keys of the runs
        that are now complete. Never returns at once with nothing done, so that a caller's
        loop does not spin."""
        retry_in = self._retry_unsaved()
        wait = timeout if retry_in is None else min(timeout, max(retry_in, 0.01))
        self._fill()
        if not self._futures:
            ready = [k for k, r in self.runs.items() if r.complete and k not in self.broken]
            if not ready:
                self._wake.wait(wait)
                self._wake.clear()
            return ready
        if not any(f.done() for f in self._futures):
            self._wake.wait(wait)
        # A completion after this clear sets it again; one before is in the scan below (and
        # the next step's check above).
        self._wake.clear()
        done = [f for f in self._futures if f.done()]
        for fut in done:
            if fut not in self._futures:
                continue
            piece, positions = self._futures.pop(fut)
            run = self.runs[piece.run]
            # Not ``fut.status``: a finished future whose worker died before we fetched the
            # result is "lost" until dask has computed it again, and ``result()`` waits for it.
            try:
                records = fut.result()
            except Exception as exc:  # noqa: BLE001 - whatever the task raised, or KilledWorker
                # Failed even after its retries (or its workers kept dying): record the points
                # as failed with the reason, and mark the chunk so a rerun tries them again.
                reason = f"{TASK_FAILED}{TASK_RETRIES} retries: {type(exc).__name__}: {exc}"
                rec = failed_result(SolverSettings(**run.solver), reason)
                records = [dict(rec) for _ in positions]
            # Fewer records than points: stopped by a cancel, recomputed on resume.
            self._deliver(piece, positions, records)
            fut.release()
        self._fill()
        return [k for k, r in self.runs.items() if r.complete and k not in self.broken]


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
    points: PointStore | None = None,
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
    points : PointStore, optional
        The point store: points it knows are not computed, computed ones are added to it.

    Returns
    -------
    RunSummary

    Chunk files found damaged at collation (set aside: ``service.studies.chunks``) are
    computed again by another run, up to twice.
    """
    kwargs = dict(scheduler=scheduler, workers=workers, chunk_size=chunk_size, client=client,
                  serial=serial, progress=progress, max_in_flight=max_in_flight, cancel=cancel,
                  on_chunk=on_chunk, limits=limits, points=points)  # fmt: skip
    for again in range(_RERUNS, -1, -1):
        try:
            return _run_once(study, root, **kwargs)
        except MissingPoints as exc:
            if not again:
                raise
            log.warning("study %s: %s at collation (damaged chunks set aside); running it "
                        "again", study.id, exc)  # fmt: skip
    raise AssertionError("unreachable")


def _run_once(
    study: Study,
    root: str | os.PathLike[str] | None,
    *,
    scheduler: str | None,
    workers: int | None,
    chunk_size: int | None,
    client: Any,
    serial: bool,
    progress: Progress | None,
    max_in_flight: int | None,
    cancel: Callable[[], bool] | None,
    on_chunk: ChunkDone | None,
    limits: PointLimits | None,
    points: PointStore | None,
) -> RunSummary:
    """One run of :func:`run_study`."""
    stop_now = cancel or (lambda: False)
    limits = limits or PointLimits()
    own_client = own_cluster = None
    closing: threading.Thread | None = None
    nworkers = 1
    run = make_run(
        study, root, chunk_size=chunk_size, progress=progress, on_chunk=on_chunk, points=points
    )
    if run.cached:
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
        if own_client is not None:
            # Every chunk is stored and nothing runs on the cluster any more: it shuts down
            # (~1 s, mostly waiting for the worker processes to exit) while this process collates.
            closing = threading.Thread(
                target=_close, args=(own_client, own_cluster), name="impactcell-close"
            )
            closing.start()
        return run.collate(nworkers)
    finally:
        if closing is not None:
            closing.join()
        else:
            _close(own_client, own_cluster)


def _close(client: Any, cluster: Any) -> None:
    """Close a client and the cluster it was started with (either may be ``None``)."""
    if client is not None:
        client.close()
    if cluster is not None:
        cluster.close()


def _summary(
    run: StudyRun,
    ds: Any,
    *,
    computed: int,
    workers: int,
    cached: bool = False,
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
        reused=counts["points"] - computed,
        failed=counts["failed"],
        irregular=found.get("irregular", 0),
        unsettled=found.get("unsettled", 0),
        wall_s=time.perf_counter() - run.t0,
        kernel_s=run.kernel_s,
        workers=workers,
        chunk_size=0 if cached else run.chunk,
        cached=cached,
        outcomes=found,
    )
