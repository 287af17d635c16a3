"""Fencing tokens and outage retries at the unit level: the backoff, which errors are waited
out, chunk files written under a token, and a pool that keeps chunks it cannot store."""

from __future__ import annotations

import errno
import time
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy.exc import IntegrityError, OperationalError

from service.studies.chunks import StudyStore, chunk_name
from service.studies.fence import Backoff, Fence, FenceLost, is_transient
from service.studies.runner import ChunkPool, StudyRun
from service.studies.schema import parse_study
from tests.service.helpers import tiny_study


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_backoff_doubles_up_to_its_cap_and_starts_over_after_a_success() -> None:
    clock = _Clock()
    b = Backoff(first=0.5, cap=4.0, clock=clock)
    waits = [b.failed() for _ in range(6)]
    # 0.5, 1, 2, 4, 4, 4 s, each up to 20 % less (jitter), never more
    for w, full in zip(waits, [0.5, 1, 2, 4, 4, 4], strict=True):
        assert 0.8 * full <= w <= full
    assert not b.due()
    clock.t += 4.0
    assert b.due() and b.elapsed() == pytest.approx(4.0)
    b.ok()
    assert b.due() and b.elapsed() == 0.0 and b.failed() <= 0.5


def test_outages_are_transient_and_bugs_or_a_lost_fence_are_not() -> None:
    assert is_transient(OSError(errno.ENOSPC, "No space left on device"))
    assert is_transient(PermissionError(errno.EROFS, "Read-only file system"))
    assert is_transient(OperationalError("SELECT 1", {}, Exception("connection refused")))
    assert not is_transient(IntegrityError("INSERT", {}, Exception("duplicate key")))
    assert not is_transient(ValueError("bad chunk"))
    assert not is_transient(FenceLost("study x: another process runs it now"))


def _store(tmp_path: Path, token: int | None, ok: list[bool] | None = None) -> StudyStore:
    study = parse_study(tiny_study(num=8, gaps=(0.1,)))

    def check() -> None:
        if ok is not None and not ok[0]:
            raise FenceLost("stale")

    return StudyStore(tmp_path, study, fence=None if token is None else Fence(token, check))


def _records(n: int) -> list[dict[str, Any]]:
    return [{"wall_s": 0.0, "outcome": "periodic", "transmittance_db": float(i)} for i in range(n)]


def test_a_chunk_is_published_under_its_token_only_while_the_fence_holds(tmp_path: Path) -> None:
    ok = [True]
    store = _store(tmp_path, 7, ok)
    store.prepare()
    path = store.write_chunk(0, 4, _records(4))
    assert path.name == chunk_name(0, 4, 7) == "0-4.g7.npz"
    ok[0] = False  # another process took the study over
    with pytest.raises(FenceLost):
        store.write_chunk(4, 8, _records(4))
    # nothing published, nothing left half-written
    assert sorted(p.name for p in store.chunk_dir.iterdir()) == ["0-4.g7.npz"]
    assert store.missing_ranges() == [(4, 8)]


def test_where_chunks_overlap_the_newest_token_counts(tmp_path: Path) -> None:
    old = _store(tmp_path, 1)
    old.prepare()
    old.write_chunk(0, 2, _records(2))  # before the takeover: stays
    new = _store(tmp_path, 2)
    new.write_chunk(2, 5, _records(3))
    new.write_chunk(5, 8, _records(3))
    old.write_chunk(4, 6, _records(2))  # a stale process published after the takeover
    reader = _store(tmp_path, None)
    assert [(a, b) for a, b, _ in reader.chunks()] == [(0, 2), (2, 5), (5, 8)]
    assert not (reader.chunk_dir / "4-6.g1.npz").exists()  # removed, not read
    cols = reader.collect()  # no "overlaps another chunk"
    assert list(cols["transmittance_db"]) == [0.0, 1.0, 0.0, 1.0, 2.0, 0.0, 1.0, 2.0]


class _Future:
    """A finished dask future stand-in: the task's records at once."""

    def __init__(self, n: int) -> None:
        self.n = n

    def done(self) -> bool:
        return True

    def result(self) -> list[dict[str, Any]]:
        return _records(self.n)

    def add_done_callback(self, fn: Any) -> None:
        fn(self)

    def release(self) -> None:
        pass


class _Client:
    def submit(self, fn: Any, points: list[Any], *args: Any, **kw: Any) -> _Future:
        return _Future(len(points))


def test_a_chunk_that_cannot_be_stored_is_kept_and_stored_when_the_disk_is_back(
    tmp_path: Path,
) -> None:
    study = parse_study(tiny_study(num=8, gaps=(0.1,)))
    run = StudyRun(study, tmp_path, chunk_size=2)
    pool = ChunkPool(_Client(), 2, hold=True, backoff_cap=0.2)
    pool.add("s", run)
    real = run.store.write_chunk
    fails = [3]

    def flaky(*a: Any, **kw: Any) -> Path:
        if fails[0] > 0:
            fails[0] -= 1
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*a, **kw)

    run.store.write_chunk = flaky  # type: ignore[method-assign]
    stalled = []
    steps = 0
    t0 = time.monotonic()
    while not run.complete:
        pool.step(0.05)
        steps += 1
        if "s" in pool.stalls:
            stalled.append(str(pool.stalls["s"]))
        assert time.monotonic() - t0 < 10
    assert stalled and "No space left" in stalled[0]
    assert "s" not in pool.stalls and not pool.broken
    assert run.store.missing_ranges() == [] and run.done == 8
    # backed off (0.5 s first, capped at 0.2 s here), never spinning
    assert steps < 60 and time.monotonic() - t0 >= 0.3
    # a step with nothing to do waits its timeout instead of returning at once
    t1 = time.monotonic()
    pool.remove("s")
    pool.step(0.2)
    assert time.monotonic() - t1 >= 0.19


def test_a_run_whose_fence_is_lost_stops_without_writing(tmp_path: Path) -> None:
    study = parse_study(tiny_study(num=8, gaps=(0.1,)))
    ok = [True]

    def check() -> None:
        if not ok[0]:
            raise FenceLost("stale")

    run = StudyRun(study, tmp_path, chunk_size=2, fence=Fence(3, check))
    pool = ChunkPool(_Client(), 1, hold=True)
    pool.add("s", run)
    pool.step(0.01)  # window 1: one chunk stored
    ok[0] = False
    pool.step(0.01)
    assert isinstance(pool.broken.get("s"), FenceLost)
    assert pool.step(0.01) == []  # never reported complete
    assert [p.name for _, _, p in run.store.chunks()] == ["0-2.g3.npz"]


class _Points:
    """A point store that knows nothing and whose saves fail while ``down``."""

    def __init__(self) -> None:
        self.down = False

    def lookup(self, keys: Any) -> dict[str, Any]:
        return {}

    def save(self, rows: Any, solver: Any, link: Any = None) -> None:
        if self.down:
            raise OSError(errno.EIO, "database away")

    def link(self, study_id: str, pairs: Any) -> None:
        pass


class _Pending(_Future):
    """A future that is done only when the test says so."""

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self.ready = False

    def done(self) -> bool:
        return self.ready

    def add_done_callback(self, fn: Any) -> None:
        pass


class _HoldingClient:
    def __init__(self) -> None:
        self.futures: list[_Pending] = []

    def submit(self, fn: Any, points: list[Any], *args: Any, **kw: Any) -> _Pending:
        self.futures.append(_Pending(len(points)))
        return self.futures[-1]

    def cancel(self, futures: Any, force: bool = False) -> None:
        pass


def test_a_failed_store_or_a_removed_run_never_leaves_a_chunk_waiting_for_ever(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two studies of the same points: the second's chunks wait for the first's tasks (claims).
    Storing fails, then the first study is removed (cancelled): the second's chunks go out again
    and it completes (the resume that hung for good)."""
    monkeypatch.setattr("distributed.Event", lambda *a, **k: type("E", (), {"set": lambda s: 0})())
    points = _Points()
    client = _HoldingClient()
    pool = ChunkPool(client, 8, hold=True, backoff_cap=0.05)
    a = StudyRun(parse_study(tiny_study(name="a", num=4, gaps=(0.1,))), tmp_path, chunk_size=2,
                 points=points)  # fmt: skip
    b = StudyRun(parse_study(tiny_study(name="b", num=4, gaps=(0.1,))), tmp_path, chunk_size=2,
                 points=points)  # fmt: skip
    pool.add("a", a)
    pool.add("b", b)
    pool.step(0.01)
    assert len(client.futures) == 2  # b's chunks wait for a's tasks: nothing submitted for b
    points.down = True
    client.futures[0].ready = True
    pool.step(0.01)  # a's first chunk cannot be stored; b's first chunk got its records
    assert "a" in pool.stalls
    pool.remove("a")  # cancelled, its second task never delivers
    points.down = False
    t0 = time.monotonic()
    while not b.complete:
        for f in client.futures:
            f.ready = True
        pool.step(0.01)
        assert time.monotonic() - t0 < 5, "b waits for ever"
    assert b.store.missing_ranges() == [] and b.done == 4
