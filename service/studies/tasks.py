"""What a dask worker runs for a study: one chunk task, and the cancel probe it polls.

Kept apart from the runner on purpose: a worker imports the module of the function it is sent,
and this one needs only ``worker`` (and ``distributed``, which the worker has loaded already),
not the runner's study schema, datasets and point store (xarray, pandas, scipy.sparse,
pydantic: ~1.3 s of imports per worker process before its first point).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from worker.cpu import check_target
from worker.simulate import simulate_chunk, simulate_line

__all__ = ["CANCEL_POLL_S", "CancelProbe", "chunk_task", "compute_chunk"]

CANCEL_POLL_S = 1.0  # how often a running task asks whether its study was cancelled


class CancelProbe:
    """Runs inside a task: whether the task's study was cancelled (a ``distributed.Event``),
    asked at most every ``CANCEL_POLL_S`` seconds so the scheduler is not flooded."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._event: Any = None
        self._next = 0.0
        self._set = False

    def __call__(self) -> bool:
        now = time.monotonic()
        if self._set or now < self._next:
            return self._set
        self._next = now + CANCEL_POLL_S
        try:
            if self._event is None:
                from distributed import Event

                self._event = Event(self.name)
            self._set = bool(self._event.is_set())
        except Exception:  # noqa: BLE001 - no scheduler to ask (a local call): not cancelled
            self._set = False
        return self._set

    def __getstate__(self) -> dict[str, Any]:
        return {"name": self.name}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["name"])  # type: ignore[misc]


def chunk_task(
    points: list[dict[str, Any]],
    solver: dict[str, Any],
    limits: dict[str, Any],
    cancel_event: str,
    line: bool = False,
    target: dict[str, str] | None = None,
) -> list[dict[str, Any]]:
    """One dask task: :func:`compute_chunk` with the study's cancel event polled inside.

    ``target`` is the submitting process's ``worker.cpu.fingerprint()``: a worker that would
    compute other bits (another CPU target or library stack) raises ``TargetMismatch`` naming
    the difference and computes nothing."""
    check_target(target)
    return compute_chunk(points, solver, limits, CancelProbe(cancel_event), line)


def compute_chunk(
    points: list[dict[str, Any]],
    solver: dict[str, Any],
    limits: dict[str, Any],
    cancel: Callable[[], bool],
    line: bool = False,
) -> list[dict[str, Any]]:
    """A chunk's records, here or on a worker: ``simulate_chunk``, or ``simulate_line`` for one
    sweep line (each point starts from the one before)."""
    run = simulate_line if line else simulate_chunk
    return run(points, solver, limits, cancel)
