"""How many functions numba compiles for a method's kernels, and how long that takes, on an
empty cache (the denominator of the first compilation's progress line:
``worker.compile_progress.COMPILED_FUNCTIONS``)::

    python benchmarks/compile_count.py [event|exponential|euler]
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time


def main(method: str) -> None:
    """Compile ``method``'s kernels into an empty cache; print the count and the seconds."""
    with tempfile.TemporaryDirectory() as cache:
        os.environ["NUMBA_CACHE_DIR"] = cache  # before numba loads: nothing comes from a cache
        import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py)
        from worker.compile_progress import compile_progress
        from worker.simulate import warm_up

        t0 = time.perf_counter()
        with compile_progress(method, every_s=float("inf")) as progress:
            warm_up(method, quiet=True)
        seconds = round(time.perf_counter() - t0, 1)
    print(json.dumps({"method": method, "functions": progress.done, "seconds": seconds}))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "event")
