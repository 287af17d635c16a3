"""The simulator of one point: the model, the solvers, the point engine (``worker.simulate``)."""

from worker.cpu import pin as _pin_cpu
from worker.numba_cache import configure as _configure_numba_cache

# First, before numba (and with it numpy and OpenBLAS) loads: the same BLAS kernels and compiled
# code on every x86-64 machine, so a point's numbers do not depend on the CPU (worker/cpu.py).
_pin_cpu()

# Before any kernel module is imported: numba's cache is keyed by the worker's source code.
NUMBA_CACHE = _configure_numba_cache()
