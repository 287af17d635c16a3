"""A progress line while numba compiles a method's kernels for the first time on a machine.

A first compilation takes tens of seconds to minutes; without a word the user cannot tell a
compile from a hang. numba broadcasts a ``numba:compile`` event for every function it compiles
(its event API, ``numba.core.event``); counting them against the count a full compilation of
the method takes gives "how much is done".
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TextIO

__all__ = ["COMPILED_FUNCTIONS", "compile_progress"]

#: Functions a full compilation of each method compiles alone (numba's ``numba:compile`` events
#: of ``warm_up`` on an empty cache): the denominator of the progress line, so "about".
#: ``python benchmarks/compile_count.py METHOD`` counts them again.
COMPILED_FUNCTIONS = {"event": 238, "exponential": 136, "euler": 140}


class _Progress:
    """Counts compile events and says how far it is, at most every ``every_s`` seconds."""

    def __init__(self, method: str, out: TextIO, every_s: float) -> None:
        self.method, self.out, self.every_s = method, out, every_s
        self.total = COMPILED_FUNCTIONS.get(method, 0)
        self.done = 0
        self.t0 = time.perf_counter()
        self.last = self.t0
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.printed = False

    def compiled(self, name: str) -> None:
        self.done += 1
        now = time.perf_counter()
        if now - self.last < self.every_s:
            return
        self.last = now
        share = f" of about {self.total}" if self.total else ""
        line = (
            f"impactcell: compiling {self.method!r}: {self.done}{share} functions, "
            f"{now - self.t0:.0f} s ({name})"
        )
        if self.tty:  # one line, rewritten in place
            self.out.write("\r" + line[:120].ljust(120))
        else:
            self.out.write(line + "\n")
        self.out.flush()
        self.printed = True

    def close(self) -> None:
        if self.tty and self.printed:
            self.out.write("\r" + " " * 120 + "\r")
            self.out.flush()


@contextmanager
def compile_progress(
    method: str, out: TextIO | None = None, every_s: float = 2.0
) -> Iterator[_Progress]:
    """Within the block, report numba's compilations of ``method``'s kernels on ``out``
    (stderr): on a terminal one line rewritten in place, elsewhere a line every ``every_s``."""
    from numba.core import event

    progress = _Progress(method, out or sys.stderr, every_s)

    class _Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            pass

        def on_end(self, ev: Any) -> None:
            disp = (ev.data or {}).get("dispatcher")
            name = getattr(getattr(disp, "py_func", None), "__qualname__", "?")
            progress.compiled(str(name))

    try:
        with event.install_listener("numba:compile", _Listener()):
            yield progress
    finally:
        progress.close()
