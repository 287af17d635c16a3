"""The solver core: settings and result, one measurement layout, the methods, the point engine.

``simulate.py`` (one level up) is the public door; this package is what it dispatches to.
"""

from worker.numba_cache import configure as _configure_numba_cache

# Before any kernel module is imported: numba's cache is keyed by the worker's source code.
NUMBA_CACHE = _configure_numba_cache()
