"""The simulator of one point: the model, the solvers, the point engine (``worker.simulate``)."""

from worker.numba_cache import configure as _configure_numba_cache

# Before any kernel module is imported: numba's cache is keyed by the worker's source code.
NUMBA_CACHE = _configure_numba_cache()
