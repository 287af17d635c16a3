"""Test-wide setup: cached bytecode, one BLAS thread, and the test tiers."""

import gc
import importlib
import os
import sys

import pytest

# This machine (and CI's) sets PYTHONDONTWRITEBYTECODE: every test process would then compile
# the service's modules and re-rewrite every test module's asserts on every run (~8 s of each
# process's ~17 s of collection), and so would every server, CLI and worker process a test
# starts. The caches go to __pycache__ folders, which git ignores.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

# The kernels and references are small dense problems: a multi-threaded BLAS only contends with
# the dask worker processes on a 2-core machine (scipy's expm ran 40x slower under load with it).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# Before numpy loads OpenBLAS, like the thread count: the same BLAS kernels and compiled code on
# every x86-64 machine, so the numbers the tests check do not depend on the CPU (worker/cpu.py).
import worker  # noqa: E402, F401

# numpy (and its OpenBLAS) loads pinned now: tests/worker/test_cpu.py asks this process's copy.
importlib.import_module("numpy")

# --------------------------------------------------------------------------- test tiers

# ``pytest -n 2 -m "not slow"`` is the developer loop (its time: README.md); CI runs everything.
# A test that uses one of these fixtures starts a real dask cluster, so it is slow wherever it
# lives; servers, subprocesses and whole studies are marked where they are written.
CLUSTER_FIXTURES = frozenset({"dask_address", "cluster_client"})


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if CLUSTER_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


def pytest_collection_finish(session: pytest.Session) -> None:
    # What collection built (the service, hypothesis, xarray, every test item: ~3e5 objects)
    # lives to the end: out of the garbage collector's sight, each full collection during the
    # tests, and pytest's five at the end of the session, no longer walk it all.
    gc.freeze()


# --------------------------------------------------------------------------- kernels


@pytest.fixture(scope="session", autouse=True)
def _each_method_compiled_once() -> None:
    """Under pytest-xdist (``-n 2``, the README's test command) each test process would
    compile every kernel it meets, all at once on a fresh cache (CI: ~1 min of CPU each). Each
    process warms every method up first, starting from a different one: the first to reach a
    method compiles it while the other compiles another, and a process that reaches a method
    being compiled waits for it (``worker.numba_cache.exclusive``) and loads it."""
    name = os.environ.get("PYTEST_XDIST_WORKER")
    if not name:
        return
    from worker.simulate import METHODS, warm_up

    k = int(name.removeprefix("gw")) % len(METHODS)
    for method in METHODS[k:] + METHODS[:k]:
        warm_up(method, quiet=True)
