"""Start an embedded cluster's worker processes by forking one that has loaded everything.

By default dask *spawns* each worker process: a fresh interpreter that imports dask.distributed
and the simulator and loads the numba kernels (~2 s of CPU each on the 2-core reference
machine, about half of it numba loading its typing registries, which imports scipy.linalg).
With :func:`start`, a multiprocessing *forkserver* does that once, and each worker is a fork of
it that starts with the kernels in memory. The forkserver is itself a fresh single-threaded
interpreter (not a fork of this threaded process), so forking it is safe; it exits with this
process.

Started early (``impactcell run`` and ``nightly`` call :func:`start` before their own imports),
the forkserver imports on the core this process leaves idle while it imports and reads the
study: Figure 5's cluster was ready 2.8–3.3 s after ``make_client`` was called, now 0.5–0.6 s,
and the run took 18.7 s instead of 22.3 s (medians of 5 interleaved pairs,
``benchmarks/run_command.py``). ``make_client`` calls :func:`start` too, so a cluster made
without the early call (the service's) still forks its workers.

A user's choice of ``distributed.worker.multiprocessing-method`` (its environment variable, or
a value other than dask's default, ``spawn``: ``dask_settings.user_set``) stands, and so does
spawning on a platform without forkserver (Windows).
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from multiprocessing import forkserver

from service.studies.dask_settings import user_set

__all__ = ["PRELOAD", "start"]

METHOD_KEY = "distributed.worker.multiprocessing-method"
PRELOAD = "service.studies.forkserver_preload"  # the module the forkserver imports first
_lock = threading.Lock()
_started: bool | None = None  # None: not tried yet


def start() -> bool:
    """Start the forkserver (if not done yet, and not overruled) and make dask's nannies use
    it. True when this process's embedded clusters fork their workers from it."""
    global _started
    with _lock:
        if _started is None:
            _started = _start()
        return _started


def _start() -> bool:
    import dask

    if user_set(METHOD_KEY) or "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    # What dask sets in the nanny's environment before it spawns a worker (glibc's trim
    # threshold: it must be there when the process starts) must be in the forkserver's, which
    # its forks inherit. A variable already set stands, as in dask. (One BLAS thread: the
    # preload imports worker first, which pins it, as in every process.)
    env = dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {}
    for key, value in env.items():
        if value is not None:
            os.environ.setdefault(key, str(value))
    multiprocessing.get_context("forkserver").set_forkserver_preload([PRELOAD])
    try:
        forkserver.ensure_running()
    except OSError:  # no process could start: the nannies spawn (and say what fails)
        return False
    dask.config.set({METHOD_KEY: "forkserver"})
    return True
