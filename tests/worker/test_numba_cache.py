"""numba's cache is keyed by the worker's source code, so no kernel runs stale machine code."""

import threading
import time
from pathlib import Path

from numba.core import config

import worker
from worker import numba_cache


def test_the_kernels_cache_under_the_source_keyed_folder():
    from worker.simulate import _kernel

    assert worker.NUMBA_CACHE is not None
    assert Path(worker.NUMBA_CACHE).name == f"numba-{numba_cache.source_key()}"
    assert config.CACHE_DIR == worker.NUMBA_CACHE
    cache_path = Path(_kernel("event")._cache._cache_path)
    assert Path(worker.NUMBA_CACHE) in cache_path.parents


def test_any_change_in_any_worker_file_changes_the_key(tmp_path, monkeypatch):
    (tmp_path / "solvers").mkdir()
    (tmp_path / "solvers" / "roots.py").write_text("def f():\n    return 1\n")
    (tmp_path / "kernel.py").write_text("from solvers.roots import f\n")
    monkeypatch.setattr(numba_cache, "_ROOT", tmp_path)
    first = numba_cache.source_key()
    assert numba_cache.source_key() == first  # deterministic
    # a callee in another file changes: numba's own check would not notice, the key does
    (tmp_path / "solvers" / "roots.py").write_text("def f():\n    return 2\n")
    assert numba_cache.source_key() != first


def test_configure_uses_numba_cache_dir_as_the_base(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)  # restored after the test
    got = numba_cache.configure()
    assert got == str(tmp_path / f"numba-{numba_cache.source_key()}")
    assert Path(got).is_dir() and got == config.CACHE_DIR


def test_an_unwritable_base_leaves_numba_its_default(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(config, "CACHE_DIR", "unchanged")
    monkeypatch.setattr(numba_cache, "_writable", lambda directory: False)
    assert numba_cache.configure() is None
    assert config.CACHE_DIR == "unchanged"


def _enter_in_a_thread(name: str, events: list[str]) -> threading.Thread:
    def enter() -> None:
        with numba_cache.exclusive(name, lambda: events.append("waiting")):
            events.append("inside")

    t = threading.Thread(target=enter, daemon=True)
    t.start()
    return t


def test_exclusive_holds_a_second_holder_until_the_first_is_done(tmp_path, monkeypatch):
    # flock locks belong to open files, so a thread with its own open file stands for a second
    # process sharing the cache
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path))
    events: list[str] = []
    with numba_cache.exclusive("warm-x"):
        t = _enter_in_a_thread("warm-x", events)
        deadline = time.monotonic() + 30  # a loaded machine may start the thread late
        while not events and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.1)  # time to get in, if the lock did not hold it
        assert events == ["waiting"] and t.is_alive()
        other: list[str] = []
        _enter_in_a_thread("warm-y", other).join(5)  # another name is another lock
        assert other == ["inside"]
    t.join(5)
    assert events == ["waiting", "inside"]
    assert (tmp_path / "warm-x.lock").exists()


def test_exclusive_without_a_cache_directory_holds_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(config, "CACHE_DIR", "")
    events: list[str] = []
    with numba_cache.exclusive("warm-x"):
        _enter_in_a_thread("warm-x", events).join(5)
    assert events == ["inside"]
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "missing"))  # cannot open: no lock
    with numba_cache.exclusive("warm-x"):
        _enter_in_a_thread("warm-x", events).join(5)
    assert events == ["inside", "inside"]
