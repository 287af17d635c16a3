"""The dispatch table: method name → its kernel run (one entry per method of ``METHODS``)."""

from __future__ import annotations

from worker.solvers.base import KernelRun
from worker.solvers.euler import EulerRun
from worker.solvers.event.driver import EventRun
from worker.solvers.exponential import ExponentialRun
from worker.solvers.settings import METHODS

RUNS: dict[str, type[KernelRun]] = {
    "event": EventRun,
    "exponential": ExponentialRun,
    "euler": EulerRun,
}
assert tuple(sorted(RUNS)) == tuple(sorted(METHODS)), "every method needs a run"

# The compiled kernel behind each method (what warm-up compiles or loads from numba's cache).
KERNELS = {
    "event": "worker.solvers.event.kernel:event_kernel",
    "exponential": "worker.solvers.exponential:exponential_kernel",
    "euler": "worker.solvers.euler:euler_kernel",
}
