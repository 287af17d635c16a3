"""The docker-compose topology with real processes on 127.0.0.1: ``dask scheduler``, two
``dask worker`` processes (a nanny and its worker child each) and ``impactcell serve
--scheduler``, talked to over HTTP with :class:`service.client.Client`.

Every process runs in its own session (process group) with its log in ``tmp_path``; finalizers
kill the groups whatever happens, and the log tails are printed with a failing test's output.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import xarray as xr

from service.api.server import free_port
from service.client import Client
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from tests.service.helpers import comparable, tiny_study
from worker import cpu

# scheduler, workers and the API as separate processes: the slow tier
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
WORKERS = 2
START_TIMEOUT = 60.0  # a loaded 2-core machine imports dask and numba slowly


class Proc:
    """A subprocess in its own process group (``dask worker`` forks a worker under its nanny)."""

    def __init__(
        self, name: str, argv: list[str], logdir: Path, env: dict[str, str] | None = None
    ) -> None:
        self.name = name
        self.logpath = logdir / f"{name}.log"
        self._log = open(self.logpath, "wb")  # noqa: SIM115 - closed in stop()
        env = {**_clean_env(), "PYTHONUNBUFFERED": "1", **(env or {})}
        self.proc = subprocess.Popen(
            argv, cwd=ROOT, env=env, stdout=self._log, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL, start_new_session=True,
        )  # fmt: skip

    @property
    def pgid(self) -> int:
        return self.proc.pid  # start_new_session: the leader's pid is the group id

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self, sig: int = signal.SIGKILL, wait: float = 10.0) -> None:
        """Signal the whole group and reap the leader (SIGKILL if it outlives ``wait``)."""
        _killpg(self.pgid, sig)
        try:
            self.proc.wait(wait)
        except subprocess.TimeoutExpired:
            _killpg(self.pgid, signal.SIGKILL)
            self.proc.wait()
        _killpg(self.pgid, signal.SIGKILL)  # orphans of the group (a nanny's worker) go too

    def stop(self) -> None:
        self.kill(signal.SIGTERM, wait=10.0)
        self._log.close()

    def tail(self, chars: int = 2500) -> str:
        self._log.flush()
        text = self.logpath.read_text(errors="replace")
        return f"----- {self.name} (exit {self.proc.poll()}) -----\n{text[-chars:]}"


def _wait(what: str, ready: Callable[[], bool], procs: list[Proc], timeout: float) -> None:
    t0 = time.monotonic()
    while not ready():
        dead = [p for p in procs if not p.alive()]
        if dead or time.monotonic() - t0 > timeout:
            why = f"{dead[0].name} exited" if dead else f"not within {timeout:g} s"
            raise RuntimeError(f"{what}: {why}\n" + "\n".join(p.tail() for p in procs))
        time.sleep(0.1)


class Topology:
    """scheduler + workers + api, as in docker-compose.yml."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[Proc] = []
        self.workers: list[Proc] = []
        self.dask: Any = None
        self._n = 0

    def start(self) -> Topology:
        """Scheduler, then workers, then the api, each waited for; ``close()`` on failure too."""
        py, tmp = sys.executable, self.tmp
        self.sched_port = free_port()
        self.scheduler = f"tcp://127.0.0.1:{self.sched_port}"
        self.sched = self._start(
            "scheduler",
            [py, "-m", "dask", "scheduler", "--host", "127.0.0.1",
             "--port", str(self.sched_port), "--dashboard-address", ":0"],
        )  # fmt: skip
        _wait("dask scheduler", self._port_open, [self.sched], START_TIMEOUT)
        from dask.distributed import Client as DaskClient

        self.dask = DaskClient(self.scheduler, timeout="30s")
        for _ in range(WORKERS):
            self.add_worker()
        self.wait_workers()
        self.api_port = free_port()
        self.url = f"http://127.0.0.1:{self.api_port}"
        self.data = tmp / "data"
        self.api = self._start(
            "api",
            [py, "-m", "service.cli", "serve", "--host", "127.0.0.1",
             "--port", str(self.api_port), "--data-dir", str(self.data),
             "--scheduler", self.scheduler, "--log-level", "warning"],
        )  # fmt: skip
        _wait("impactcell serve", self._healthy, [self.api], START_TIMEOUT)
        return self

    def _start(self, name: str, argv: list[str]) -> Proc:
        p = Proc(name, argv, self.tmp)
        self.procs.append(p)
        return p

    def _port_open(self) -> bool:
        import socket

        with socket.socket() as s:
            s.settimeout(0.5)
            return s.connect_ex(("127.0.0.1", self.sched_port)) == 0

    def _healthy(self) -> bool:
        try:
            return httpx.get(f"{self.url}/health", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    def add_worker(self) -> Proc:
        self._n += 1
        w = self._start(
            f"worker{self._n}",
            [sys.executable, "-m", "dask", "worker", self.scheduler, "--nthreads", "1",
             "--nworkers", "1", "--no-dashboard", "--local-directory",
             str(self.tmp / f"worker{self._n}-space"), "--preload-nanny", "worker"],
        )  # fmt: skip
        self.workers.append(w)
        return w

    def worker_pids(self) -> dict[str, int]:
        """Worker address -> pid of the worker process, as the scheduler sees them."""
        return self.dask.run_on_scheduler(
            lambda dask_scheduler: {a: ws.pid for a, ws in dask_scheduler.workers.items()}
        )

    def wait_workers(self) -> None:
        """Until the scheduler has exactly ``WORKERS`` workers, all of them live processes."""
        self.workers = [w for w in self.workers if w.alive()]
        for _ in range(WORKERS - len(self.workers)):
            self.add_worker()

        def ready() -> bool:
            groups = {w.pgid for w in self.workers}
            pids = self.worker_pids().values()
            return len(pids) == WORKERS and all(_pgid(p) in groups for p in pids)

        _wait("dask workers", ready, [self.sched, *self.workers], START_TIMEOUT)

    def worker_of(self, address: str) -> Proc:
        pgid = _pgid(self.worker_pids()[address])
        return next(w for w in self.workers if w.pgid == pgid)

    def tails(self) -> str:
        return "\n".join(p.tail() for p in self.procs)

    def close(self) -> None:
        if self.dask is not None:
            with contextlib.suppress(Exception):  # tearing down anyway
                self.dask.close(timeout=10)
        for p in reversed(self.procs):  # the api first: it holds a client of the scheduler
            p.stop()


def _clean_env() -> dict[str, str]:
    # No IMPACTCELL_* setting of the caller's (token, database, scheduler) leaks in, nor the
    # CPU pin the test process inherited: each process must pin it itself, as in compose.
    pins = (cpu.BLAS_ENV, cpu.NUMBA_ENV, cpu.FEATURES_ENV, cpu.NUMPY_ENV)
    return {
        k: v for k, v in os.environ.items() if not k.startswith("IMPACTCELL_") and k not in pins
    }


def _killpg(pgid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(pgid, sig)


def _pgid(pid: int) -> int:
    try:
        return os.getpgid(pid)
    except ProcessLookupError:
        return -1


@pytest.fixture(scope="module")
def _topology(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Topology]:
    topo = Topology(tmp_path_factory.mktemp("topology"))
    try:
        yield topo.start()  # a failed start raises with the log tails, and is torn down here
    finally:
        topo.close()


@pytest.fixture
def topology(_topology: Topology) -> Iterator[Topology]:
    """The running topology with its full complement of workers; logs shown on failure."""
    _topology.wait_workers()
    assert _topology.api.alive(), _topology.tails()
    yield _topology
    print(_topology.tails())  # captured: pytest shows it only when the test fails


class Reference:
    """The same study run serially by ``impactcell run --serial``, in a subprocess started
    beside the service's run (one BLAS thread, as on the dask workers: a multi-threaded BLAS
    on a busy 2-core machine makes scipy's expm many times slower)."""

    def __init__(self, d: dict[str, Any], tmp: Path) -> None:
        self.study = parse_study(d)
        self.root = tmp / "ref"
        self.root.mkdir(parents=True)
        (self.root / "study.json").write_text(json.dumps(d), encoding="utf-8")
        env = {**_clean_env(), **{v: "1" for v in _BLAS_THREADS}}
        self.log = self.root / "run.log"
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "service.cli", "run", str(self.root / "study.json"),
                 "--out", str(self.root), "--serial", "--no-progress", "--json"],
                cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL, start_new_session=True,
            )  # fmt: skip

    def result(self, timeout: float = 180.0) -> xr.Dataset:
        try:
            rc = self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                _killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        assert rc == 0, self.log.read_text(errors="replace")[-3000:]
        return open_results(StudyStore(self.root, self.study).results_path)


_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _reasons(ds: xr.Dataset) -> set[str]:
    """The reasons of the failed points."""
    return {str(r) for r in ds["reason"].values[ds["failed"].values.astype(bool)].ravel()}


def _same(a: xr.Dataset, b: xr.Dataset) -> None:
    # The git commit is read when a results file is written: other work may be committed to
    # the checkout between the service's run and the reference run.
    a, b = comparable(a), comparable(b)
    for ds in (a, b):
        ds.attrs.pop("git_commit", None)
    xr.testing.assert_identical(a, b)


@pytest.fixture
def reference(tmp_path: Path) -> Iterator[Callable[[dict[str, Any]], Reference]]:
    """Start serial reference runs; any still running at teardown are killed."""
    started: list[Reference] = []

    def start(d: dict[str, Any]) -> Reference:
        started.append(Reference(d, tmp_path / f"ref{len(started)}"))
        return started[-1]

    yield start
    for r in started:
        if r.proc.poll() is None:
            _killpg(r.proc.pid, signal.SIGKILL)
            r.proc.wait()


def test_study_through_the_api_matches_the_embedded_run(
    topology: Topology, reference: Callable[[dict[str, Any]], Reference]
) -> None:
    from dask.distributed import get_task_stream

    d = tiny_study(name="topology", num=12, gaps=(0.1, 0.5, 2.0))  # 36 points
    ref = reference(d)
    with get_task_stream(topology.dask) as stream, Client(topology.url, token=None) as c:
        rec = c.submit(d)
        assert rec["points_total"] == 36
        rec = c.wait(rec["id"], progress=False, timeout=120, poll=0.1)
        assert rec["status"] == "finished", rec
        assert (rec["points_done"], rec["points_failed"]) == (36, 0)
        ds = c.dataset(rec["id"])
    # The points were computed by the external workers, not by an embedded cluster.
    ran = [t for t in stream.data if str(t["key"]).startswith(f"impactcell-{rec['id']}-")]
    assert ran and {t["worker"] for t in ran} <= set(topology.worker_pids())
    _same(ds, ref.result())
    # Each nanny pinned the CPU target before it started its worker (--preload-nanny worker).
    if cpu.pinnable():
        assert set(topology.dask.run(cpu.kernels).values()) == {cpu.BLAS_CORE}
        assert set(topology.dask.run(cpu.compiled_for).values()) == {cpu.NUMBA_CPU}
    # ... and every worker computes with this process's whole fingerprint, which the dataset
    # records.
    assert list(topology.dask.run(cpu.fingerprint).values()) == [cpu.fingerprint()] * WORKERS
    for key, value in cpu.fingerprint().items():
        assert ds.attrs[key] == value, key


@pytest.mark.skipif(not cpu.pinnable(), reason="the CPU pin is for x86-64 with AVX2 and FMA")
def test_a_worker_that_would_compute_other_bits_is_refused(tmp_path: Path) -> None:
    # A worker started with another numba target than the service's (here: explicit features,
    # on any CPU; a bare `dask worker` on an AVX-512 machine differs in its BLAS kernels and
    # numpy's dispatch): the service's runner refuses the cluster, naming the worker and the
    # difference, and a task sent to it computes nothing.
    from dask.distributed import Client as DaskClient

    from service.studies.runner import make_client
    from service.studies.tasks import chunk_task

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [
        Proc("scheduler", [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1",
                           "--port", str(port), "--dashboard-address", ":0"], tmp_path),
        Proc("odd-worker", [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1",
                            "--no-dashboard", "--preload-nanny", "worker"], tmp_path,
             env={cpu.FEATURES_ENV: "+avx2"}),
    ]  # fmt: skip
    try:
        with DaskClient(address, timeout="30s") as dask:
            dask.wait_for_workers(1, timeout=START_TIMEOUT)
            with pytest.raises(cpu.TargetMismatch) as refused:
                make_client(address, None)
            text = str(refused.value)
            assert "1 of 1 workers compute otherwise" in text
            assert f"numba_cpu haswell+avx2, not {cpu.NUMBA_CPU}" in text
            assert "--preload-nanny worker" in text
            # A task that reaches such a worker anyway (one that joined later) is refused there.
            fut = dask.submit(chunk_task, [], {}, {}, "no-event", False, cpu.fingerprint(),
                              pure=False)  # fmt: skip
            with pytest.raises(cpu.TargetMismatch, match="this worker computes otherwise"):
                fut.result(timeout=60)
    except BaseException:
        print("\n".join(p.tail() for p in procs))
        raise
    finally:
        for p in reversed(procs):
            p.stop()


# Slower per point than FAST_SOLVER (which does 600 points in well under a second on two
# workers): a few seconds of work, so that a worker can be killed in the middle of it.
KILL_SOLVER = {"steps_per_period": 2048, "max_periods": 100, "periodicity_tol": 1e-13}


def test_worker_killed_mid_study_the_other_takes_over(
    topology: Topology, reference: Callable[[dict[str, Any]], Reference]
) -> None:
    d = tiny_study(name="topology-kill", num=150, gaps=(0.1, 0.3, 0.5, 0.7), **KILL_SOLVER)
    total = 600
    ref = reference(d)
    with Client(topology.url, token=None) as c:
        sid = c.submit(d)["id"]
        t0 = time.monotonic()
        while (rec := c.get(sid))["points_done"] <= total // 5:
            assert rec["status"] in ("queued", "running"), (rec, topology.tails())
            assert time.monotonic() - t0 < 120, topology.tails()
            time.sleep(0.05)
        # Kill (nanny and worker child) a worker that is computing a chunk right now.
        victim = None
        while victim is None:
            busy = [a for a, keys in topology.dask.processing().items() if keys]
            victim = topology.worker_of(busy[0]) if busy else None
            assert time.monotonic() - t0 < 120, topology.tails()
            time.sleep(0.01)
        victim.kill()
        at_kill = c.get(sid)
        assert at_kill["status"] == "running" and at_kill["points_done"] < total, at_kill
        rec = c.wait(sid, progress=False, timeout=180, poll=0.2)
        assert rec["status"] == "finished", (rec, topology.tails())
        ds = c.dataset(sid)
        assert (rec["points_done"], rec["points_failed"]) == (total, 0), (rec, _reasons(ds))
    assert not victim.alive()
    assert len(topology.worker_pids()) == WORKERS - 1  # the other worker did the rest
    # The chunks collated without overlap or gap (collect raises on either), none was kept
    # for a retry, and every point equals the serial run's.
    store = StudyStore(topology.data, parse_study(d))
    assert store.results_path.is_file()
    assert not store.has_retry_chunks() and not store.chunks()
    assert int(ds["failed"].sum()) == 0
    _same(ds, ref.result())  # work counters too: the machine's load changes none


def test_worker_lost_holding_finished_chunks_not_yet_collected(
    topology: Topology, reference: Callable[[dict[str, Any]], Reference], tmp_path: Path
) -> None:
    """A worker dies while results of finished tasks are still in its memory: dask computes
    them again and the runner must wait for them, not record the chunks as failed."""
    d = tiny_study(name="topology-lost", num=60, gaps=(0.1, 0.5), **KILL_SOLVER)  # 120 points
    study = parse_study(d)
    ref = reference(d)
    prefix = f"impactcell-{study.id}-"
    lost: list[str] = []

    def held() -> dict[str, list[str]]:
        # Tasks of this study whose results sit in worker memory: key -> worker addresses.
        return topology.dask.run_on_scheduler(
            lambda dask_scheduler: {
                str(ts.key): [ws.address for ws in ts.who_has or ()]
                for ts in dask_scheduler.tasks.values()
                if ts.state == "memory" and str(ts.key).startswith(prefix)
            }
        )

    def on_chunk(start: int, stop: int, records: list[dict[str, Any]]) -> None:
        # On the first chunk (the runner is blocked here): wait until another task has
        # finished, then kill the worker holding its result before the runner collects it.
        if lost:
            return
        this = f"{prefix}{start}-{stop}-"
        t0 = time.monotonic()
        while not (other := {k: w for k, w in held().items() if not k.startswith(this)}):
            assert time.monotonic() - t0 < 60, topology.tails()
            time.sleep(0.05)
        key, (address, *_) = min(other.items())
        topology.worker_of(address).kill()
        lost.append(key)
        while address in held().get(key, ()):  # (it may be in memory again elsewhere)
            assert time.monotonic() - t0 < 60, topology.tails()
            time.sleep(0.05)
        time.sleep(0.2)  # the runner's client hears of the lost key

    summary = run_study(study, tmp_path / "data", client=topology.dask, on_chunk=on_chunk)
    assert lost
    ds = open_results(summary.path)
    assert (summary.points, summary.failed) == (120, 0), _reasons(ds)
    store = StudyStore(tmp_path / "data", study)
    assert not store.has_retry_chunks() and not store.chunks()
    _same(ds, ref.result())
