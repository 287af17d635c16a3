"""Real faults mid-study: the disk refusing writes, PostgreSQL restarted, a service paused past
its lease, a 2M-point grid. Each study finishes with nothing lost and nothing computed twice."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import xarray as xr
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.catalogue import Catalogue, LeaseRow
from service.api.jobs import lease_name
from service.api.settings import Settings
from service.studies import runner as runner_mod
from service.studies.chunks import StudyStore
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from tests.service.helpers import JSON_BODY, SLOW_SOLVER, Server, comparable, tiny_study

# 64 points of ~20 ms each in 8 chunks (2 workers): a run of a second or two, non-chaotic
# points (the same bits wherever they run on this machine).
STUDY = tiny_study(name="outage", num=32, gaps=(0.1, 0.5), **SLOW_SOLVER)


def _wait(get: Callable[[], dict[str, Any]], until: Callable[[dict[str, Any]], bool],
          timeout: float = 120.0) -> dict[str, Any]:  # fmt: skip
    t0 = time.monotonic()
    while True:
        rec = get()
        if until(rec):
            return rec
        assert time.monotonic() - t0 < timeout, rec
        time.sleep(0.05)


def _reference(tmp_path: Path, d: dict[str, Any]) -> xr.Dataset:
    """The study run alone, in this process, in a folder of its own (a clean run)."""
    summary = run_study(parse_study(d), tmp_path / "reference", serial=True)
    return open_results(summary.path)


def _same(ds: xr.Dataset, ref: xr.Dataset) -> None:
    """Every variable equal to the bit (NaN where the reference has NaN)."""
    a, b = comparable(ds), comparable(ref)
    assert sorted(a.data_vars) == sorted(b.data_vars)
    for name in b.data_vars:
        x, y = a[name].values, b[name].values
        if x.dtype.kind == "f":
            assert np.array_equal(x, y, equal_nan=True), name
        else:
            assert (x == y).all(), name


@contextlib.contextmanager
def _count_launches() -> Iterator[list[int]]:
    """Points handed to the cluster, per chunk launched (each must go out once)."""
    launched: list[int] = []
    real = runner_mod.ChunkPool._launch

    def counting(self: Any, key: str, run: Any, start: int, stop: int) -> None:
        launched.extend(range(start, stop))
        real(self, key, run, start, stop)

    runner_mod.ChunkPool._launch = counting  # type: ignore[method-assign]
    try:
        yield launched
    finally:
        runner_mod.ChunkPool._launch = real  # type: ignore[method-assign]


@contextlib.contextmanager
def _after_first_chunk(fault: Callable[[], None]) -> Iterator[threading.Event]:
    """Call ``fault`` right after the first chunk file is stored (in the runner's thread, so
    the fault lands mid-study on any machine); the event says it happened."""
    real = StudyStore.write_chunk
    hit = threading.Event()

    def write(self: StudyStore, *a: Any, **kw: Any) -> Path:
        path = real(self, *a, **kw)
        if not hit.is_set():
            hit.set()
            fault()
        return path

    StudyStore.write_chunk = write  # type: ignore[method-assign]
    try:
        yield hit
    finally:
        StudyStore.write_chunk = real  # type: ignore[method-assign]


def _run_through(tc: TestClient, d: dict[str, Any], fault: Callable[[], None],
                 mend: Callable[[], None], seen: Callable[[dict[str, Any]], bool],
                 watch: Callable[[str], dict[str, Any]] | None = None,
                 ) -> tuple[dict[str, Any], list[int]]:  # fmt: skip
    """Submit ``d``; the fault strikes after its first chunk; once ``seen`` holds for what
    ``watch(study id)`` gives (default: the study's record), mend."""
    with _count_launches() as launched, _after_first_chunk(fault) as hit:
        sid = tc.post("/studies", json=d).json()["id"]
        _wait(lambda: {"hit": hit.is_set()}, lambda r: r["hit"])
        t0 = time.monotonic()
        _wait(lambda: (watch or (lambda i: tc.get(f"/studies/{i}").json()))(sid), seen)
        waited = time.monotonic() - t0
        mend()
        rec = _wait(lambda: tc.get(f"/studies/{sid}").json(),
                    lambda r: r["status"] in ("finished", "failed"))  # fmt: skip
    assert waited < 30
    return rec, launched


def _mount_tmpfs(where: Path) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    where.mkdir(parents=True, exist_ok=True)
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(where)],
                         capture_output=True)  # fmt: skip
    return res.returncode == 0


@pytest.mark.slow
def test_a_disk_refusing_writes_mid_study_pauses_it_until_it_takes_them_again(
    tmp_path: Path, dask_address: str
) -> None:
    """A full disk (a 4 MB tmpfs, filled) where one can be mounted, else a chunk folder that
    is not a folder any more (refused to root too); the study waits, then finishes."""
    disk = tmp_path / "disk"
    full = _mount_tmpfs(disk)
    data = disk / "data"
    study = parse_study(STUDY)
    chunks = StudyStore(data, study).chunk_dir
    filler = disk / "filler"

    def fault() -> None:
        if full:  # fill the disk: every write from now on fails with ENOSPC
            with contextlib.suppress(OSError), open(filler, "wb") as fh:
                while True:
                    fh.write(b"\0" * 65536)
        else:  # ENOTDIR / EEXIST for every chunk written from now on
            chunks.rename(chunks.with_name("away"))
            chunks.write_text("not a folder")

    def mend() -> None:
        if full:
            filler.unlink()
        else:
            chunks.unlink()
            chunks.with_name("away").rename(chunks)

    try:
        s = Settings(data_dir=data, scheduler=dask_address, outage_backoff_s=1.0,
                     database_url=f"sqlite:///{tmp_path / 'catalogue.sqlite'}")  # fmt: skip
        with TestClient(create_app(s, run_jobs=True)) as tc:
            rec, launched = _run_through(
                tc, STUDY, fault, mend,
                lambda r: r["status"] == "waiting" and "disk refused a write" in r["error"],
            )  # fmt: skip
            assert rec["status"] == "finished", rec
            assert rec["error"] is None and rec["points_done"] == study.size
            assert sorted(launched) == list(range(study.size))  # each point computed once
            ds = xr.load_dataset(tc.get(f"/studies/{rec['id']}/dataset").content)
        _same(ds, _reference(tmp_path, STUDY))
    finally:
        if full:
            subprocess.run(["umount", "-l", str(disk)], check=False)


def _as_pg(cmd: list[str]) -> list[str]:
    """``cmd`` as PostgreSQL's user when we are root (the server refuses to run as root)."""
    return ["runuser", "-u", "postgres", "--", *cmd] if os.geteuid() == 0 else cmd


@pytest.fixture
def own_postgres(tmp_path: Path) -> Iterator[tuple[str, Callable[[], None], Callable[[], None]]]:
    """A PostgreSQL server of this test alone (stopping CI's would break the other xdist
    process's tests): its URL, and functions that stop and start it."""
    if not os.environ.get("IMPACTCELL_TEST_DATABASE_URL"):
        pytest.skip("PostgreSQL leg: IMPACTCELL_TEST_DATABASE_URL is not set (.ci/run sets it)")
    bins = sorted(Path("/usr/lib/postgresql").glob("*/bin/pg_ctl"))
    if not bins:
        pytest.skip("PostgreSQL leg: no pg_ctl under /usr/lib/postgresql")
    pg_bin = bins[-1].parent
    root = Path(tempfile.mkdtemp(prefix="impactcell-pg-restart."))
    if os.geteuid() == 0:
        shutil.chown(root, "postgres")
    data = root / "data"
    subprocess.run(_as_pg([str(pg_bin / "initdb"), "-D", str(data), "-U", "postgres", "--no-sync",
                           "--auth=trust"]), check=True, capture_output=True)  # fmt: skip
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    opts = f"-c listen_addresses=127.0.0.1 -p {port} -k {root} -c fsync=off"

    def start() -> None:
        subprocess.run(_as_pg([str(pg_bin / "pg_ctl"), "-D", str(data), "-l",
                               str(root / "server.log"), "-w", "-t", "60", "-o", opts, "start"]),
                       check=True, capture_output=True)  # fmt: skip

    def stop() -> None:
        subprocess.run(_as_pg([str(pg_bin / "pg_ctl"), "-D", str(data), "-m", "fast", "-w",
                               "stop"]), check=True, capture_output=True)  # fmt: skip

    start()
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres", stop, start
    finally:
        subprocess.run(_as_pg([str(pg_bin / "pg_ctl"), "-D", str(data), "-m", "immediate",
                               "stop"]), capture_output=True)  # fmt: skip
        shutil.rmtree(root, ignore_errors=True)


@pytest.mark.slow
def test_postgresql_restarted_mid_study_pauses_it_until_it_is_back(
    tmp_path: Path, dask_address: str, own_postgres: Any, caplog: pytest.LogCaptureFixture
) -> None:
    url, stop, start = own_postgres
    study = parse_study(STUDY)

    def mend() -> None:
        time.sleep(3.0)  # an outage of a few seconds
        start()

    s = Settings(data_dir=tmp_path / "data", scheduler=dask_address, database_url=url,
                 outage_backoff_s=1.0)  # fmt: skip
    caplog.set_level(logging.WARNING, logger="impactcell.jobs")
    with TestClient(create_app(s, run_jobs=True)) as tc:
        # The database is away: nobody can read the record; the runner says it waits.
        rec, launched = _run_through(
            tc, STUDY, stop, mend,
            lambda r: "waits: the catalogue database cannot be reached" in r["log"],
            watch=lambda _: {"log": caplog.text},
        )  # fmt: skip
        assert rec["status"] == "finished", rec
        assert rec["points_done"] == study.size and rec["error"] is None
        assert sorted(launched) == list(range(study.size))  # each point computed once
        ds = xr.load_dataset(tc.get(f"/studies/{rec['id']}/dataset").content)
    _same(ds, _reference(tmp_path, STUDY))


def _holder_pid(cat: Catalogue, sid: str) -> int | None:
    with cat._tx() as s:
        row = s.get(LeaseRow, lease_name(sid))
        return None if row is None else int(row.holder.split(":")[1])


@pytest.mark.slow
def test_a_service_paused_past_its_lease_writes_nothing_after_the_takeover(
    tmp_path: Path, dask_address: str
) -> None:
    data = tmp_path / "data"
    env = {"IMPACTCELL_LEASE_TTL_S": "2"}
    # 192 points of ~20 ms: the study is still running when the first service is paused.
    d = tiny_study(name="paused", num=96, gaps=(0.1, 0.5), **SLOW_SOLVER)
    study = parse_study(d)
    a = Server(data, dask_address, env=env)
    b = Server(data, dask_address, env=env)
    cat = Catalogue(Settings(data_dir=data).catalogue_url())
    try:
        sid = httpx.post(f"{a.url}/studies", json=d).json()["id"]
        rec = _wait(lambda: httpx.get(f"{a.url}/studies/{sid}").json(),
                    lambda r: r["points_done"] > 0)  # fmt: skip
        owner = _holder_pid(cat, sid)
        first, other = (a, b) if owner == a.proc.pid else (b, a)
        first.proc.send_signal(signal.SIGSTOP)
        try:
            # The other service takes the study over once the lease has expired.
            _wait(lambda: {"pid": _holder_pid(cat, sid)},
                  lambda r: r["pid"] == other.proc.pid, timeout=60)  # fmt: skip
            time.sleep(1.0)
        finally:
            first.proc.send_signal(signal.SIGCONT)  # wakes up with its tasks' results
        rec = _wait(lambda: httpx.get(f"{other.url}/studies/{sid}").json(),
                    lambda r: r["status"] in ("finished", "failed"))  # fmt: skip
        assert rec["status"] == "finished", rec
        assert rec["points_done"] == rec["points_total"] == study.size
        time.sleep(3.0)  # the woken service had time to try its writes
        rec2 = httpx.get(f"{first.url}/studies/{sid}").json()
        assert rec2["status"] == "finished" and rec2["points_done"] == study.size
        store = StudyStore(data, study)
        assert store.chunks() == [] and store.results_path.exists()  # no stray chunk
        r = httpx.get(f"{first.url}/studies/{sid}/dataset", timeout=60)
        assert r.status_code == 200
        _same(xr.load_dataset(r.content), _reference(tmp_path, d))
        assert "stopping here" in first.logtext()  # it found its token stale
    finally:
        cat.close()
        for srv in (a, b):
            with contextlib.suppress(Exception):
                srv.proc.send_signal(signal.SIGCONT)
            srv.stop()


@pytest.mark.slow
def test_a_small_study_starts_within_seconds_behind_a_2m_point_grid(
    tmp_path: Path, dask_address: str
) -> None:
    s = Settings(data_dir=tmp_path / "data", scheduler=dask_address, lease_ttl_s=3)
    with TestClient(create_app(s, run_jobs=True)) as tc:
        cat = Catalogue(s.catalogue_url())
        big = tc.post("/studies", json=tiny_study(name="big", num=1_000_000, gaps=(0.1, 0.5)))
        assert big.status_code in (200, 201, 202), big.text
        bid = big.json()["id"]
        assert big.json()["points_total"] == 2_000_000
        _wait(lambda: tc.get(f"/studies/{bid}").json(), lambda r: r["status"] == "running")
        time.sleep(1.0)
        t0 = time.monotonic()
        sid = tc.post("/studies", json=tiny_study(name="small", num=5, gaps=(0.1,))).json()["id"]
        _wait(lambda: tc.get(f"/studies/{sid}").json(), lambda r: r["status"] != "queued")
        started = time.monotonic() - t0
        rec = _wait(lambda: tc.get(f"/studies/{sid}").json(),
                    lambda r: r["status"] == "finished", timeout=60)  # fmt: skip
        took = time.monotonic() - t0
        assert rec["points_done"] == 5
        # (held for about a minute while the big grid was expanded on the runner's thread)
        assert started < 5.0, f"the 5-point study started {started:.1f} s after submission"
        assert took < 20.0, f"the 5-point study took {took:.1f} s behind the 2M-point one"
        # the big study's lease is renewed all along (3 s lease, renewed every second)
        lease = cat.lease(lease_name(bid))
        assert lease is not None
        assert lease["expires_at"].timestamp() > time.time() + 0.5
        assert tc.get(f"/studies/{bid}").json()["status"] == "running"
        assert tc.post(f"/studies/{bid}/cancel", headers=JSON_BODY).json()["status"] == "cancelled"
    cat.close()


@pytest.mark.slow
def test_a_small_study_finishes_while_a_big_ones_results_file_is_written(
    tmp_path: Path, dask_address: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Collation runs off the runner thread: a study whose results file takes long to write
    (held here for 8 s) holds no other study, and is recorded once its file is there."""
    release = threading.Event()
    plain = runner_mod.StudyRun.collate

    def slow_collate(self: runner_mod.StudyRun, workers: int) -> Any:
        if self.study.name == "first":
            release.wait(8.0)
        return plain(self, workers)

    monkeypatch.setattr(runner_mod.StudyRun, "collate", slow_collate)
    s = Settings(data_dir=tmp_path / "data", scheduler=dask_address)
    with TestClient(create_app(s, run_jobs=True)) as tc:
        fid = tc.post("/studies", json=tiny_study(name="first", num=6, gaps=(0.1,))).json()["id"]
        _wait(lambda: tc.get(f"/studies/{fid}").json(), lambda r: r["points_done"] == 6)
        t0 = time.monotonic()
        sid = tc.post("/studies", json=tiny_study(name="second", num=5, gaps=(0.1,))).json()["id"]
        rec = _wait(lambda: tc.get(f"/studies/{sid}").json(),
                    lambda r: r["status"] == "finished", timeout=30)  # fmt: skip
        took = time.monotonic() - t0
        assert rec["points_done"] == 5 and took < 6.0, f"held {took:.1f} s behind a collation"
        assert tc.get(f"/studies/{fid}").json()["status"] == "running"  # its file not yet there
        release.set()
        first = _wait(lambda: tc.get(f"/studies/{fid}").json(),
                      lambda r: r["status"] == "finished", timeout=30)  # fmt: skip
        assert first["points_done"] == 6
        assert tc.get(f"/studies/{fid}/dataset").status_code == 200
