"""What the forkserver of :mod:`service.studies.forkserver` imports before it forks any
worker, so that every worker starts with it: the simulator, dask.distributed and, when numba's
cache holds them, the default method's kernels (a study of another method loads its own as each
worker starts, ``runner._load_at_start``). Nothing is compiled here: on a cold cache the process
that starts the cluster compiles, and the workers load what it wrote."""

import contextlib

import worker  # noqa: F401  # first: one BLAS thread and the pinned CPU, before numpy loads
from worker import simulate
from worker.solvers.settings import DEFAULT_METHOD

# isort: split
import distributed  # noqa: F401  # what every worker imports

# An error here would end the forkserver and with it every worker start; a worker that finds
# no kernels loads them itself (and reports what fails where a task can say it).
with contextlib.suppress(Exception):
    if simulate.cache_ready(DEFAULT_METHOD):
        simulate.warm_up(DEFAULT_METHOD, quiet=True)
