"""The forkserver that an embedded cluster's workers are forked from (service.studies.forkserver):
when it starts, what it passes on, and that a user's choice stands. The real cluster's side
(workers forked, with the kernels and the environment) is in test_runner.py."""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import dask
import pytest

from service.studies import forkserver
from service.studies.dask_settings import env_name

KEY = forkserver.METHOD_KEY


@pytest.fixture
def fresh(monkeypatch) -> Iterator[list[list[str]]]:
    """A process where start() was never called, whose dask config and environment are
    restored afterwards, and where starting the forkserver only records its preload."""
    import distributed  # noqa: F401  # its defaults

    monkeypatch.setattr(forkserver, "_started", None)
    monkeypatch.delenv(env_name(KEY), raising=False)
    for var in dask.config.get("distributed.nanny.pre-spawn-environ"):  # put back afterwards
        if var in os.environ:
            monkeypatch.setenv(var, os.environ[var])
        else:
            monkeypatch.delenv(var, raising=False)
    started: list[list[str]] = []
    ctx = multiprocessing.get_context("forkserver")
    monkeypatch.setattr(ctx, "set_forkserver_preload", lambda mods: started.append(list(mods)))
    monkeypatch.setattr(forkserver.forkserver, "ensure_running", lambda: started.append(["run"]))
    with dask.config.set({KEY: "spawn"}):  # dask's default; the value before is put back
        yield started


def test_the_forkserver_starts_once_with_the_preload_and_dask_uses_it(fresh, monkeypatch) -> None:
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # set by the user: stands, as in dask
    assert dask.config.get(KEY) == "spawn"
    assert forkserver.start() is True
    assert forkserver.start() is True
    assert fresh == [[forkserver.PRELOAD], ["run"]]  # one forkserver, told what to load
    assert dask.config.get(KEY) == "forkserver"
    # dask's pre-spawn environment is in the forkserver's, which its forks inherit
    spawn_env: dict[str, Any] = dask.config.get("distributed.nanny.pre-spawn-environ")
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == str(spawn_env["MALLOC_TRIM_THRESHOLD_"])
    assert os.environ["OMP_NUM_THREADS"] == "3"


@pytest.mark.parametrize("how", ["environment", "config"])
def test_a_users_multiprocessing_method_stands(fresh, monkeypatch, how: str) -> None:
    if how == "environment":
        # even dask's default, when the user names it, is the user's choice
        monkeypatch.setenv(env_name(KEY), "spawn")
        expected = "spawn"
    else:
        dask.config.set({KEY: "fork"})
        expected = "fork"
    assert forkserver.start() is False
    assert fresh == []
    assert dask.config.get(KEY) == expected


def test_a_forkserver_that_cannot_start_leaves_dask_spawning(fresh, monkeypatch) -> None:
    def no_process() -> None:
        raise OSError("out of processes")

    monkeypatch.setattr(forkserver.forkserver, "ensure_running", no_process)
    assert forkserver.start() is False
    assert dask.config.get(KEY) == "spawn"


@pytest.mark.slow  # a fresh interpreter loads the kernels
def test_the_preload_loads_the_default_methods_kernels_from_a_ready_cache() -> None:
    # What the forkserver imports by name; its forks start with what it loaded.
    code = (
        "from worker import simulate\n"
        "from worker.solvers.settings import DEFAULT_METHOD\n"
        "simulate.fill_cache(DEFAULT_METHOD)\n"
        "simulate._warm.clear()  # as a fresh forkserver, which loads from the cache\n"
        f"import {forkserver.PRELOAD}\n"
        "print(sorted(simulate._warm), DEFAULT_METHOD)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=600
    ).stdout.split()
    assert out[:-1] == [f"['{out[-1]}']"]
