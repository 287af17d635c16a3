"""Run a study on dask.distributed: chunking, submission with retries, progress, resume.

The runner owns the dask client. By default it starts an embedded ``LocalCluster`` (one
single-threaded worker process per core); given a scheduler address (``Settings.scheduler``:
``--scheduler`` or ``IMPACTCELL_SCHEDULER``) it uses that cluster instead. Points go out in
chunks of consecutive grid points (one ``worker.simulate.simulate_chunk`` call per task); each
finished chunk is written to the store as soon as it arrives, so a rerun after a crash computes
only what is missing. Results do not depend on the chunk size: each point is computed on its own.

Workers never compile the same kernel twice: before an embedded cluster starts (and before the
workers warm up) this process compiles the method's numba kernels, or loads them from numba's
on-disk cache, so the worker processes load that cache instead of each compiling the same
kernels in parallel.
"""

from __future__ import annotations

import math
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.studies.chunks import StudyStore, iter_chunk_ranges
from service.studies.dataset import open_results, results_from_records, summarize
from service.studies.schema import Study
from service.studies.variables import OUTCOMES, outcome_names
from worker import simulate
from worker.simulate import failed_result, simulate_chunk
from worker.solvers.settings import DEFAULT_METHOD

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "Cancelled",
    "RunSummary",
    "default_chunk_size",
    "make_client",
    "run_study",
    "warm_up",
]

DEFAULT_CHUNK_SIZE = 32  # points per task: ~0.1–0.6 s at 2–20 ms a point, ≫ dask's ~1 ms
TASK_RETRIES = 2
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
        return Client(scheduler, timeout="30s"), None
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
        Points per task (default :func:`default_chunk_size`).
    client : distributed.Client, optional
        Use this client (not closed here); overrides ``scheduler``/``workers``.
    serial : bool
        Run in this process without dask (reference runs, debugging).
    progress : callable, optional
        ``progress(done, total)`` after every chunk (and once at the start).
    max_in_flight : int, optional
        Tasks submitted ahead of completion (default ``4 ×`` worker threads, at least 8).
    cancel : callable, optional
        Polled between chunks; when it returns true, queued tasks are cancelled, finished
        chunks are kept and the run returns with ``cancelled=True`` (no results file).
    on_chunk : callable, optional
        ``on_chunk(start, stop, records)`` after each chunk is stored.

    Returns
    -------
    RunSummary
    """
    t0 = time.perf_counter()
    store = StudyStore(root, study)
    total = study.size
    if store.results_path.exists() and not store.has_retry_chunks():
        ds = open_results(store.results_path)
        return _summary(
            study, store, ds, t0, computed=0, kernel_s=0.0, workers=0, chunk=0, reused=True
        )
    store.prepare()
    missing = store.missing_ranges()
    n_missing = sum(b - a for a, b in missing)
    done = total - n_missing
    if progress:
        progress(done, total)
    solver = study.solver.settings().__dict__.copy()
    kernel_s = 0.0
    own_client = own_cluster = None
    nworkers = 1
    try:
        if n_missing and not serial:
            method = study.solver.method
            if client is None:
                own_client, own_cluster = make_client(scheduler, workers, method=method)
                client = own_client
            elif _is_local(client):
                simulate.warm_up(method)  # fill numba's cache before the workers look in it
            warm_up(client, method)
            nworkers = _nthreads(client)
        chunk = default_chunk_size(n_missing, nworkers) if chunk_size is None else chunk_size
        pieces = iter_chunk_ranges(missing, chunk)  # refuses a chunk size below 1

        def finished(start: int, stop: int, records: list[dict[str, Any]], retry: bool) -> None:
            nonlocal done, kernel_s
            store.write_chunk(start, stop, records, retry=retry)
            kernel_s += sum(r["wall_s"] for r in records)
            done += stop - start
            if on_chunk:
                on_chunk(start, stop, records)
            if progress:
                progress(done, total)

        stop_now = cancel or (lambda: False)
        try:
            if serial or not pieces:
                for start, stop in pieces:
                    if stop_now():
                        raise Cancelled
                    records = simulate_chunk(study.points(start, stop), solver)
                    finished(start, stop, records, False)
            else:
                window = max_in_flight or max(8, 4 * nworkers)
                _run_distributed(client, study, solver, pieces, finished, window, stop_now)
        except Cancelled:
            return RunSummary(
                study_id=study.id, path=store.results_path, points=total,
                computed=done - (total - n_missing), failed=0, irregular=0, unsettled=0,
                wall_s=time.perf_counter() - t0, kernel_s=kernel_s,
                workers=0 if serial else nworkers, chunk_size=chunk, cancelled=True,
            )  # fmt: skip
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()

    cols = store.collect()
    ds = results_from_records(study, cols)
    store.write_results(ds)
    if not store.has_retry_chunks():  # keep task failures around for the next run to retry
        store.remove_chunks()
    return _summary(
        study,
        store,
        ds,
        t0,
        computed=n_missing,
        kernel_s=kernel_s,
        workers=0 if serial else nworkers,
        chunk=chunk,
        outcomes=outcome_names(cols["outcome"]),
    )


def _run_distributed(
    client: Any,
    study: Study,
    solver: dict[str, Any],
    pieces: list[tuple[int, int]],
    finished: Callable[[int, int, list[dict[str, Any]], bool], None],
    max_in_flight: int,
    stop_now: Callable[[], bool],
) -> None:
    from dask.distributed import as_completed

    todo = iter(pieces)
    ranges: dict[str, tuple[int, int]] = {}
    run = uuid.uuid4().hex[:8]  # a resumed run must not reuse keys of a cancelled one

    def submit() -> Any:
        try:
            start, stop = next(todo)
        except StopIteration:
            return None
        fut = client.submit(
            simulate_chunk,
            study.points(start, stop),
            solver,
            key=f"impactcell-{study.id}-{start}-{stop}-{run}",
            retries=TASK_RETRIES,
            pure=False,
        )
        ranges[fut.key] = (start, stop)
        return fut

    # A bounded window of tasks keeps memory flat however large the study is.
    initial = [f for f in (submit() for _ in range(max_in_flight)) if f is not None]
    queue = as_completed(initial, with_results=False, timeout=None)
    pending = {f.key: f for f in initial}
    for fut in queue:
        pending.pop(fut.key, None)
        start, stop = ranges.pop(fut.key)
        # Not ``fut.status``: a finished future whose worker died before we fetched the result
        # is "lost" until dask has computed it again, and ``result()`` waits for that.
        try:
            records = fut.result()
        except Exception as exc:  # noqa: BLE001 - whatever the task raised, or KilledWorker
            # The task failed even after its retries (or its workers kept dying): record the
            # points as failed with the reason, and mark the chunk so a rerun tries them again.
            reason = f"task failed after {TASK_RETRIES} retries: {type(exc).__name__}: {exc}"
            from worker.simulate import SolverSettings

            rec = failed_result(SolverSettings(**solver), reason)
            finished(start, stop, [dict(rec) for _ in range(stop - start)], True)
        else:
            finished(start, stop, records, False)
        fut.release()
        if stop_now():
            # Finished chunks are stored; queued tasks are dropped (running ones end unused).
            client.cancel(list(pending.values()), force=False)
            raise Cancelled
        nxt = submit()
        if nxt is not None:
            pending[nxt.key] = nxt
            queue.add(nxt)


def _summary(
    study: Study,
    store: StudyStore,
    ds: Any,
    t0: float,
    *,
    computed: int,
    kernel_s: float,
    workers: int,
    chunk: int,
    reused: bool = False,
    outcomes: Any = None,
) -> RunSummary:
    """The summary of a finished run; outcomes (names) from the records, else from the dataset
    (a reused results file stored without the ``response`` group has no ``outcome``: no
    counts)."""
    counts = summarize(ds, outcomes)
    outcomes = {k: counts[k] for k in OUTCOMES if k in counts}
    return RunSummary(
        study_id=study.id,
        path=store.results_path,
        points=counts["points"],
        computed=computed,
        failed=counts["failed"],
        irregular=outcomes.get("irregular", 0),
        unsettled=outcomes.get("unsettled", 0),
        wall_s=time.perf_counter() - t0,
        kernel_s=kernel_s,
        workers=workers,
        chunk_size=chunk,
        reused=reused,
        outcomes=outcomes,
    )
