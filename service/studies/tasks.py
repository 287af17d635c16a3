"""What a dask worker runs for a study: one chunk task, and the cancel probe it polls.

Kept apart from the runner on purpose: a worker imports the module of the function it is sent,
and this one needs only ``worker`` (and ``distributed``, which the worker has loaded already),
not the runner's study schema, datasets and point store (xarray, pandas, scipy.sparse,
pydantic: ~1.3 s of imports per worker process before its first point).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

from worker.cpu import check_target
from worker.simulate import simulate_chunk, simulate_line

__all__ = ["CANCEL_POLL_S", "CancelProbe", "Points", "Records", "chunk_task", "compute_chunk"]

CANCEL_POLL_S = 1.0  # how often a running task asks whether its study was cancelled


class Records(list):  # type: ignore[type-arg]
    """A chunk task's records: a list, sent back as one pickle.

    dask.distributed serialises a plain ``list`` result element by element (a header and a
    frame per record, each read and unpickled on its own); a subclass of ``list`` it pickles
    whole. For Figure 5's chunks of 96 records that was ~4 ms of the worker's and ~5 ms of the
    command's CPU per task. The records are the same dicts either way."""

    __slots__ = ()


class Points:
    """A chunk task's points on their way to a worker: one opaque object to dask.

    dask walks a task's arguments, container by container, for futures in them, in the
    process that submits and again on the scheduler; a list of 96 point dicts was ~1.6 ms of
    the command's CPU per task (Figure 5's chunks). The points are the same dicts."""

    __slots__ = ("items",)

    def __init__(self, items: list[dict[str, Any]]) -> None:
        self.items = items

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return iter(self.items)

    def __getstate__(self) -> list[dict[str, Any]]:
        return self.items

    def __setstate__(self, items: list[dict[str, Any]]) -> None:
        self.items = items


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
    points: Points | list[dict[str, Any]],
    solver: dict[str, Any],
    limits: dict[str, Any],
    cancel_event: str,
    line: bool = False,
    target: dict[str, str] | None = None,
) -> Records:
    """One dask task: :func:`compute_chunk` with the study's cancel event polled inside (the
    points as :class:`Points` or a list, the records as :class:`Records`).

    ``target`` is the submitting process's ``worker.cpu.fingerprint()``: a worker that would
    compute other bits (another CPU target or library stack) raises ``TargetMismatch`` naming
    the difference and computes nothing."""
    check_target(target)
    pts = points.items if isinstance(points, Points) else points
    return Records(compute_chunk(pts, solver, limits, CancelProbe(cancel_event), line))


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
