"""Fencing tokens and retry backoff for a study's writes.

A service process runs a study while it holds the study's catalogue lease; each acquisition of
that lease by a new holder has a new *generation*, the fencing token. Every write the process
makes for the study (chunk files, point rows, record updates) checks at commit that the lease
still has that generation, so a process that was paused or cut off past the lease's expiry,
while another took the study over, cannot write once it wakes up: its check raises
:class:`FenceLost` and it stops running the study.

Writes that fail for a passing reason (the database unreachable, the disk full or read-only:
:func:`is_transient`) are retried with :class:`Backoff`, never dropped.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["Backoff", "Fence", "FenceLost", "is_transient"]


class FenceLost(RuntimeError):
    """This process's fencing token for a study is stale: another process runs it now."""


@dataclass(frozen=True)
class Fence:
    """A study's fencing token and the check that it is still current (raises
    :class:`FenceLost` when it is not)."""

    token: int
    check: Callable[[], None]


def is_transient(exc: BaseException) -> bool:
    """Whether a failed write may succeed later: an ``OSError`` (disk full, read-only, I/O) or
    a database connection error (SQLAlchemy's ``OperationalError`` / ``InterfaceError``, or a
    connection it invalidated)."""
    if isinstance(exc, FenceLost):
        return False
    if isinstance(exc, OSError):
        return True
    try:
        from sqlalchemy import exc as sa_exc
    except ImportError:  # pragma: no cover - the service always has it
        return False
    if isinstance(exc, sa_exc.OperationalError | sa_exc.InterfaceError):
        return True
    return isinstance(exc, sa_exc.DBAPIError) and bool(exc.connection_invalidated)


@dataclass
class Backoff:
    """Exponential backoff with jitter: ``first`` s, doubling up to ``cap`` s between tries.

    ``due()`` says whether the next try may run; ``failed()`` schedules the one after; ``ok()``
    starts over. ``elapsed()`` is the time since the first failure of the current streak.
    """

    first: float = 0.5
    cap: float = 30.0
    clock: Callable[[], float] = time.monotonic
    tries: int = 0
    since: float | None = None
    next_at: float = 0.0
    _rng: random.Random = field(default_factory=random.Random, repr=False)

    def delay(self) -> float:
        """The wait after the current number of failed tries (before jitter)."""
        return min(self.cap, self.first * 2 ** max(0, self.tries - 1))

    def failed(self) -> float:
        """Count a failed try; returns the wait before the next one."""
        now = self.clock()
        if self.since is None:
            self.since = now
        self.tries += 1
        # Up to 20 % less, so processes that failed together do not retry together.
        wait = self.delay() * (1.0 - 0.2 * self._rng.random())
        self.next_at = now + wait
        return wait

    def due(self) -> bool:
        """Whether the next try may run now."""
        return self.clock() >= self.next_at

    def ok(self) -> None:
        """A try succeeded: the next failure starts a new streak."""
        self.tries = 0
        self.since = None
        self.next_at = 0.0

    def elapsed(self) -> float:
        """Seconds since the first failure of the current streak (0 when none)."""
        return 0.0 if self.since is None else self.clock() - self.since
