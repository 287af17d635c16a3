"""The simulator of one point: the model, the solvers, the point engine (``worker.simulate``).

Importing the package pins the CPU target and nothing more (no numpy, no numba): the service
package imports it first, and so does the light Python client (``service.client``).
"""

from __future__ import annotations

from typing import Any

from worker.cpu import pin as _pin_cpu

# First, before numba (and with it numpy and OpenBLAS) loads: the same BLAS kernels and compiled
# code on every x86-64 machine, so a point's numbers do not depend on the CPU (worker/cpu.py).
_pin_cpu()


def __getattr__(name: str) -> Any:
    # numba's cache folder is chosen where the kernels live (worker/solvers/__init__.py), so a
    # process that never simulates never loads numba.
    if name == "NUMBA_CACHE":
        from worker.solvers import NUMBA_CACHE

        return NUMBA_CACHE
    raise AttributeError(f"module 'worker' has no attribute {name!r}")
