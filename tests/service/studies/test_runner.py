"""The runner on a real LocalCluster, resume after SIGKILL, and the run/show CLI.

"Identical" results: every coordinate, every data variable except ``wall_s`` and every global
attribute except ``created`` are equal (``xr.testing.assert_identical``). ``wall_s`` is a
measured time and ``created`` a clock reading, so they differ between any two runs; everything
computed is deterministic and must match exactly, whatever the chunking, the worker or the
interruption.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import dask
import distributed  # noqa: F401  # its config defaults
import pytest
import xarray as xr

from service.cli import main
from service.studies import forkserver, runner
from service.studies.chunks import StudyStore
from service.studies.dask_settings import env_name
from service.studies.dataset import open_results
from service.studies.runner import (
    DEFAULT_CHUNK_SIZE,
    default_chunk_size,
    make_client,
    run_study,
)
from service.studies.schema import load_study, parse_study
from service.studies.variables import outcome_names
from tests.service.helpers import comparable
from worker.simulate import simulate_chunk
from worker.solvers.settings import OUTCOMES

ROOT = Path(__file__).resolve().parents[3]
SOLVER = {"steps_per_period": 512, "max_periods": 200, "periodicity_tol": 1e-6, "window": 10}


def test_default_chunks_are_large_but_every_worker_gets_several() -> None:
    # Figure 5 on two workers: whole chunks (a task's fixed cost is ~20 ms of CPU)
    assert default_chunk_size(5820, 2) == DEFAULT_CHUNK_SIZE == 96
    # a small study: at least four tasks per worker, so none waits idle while one computes
    assert default_chunk_size(100, 2) == 13
    assert default_chunk_size(3, 8) == 1


def _study(name: str = "runner", **extra: Any) -> Any:
    d = {
        "name": name,
        "solver": SOLVER,
        "grid": {
            "gamma_r": {"start": 0.3, "stop": 4.0, "num": 24},
            "gap": [0.1, 0.6],
            "theta": 0.3,
            "sigma": 0.05,
            "gamma_s": 1.0,
        },
    }
    d.update(extra)
    return parse_study(d)


@pytest.fixture(scope="module")
def cluster_client() -> Iterator[Any]:
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40
    )
    c = Client(cluster)
    try:
        yield c
    finally:
        c.close()
        cluster.close()


def test_local_cluster_matches_serial(tmp_path: Path, cluster_client: Any) -> None:
    study = _study()
    seen: list[tuple[int, int]] = []
    dist = run_study(
        study,
        tmp_path / "d",
        client=cluster_client,
        chunk_size=5,
        progress=lambda d, t: seen.append((d, t)),
    )
    serial = run_study(study, tmp_path / "s", serial=True, chunk_size=study.size)
    assert dist.points == serial.points == study.size == dist.computed
    assert seen[0] == (0, study.size) and seen[-1] == (study.size, study.size)
    a, b = open_results(dist.path), open_results(serial.path)
    xr.testing.assert_identical(comparable(a), comparable(b))
    # Chunk files are gone once the results file holds them.
    assert not list(StudyStore(tmp_path / "d", study).chunk_dir.glob("*.npz"))


def test_failed_points_do_not_fail_the_study(tmp_path: Path, cluster_client: Any) -> None:
    # Euler at 256 steps a period is unstable for γ_r = 0.2 (Δτ·ω̃_max > 2), fine for γ_r >= 1.
    study = parse_study(
        {
            "name": "fails",
            "solver": {"method": "euler", "steps_per_period": 256, "max_periods": 60, "window": 5},
            "grid": {
                "gamma_r": [0.2, 1.0, 2.0],
                "gap": 0.3,
                "theta": 0.3,
                "sigma": 0.05,
                "gamma_s": 1.0,
            },
        }  # fmt: skip
    )
    s = run_study(study, tmp_path, client=cluster_client, chunk_size=2)
    ds = open_results(s.path)
    assert s.failed == 1 and bool(ds["failed"].sel(gamma_r=0.2))
    assert "unstable" in str(ds["reason"].sel(gamma_r=0.2).values)
    assert not ds["failed"].sel(gamma_r=[1.0, 2.0]).any()


def test_resume_computes_only_missing(tmp_path: Path, cluster_client: Any) -> None:
    study = _study("resume")
    store = StudyStore(tmp_path, study)
    store.prepare()
    solver = study.solver.settings().__dict__
    for a, b in [(0, 7), (20, 30)]:
        store.write_chunk(a, b, simulate_chunk(study.points(a, b), solver))
    s = run_study(study, tmp_path, client=cluster_client, chunk_size=8)
    assert s.computed == study.size - 17
    ref = run_study(study, tmp_path / "ref", serial=True)
    xr.testing.assert_identical(
        comparable(open_results(s.path)), comparable(open_results(ref.path))
    )
    again = run_study(study, tmp_path, client=cluster_client)
    assert again.reused and again.computed == 0


def test_quick_study_runs(tmp_path: Path, cluster_client: Any) -> None:
    study = load_study(ROOT / "studies" / "quick.yaml")
    assert study.solver.method == "event"  # the worker's default, not set in the file
    s = run_study(study, tmp_path, client=cluster_client)
    assert s.points == study.size and s.failed == 0
    ds = open_results(s.path)
    assert ds["transmittance_db"].notnull().all()
    assert sum(s.outcomes.values()) == study.size


@pytest.mark.slow  # starts its own cluster
def test_own_cluster_shuts_down_while_the_results_are_collated(tmp_path: Path, monkeypatch) -> None:
    import threading

    seen: list[tuple[str, str]] = []
    close, collate = runner._close, runner.StudyRun.collate

    def traced_close(client: Any, cluster: Any) -> None:
        seen.append(("close", threading.current_thread().name))
        close(client, cluster)

    def traced_collate(self: Any, workers: int) -> Any:
        seen.append(("collate", threading.current_thread().name))
        return collate(self, workers)

    monkeypatch.setattr(runner, "_close", traced_close)
    monkeypatch.setattr(runner.StudyRun, "collate", traced_collate)
    s = run_study(_study(), tmp_path, workers=1)
    assert s.computed == s.points == 48 and s.path.is_file()
    assert sorted(seen) == [("close", "impactcell-close"), ("collate", "MainThread")]
    # Cancelled: nothing to collate; the cluster is closed before the call returns.
    seen.clear()
    s = run_study(_study("cancelled"), tmp_path, workers=1, cancel=lambda: True)
    assert s.cancelled and seen == [("close", "MainThread")]


def test_summary_counts_outcomes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # A short budget and a tight standard error: some points end irregular, some run out of
    # periods (unsettled).
    study = parse_study(
        {
            "name": "outcomes",
            "solver": {"steps_per_period": 256, "max_periods": 120, "window": 5,
                       "stat_tol_db": 0.05},
            "grid": {"gamma_r": [0.5, 1.0, 2.2, 4.5], "gap": [0.1, 0.5], "theta": 0.3,
                     "sigma": 0.05, "gamma_s": 1.0},
        }
    )  # fmt: skip
    truth = [r["outcome"] for r in simulate_chunk(study.points(0, study.size),
                                                   study.solver.settings().__dict__)]  # fmt: skip
    want = {k: truth.count(k) for k in OUTCOMES}
    assert want["irregular"] and want["unsettled"], truth  # the grid covers both
    s = run_study(study, tmp_path, serial=True)
    assert s.outcomes == want
    assert (s.irregular, s.unsettled, s.failed) == (
        want["irregular"], want["unsettled"], want["failed"],
    )  # fmt: skip
    # Unsettled points have period 0 too, but they are not irregular.
    ds = open_results(s.path)
    period0 = int((ds["response_period"] == 0).sum())
    assert period0 == want["irregular"] + want["unsettled"] > s.irregular
    assert list(outcome_names(ds["outcome"]).ravel()) == truth
    # A reused results file counts the same, from the dataset.
    again = run_study(study, tmp_path, serial=True)
    assert again.reused and again.outcomes == want and again.unsettled == want["unsettled"]
    # The command line reports both counts.
    assert main(["run", str(_study_file(tmp_path, study)), "--out", str(tmp_path), "--json",
                 "--serial", "--no-progress"]) == 0  # fmt: skip
    summary = json.loads(capsys.readouterr().out)
    assert summary["irregular"] == want["irregular"]
    assert summary["unsettled"] == want["unsettled"]
    assert main(["show", str(s.path)]) == 0
    out = capsys.readouterr().out
    assert f"irregular {want['irregular']:,}" in out and f"unsettled {want['unsettled']:,}" in out


def _study_file(folder: Path, study: Any) -> Path:
    path = folder / "study.json"
    path.write_text(study.canonical_json())
    return path


def test_embedded_cluster_starts_while_the_parent_warms_up(monkeypatch) -> None:
    """On a cache without the kernels, the worker processes start while the parent compiles
    them; the client comes only when both are done, so the workers, asked to load kernels
    after that, load the parent's cache instead of compiling."""
    import threading

    import dask.distributed

    calls: list[str] = []
    begun = threading.Event()

    def warm(m: str | None = None) -> None:
        # The cluster's start has begun before the parent's kernels are ready: they overlap.
        assert begun.wait(10), "the cluster did not start while the parent warmed up"
        calls.append(f"warm {m}")

    class FakeCluster:
        def __init__(self, **kw: Any) -> None:
            begun.set()
            calls.append(f"cluster {kw['n_workers']}" + (" preload" if kw["preload"] else ""))

        def close(self) -> None:
            calls.append("closed")

    ready: set[str | None] = set()
    monkeypatch.setattr(runner.simulate, "cache_ready", lambda m=None: m in ready)
    monkeypatch.setattr(runner.simulate, "warm_up", warm)
    monkeypatch.setattr(dask.distributed, "LocalCluster", FakeCluster)
    monkeypatch.setattr(dask.distributed, "Client", lambda c, **kw: calls.append("client") or c)
    monkeypatch.delenv("IMPACTCELL_SCHEDULER", raising=False)
    # the workers are forked from the forkserver (started once per process, before a cluster)
    monkeypatch.setattr(runner.forkserver, "start", lambda: calls.append("forkserver"))
    make_client(None, 2, method="euler")
    assert calls == ["forkserver", "cluster 2", "warm euler", "client"]
    begun.clear()
    calls.clear()
    make_client(None, 1)
    assert calls == ["forkserver", "cluster 1", "warm event", "client"]

    # A warm cache: the workers load the kernels as they start; the parent loads nothing.
    ready.add("euler")
    calls.clear()
    make_client(None, 2, method="euler")
    assert calls == ["forkserver", "cluster 2 preload", "client"]
    ready.clear()

    # A failed warm-up (a kernel that does not compile) closes the cluster started meanwhile.
    def broken(m: str | None = None) -> None:
        begun.wait(10)
        raise RuntimeError("no kernel")

    calls.clear()
    monkeypatch.setattr(runner.simulate, "warm_up", broken)
    with pytest.raises(RuntimeError, match="no kernel"):
        make_client(None, 2)
    assert calls == ["forkserver", "cluster 2", "closed"]

    # A scheduler elsewhere: its workers do not share this machine's cache; nothing to warm,
    # but every worker is asked for its fingerprint (tests/test_topology.py: one is refused).
    class FakeClient:
        def __init__(self, address: str, **kw: Any) -> None:
            self.address = address

        def run(self, fn: Any) -> dict[str, Any]:
            calls.append(f"run {fn.__name__}")
            return {}

    calls.clear()
    monkeypatch.setattr(dask.distributed, "Client", FakeClient)
    client, cluster = make_client("tcp://127.0.0.1:1", None)
    assert (client.address, cluster) == ("tcp://127.0.0.1:1", None)
    assert calls == ["run fingerprint"]


def test_local_workers_are_asked_to_load_a_method_only_after_this_process_filled_the_cache(
    monkeypatch,
) -> None:
    # The job manager meets methods one by one on one cluster: a later method must be compiled
    # once, here, before the workers (which share this machine's cache) load it.
    calls: list[str] = []

    class FakeClient:
        def run(self, fn: Any, method: str) -> None:
            calls.append(f"workers {fn.__name__} {method}")

    monkeypatch.setattr(runner.simulate, "fill_cache", lambda m=None: calls.append(f"fill {m}"))
    for local in (True, False):
        monkeypatch.setattr(runner, "_is_local", lambda client, local=local: local)
        runner.warm_up(FakeClient(), "euler")
    # a scheduler elsewhere: its workers have their own cache, nothing to fill here
    assert calls == ["fill euler", "workers warm_up euler", "workers warm_up euler"]


_WORKERS_LOAD_AT_START = r"""
import json
import os
import sys

PARENT = os.getpid()
from service.studies.runner import _close, make_client
from worker import simulate
from worker.cpu import blas_threads

assert simulate.cache_ready("event")
client, cluster = make_client(None, 2, method="event")
# before anything else here could import them
early = ["dask.array" in sys.modules, "netCDF4" in sys.modules]
try:
    loaded = client.run(lambda: sorted(__import__("worker.simulate").simulate._warm))
    # how each worker process came to be, and what it started with

    origin = client.run(lambda: [os.getppid() == PARENT, os.environ.get("MALLOC_TRIM_THRESHOLD_"),
                                 blas_threads()])
    profiling = client.run(lambda dask_worker: "profile" in dask_worker.periodic_callbacks)
    # the event-loop health check's period (s): each worker's, and the scheduler's
    ticks = client.run(lambda dask_worker: dask_worker._tick_interval)
    ticks["scheduler"] = client.run_on_scheduler(
        lambda dask_scheduler: dask_scheduler._tick_interval
    )
    from xarray.backends.locks import get_dask_scheduler

    # what xarray's NetCDF writes in this process would lock on
    print(json.dumps([sorted(simulate._warm), sorted(loaded.values()), get_dask_scheduler(),
                      sorted(profiling.values()), sorted(ticks.values()),
                      sorted(origin.values()), early]))
finally:
    _close(client, cluster)
"""


@pytest.mark.slow  # real worker processes
@pytest.mark.parametrize("start", ["forked", "spawned"])
def test_on_a_warm_cache_workers_load_kernels_as_they_start_and_the_parent_loads_none(
    start: str,
) -> None:
    method = env_name(forkserver.METHOD_KEY)
    quiet = {env_name(k) for k in runner._EMBEDDED_CONFIG}
    env = {k: v for k, v in os.environ.items()
           if k not in ("IMPACTCELL_SCHEDULER", "MALLOC_TRIM_THRESHOLD_", method)
           and k not in quiet}  # fmt: skip
    if start == "spawned":  # the user's choice of dask's default stands
        env[method] = "spawn"
    fill = "from worker import simulate; simulate.fill_cache('event')"
    subprocess.run([sys.executable, "-c", fill], cwd=ROOT, env=env, check=True, timeout=600)
    script = [sys.executable, "-c", _WORKERS_LOAD_AT_START]
    out = subprocess.run(
        script, cwd=ROOT, env=env, capture_output=True, text=True, check=True, timeout=300
    ).stdout
    parent, workers, netcdf_lock, profiling, ticks, origin, early = json.loads(
        out.strip().splitlines()[-1]
    )
    # imported while the cluster started (xarray's first variable imports dask.array, the
    # results file needs netCDF4): not at collation, and a failing import fails before any point
    assert early == [True, True]
    # Forked from the forkserver (not this process's children) or spawned by this process's
    # nannies; either way with dask's pre-spawn environment (glibc's trim threshold) and one
    # BLAS thread (another count sums in another order).
    trim = str(dask.config.get("distributed.nanny.pre-spawn-environ")["MALLOC_TRIM_THRESHOLD_"])
    assert origin == [[start == "spawned", trim, 1]] * 2
    assert profiling == [False, False]  # no worker samples its threads' stacks every 10 ms
    assert ticks == [1.0, 1.0, 1.0]  # health checks each second, not each 20 ms (dask's default)
    assert parent == []  # nothing compiled or loaded in the process that only hands out points
    assert workers == [["event"], ["event"]]  # loaded before anyone asked (no warm_up yet)
    # The client is not dask's default, so a NetCDF write (the results file, collated while the
    # cluster shuts down) takes a lock in this process, not on the scheduler ("distributed").
    assert netcdf_lock != "distributed"


def test_a_chunk_travels_as_one_object_each_way() -> None:
    # dask walks a plain list of point dicts for futures at every hop, and sends a plain list
    # result one frame per record: Points and Records each go as one object, same contents.
    import pickle

    from dask._task_spec import parse_input
    from distributed.protocol import deserialize, serialize

    from service.studies.tasks import Points, Records, chunk_task

    study = _study()
    pts = study.points(0, 3)
    sent = Points(pts)
    assert parse_input(sent) is sent
    assert pickle.loads(pickle.dumps(sent)).items == pts
    solver = study.solver.settings().__dict__
    records = chunk_task(sent, solver, {}, "no-event")
    assert type(records) is Records
    again = chunk_task(pts, solver, {}, "no-event")
    plain = simulate_chunk(pts, solver)
    for a, b, c in zip(records, again, plain, strict=True):
        assert {**a, "wall_s": 0} == {**b, "wall_s": 0} == {**c, "wall_s": 0}
    header, frames = serialize(records, iterate_collection=True)
    assert len(frames) == 1
    assert deserialize(header, frames) == records


def test_a_cluster_that_cannot_start_is_an_error_in_the_caller(monkeypatch) -> None:
    import dask.distributed

    class NoCluster:
        def __init__(self, **kw: Any) -> None:
            raise OSError("no free port")

    monkeypatch.setattr(runner.simulate, "warm_up", lambda m=None: None)
    monkeypatch.setattr(runner.forkserver, "start", lambda: False)
    monkeypatch.setattr(dask.distributed, "LocalCluster", NoCluster)
    with pytest.raises(OSError, match="no free port"):
        make_client(None, 2)


def test_workers_get_one_blas_thread() -> None:
    import dask

    runner._worker_environ()
    env = dask.config.get("distributed.nanny.pre-spawn-environ")
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        assert int(env[var]) == 1, var


def test_embedded_clusters_run_without_what_only_a_dashboard_reads_unless_asked(
    monkeypatch,
) -> None:
    import dask

    shipped = dask.config.merge(*dask.config.defaults)
    for key, value in runner._EMBEDDED_CONFIG.items():
        default = dask.config.get(key, config=shipped)
        assert value != default, key  # each entry changes something
        env = env_name(key)
        with dask.config.set({key: default}):
            monkeypatch.delenv(env, raising=False)
            runner._quiet_embedded_cluster()
            assert dask.config.get(key) == value
        with dask.config.set({key: default}):
            monkeypatch.setenv(env, str(default))  # the user's choice stands
            runner._quiet_embedded_cluster()
            assert dask.config.get(key) == default
        monkeypatch.delenv(env)
        other = "7s" if isinstance(default, str) else (not default)
        with dask.config.set({key: other}):  # a dask config file's value stands too
            runner._quiet_embedded_cluster()
            assert dask.config.get(key) == other
    # dask reads these variables as these keys
    assert env_name("distributed.worker.memory.monitor-interval") == (
        "DASK_DISTRIBUTED__WORKER__MEMORY__MONITOR_INTERVAL"
    )


def test_worker_warm_up_uses_the_default_method(cluster_client: Any) -> None:
    import inspect

    assert inspect.signature(runner.warm_up).parameters["method"].default == "event"
    runner.warm_up(cluster_client)  # compiles or loads in every worker; returns once all are done
    cached = cluster_client.run(lambda: __import__("worker.simulate").simulate._warm.copy())
    assert all("event" in methods for methods in cached.values())


@pytest.mark.slow  # a new Python process
def test_a_worker_imports_only_the_simulator_to_run_a_chunk(tmp_path: Path) -> None:
    """A worker imports the module of the function it is sent: the chunk task's module must not
    pull in the runner's schema, datasets and store (~1.3 s per worker before its first point)."""
    sent: list[Any] = []

    class Future:
        def add_done_callback(self, fn: Any) -> None:
            pass

    class Client:
        def submit(self, fn: Any, *args: Any, **kw: Any) -> Future:
            sent.append(fn)
            return Future()

    pool = runner.ChunkPool(Client(), window=1)
    pool.add("one", runner.make_run(_study(), tmp_path))
    pool._fill()
    assert [f.__module__ for f in sent] == ["service.studies.tasks"]
    heavy = ("xarray", "pandas", "scipy.sparse", "pydantic", "sqlalchemy", "service.studies.runner")
    assert _loaded_after("service.studies.tasks", heavy) == []


@pytest.mark.slow  # a new Python process
def test_the_process_that_hands_out_points_imports_no_scipy_solvers() -> None:
    """scipy's linear algebra and special functions cost ~0.4 s of CPU to import, on the
    command's critical path before its cluster starts; only a point's set-up (``exponential``)
    and an irregular point's statistics need them, in the workers."""
    command = "service.cli, service.studies.runner, service.api.points, worker.simulate"
    assert _loaded_after(command, ("scipy.linalg", "scipy.special")) == []


def _loaded_after(imports: str, modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh interpreter holds after ``import <imports>``."""
    held = f"[m for m in {modules!r} if m in sys.modules]"
    code = f"import json, sys, {imports}; print(json.dumps({held}))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _chunk_files(folder: Path) -> list[Path]:
    return list(folder.glob("*.npz")) if folder.is_dir() else []


@pytest.mark.slow  # a real `impactcell run` process, killed and resumed
def test_sigkill_and_resume(tmp_path: Path) -> None:
    study_file = tmp_path / "kill.yaml"
    study_file.write_text(
        "name: kill\n"
        "solver: {steps_per_period: 1024, max_periods: 400}\n"
        "grid: {gamma_r: {start: 0.3, stop: 5.0, num: 60}, gap: [0.1, 0.4, 0.8], theta: 0.3,\n"
        "       sigma: 0.05, gamma_s: 1.0}\n"
    )
    study = load_study(study_file)
    out = tmp_path / "data"
    store = StudyStore(out, study)
    cmd = [sys.executable, "-m", "service.cli", "run", str(study_file), "--out", str(out)]
    opts = ["--workers", "1", "--chunk-size", "4", "--no-progress", "--json"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        cmd + opts, cwd=ROOT, env=env, start_new_session=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while len(_chunk_files(store.chunk_dir)) < 3:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, "no chunk files appeared"
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        # The embedded cluster's worker processes are in the killed process's group.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    assert not store.results_path.exists(), "the study finished before it was killed"
    done = store.done_mask().sum()
    assert 0 < done < study.size

    rerun = subprocess.run(
        cmd + opts, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300, check=True
    )
    summary = json.loads(rerun.stdout)
    # Nothing finished is computed again: the chunk files found after the kill are reused, and
    # so are the points of a chunk killed between its two writes (the point store first, then
    # its chunk file; a run once fell there, reusing 16 points where 12 had chunk files).
    assert summary["computed"] + summary["reused"] == study.size
    assert summary["reused"] >= done and summary["computed"] > 0
    resumed = open_results(store.results_path)

    ref = run_study(study, tmp_path / "ref", serial=True)
    xr.testing.assert_identical(comparable(resumed), comparable(open_results(ref.path)))


@pytest.mark.slow  # runs whole (small) studies
def test_cli_show_and_bad_study(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    study = _study("cli")
    s = run_study(study, tmp_path, serial=True)
    assert main(["show", str(s.path)]) == 0
    out = capsys.readouterr().out
    assert study.id in out and "transmittance_db" in out and "outcome" in out
    assert re.search(r"points\s+48  failed 0  linear \d+  periodic \d+  irregular \d+  "
                     r"unsettled \d+", out)  # fmt: skip
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nnope: 1\ngrid: {gamma_r: -1}\n")
    assert main(["run", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "nope: unknown key" in err and "grid.gamma_r" in err and "grid.theta" in err
    assert main(["show", str(tmp_path / "missing.nc")]) == 2
