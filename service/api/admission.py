"""Admission control for heavy reads: a bounded pool of their own, a bounded queue, then 503.

Plots, datasets, slices, maps, ``/points`` pages and ``/timeseries`` take from milliseconds to
tens of seconds each. Run in the server's shared thread pool, a burst of them would take every
thread and leave ``/health`` and the light routes waiting behind them. Routes marked
:func:`heavy` run instead in :class:`Admission`'s pool of ``Settings.heavy_pool_size()``
threads; at most ``Settings.heavy_queue`` more wait for it, and a request beyond that is
answered at once with 503 and a ``Retry-After`` from the recent durations.
"""

from __future__ import annotations

import asyncio
import functools
import inspect
import logging
import math
import threading
import time
import typing
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from fastapi import HTTPException, Request

__all__ = ["Admission", "heavy"]

F = TypeVar("F", bound=Callable[..., Any])
log = logging.getLogger("impactcell.admission")
_REQUEST = "_admission_request"  # the parameter heavy() adds to find the app's pool


class Admission:
    """A pool of ``workers`` threads that admits ``workers + queue`` requests at once."""

    def __init__(self, workers: int, queue: int) -> None:
        self.workers = workers
        self.limit = workers + queue
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="impactcell-heavy")
        self._lock = threading.Lock()
        self._admitted = 0
        self._mean_s = 1.0  # recent duration of one request (exponential average)

    @property
    def admitted(self) -> int:
        """Requests running or waiting in the pool."""
        return self._admitted

    def retry_after(self) -> int:
        """Seconds after which a refused request has a fair chance (1…60)."""
        waves = math.ceil(max(self._admitted, 1) / self.workers)
        return int(min(60, max(1, math.ceil(waves * self._mean_s))))

    async def run(self, fn: Callable[[], Any]) -> Any:
        """``fn()`` in the pool, or 503 with ``Retry-After`` when the queue is full."""
        with self._lock:
            if self._admitted >= self.limit:
                wait = self.retry_after()
                raise HTTPException(
                    503,
                    f"busy: {self._admitted} heavy requests (plots, datasets, slices, time "
                    f"series) are running or queued, the most this service takes; retry in "
                    f"{wait} s",
                    headers={"Retry-After": str(wait)},
                )
            self._admitted += 1
        try:
            future = self._pool.submit(self._timed, fn)
        except RuntimeError:  # the pool is shut down: the service is stopping
            self._release(None)
            raise HTTPException(
                503, "the service is stopping", headers={"Retry-After": "5"}
            ) from None
        # Released when the work ends, not when the request does: a client that hangs up
        # does not stop its work in the pool, which still counts.
        future.add_done_callback(self._release)
        return await asyncio.wrap_future(future)

    def _release(self, _future: Any) -> None:
        with self._lock:
            self._admitted -= 1

    def _timed(self, fn: Callable[[], Any]) -> Any:
        t0 = time.monotonic()
        try:
            return fn()
        finally:
            self._mean_s = 0.8 * self._mean_s + 0.2 * (time.monotonic() - t0)

    def prepare(self, fn: Callable[[], Any]) -> None:
        """Run ``fn`` in the pool ahead of the requests (a warm-up: imports, caches); its
        errors are logged, never raised."""

        def run() -> None:
            try:
                fn()
            except Exception:  # a warm-up that fails leaves the first request to pay
                log.exception("warm-up of the heavy-read pool failed")

        self._pool.submit(run)

    def close(self) -> None:
        """Stop taking work; requests in the pool finish."""
        self._pool.shutdown(wait=False, cancel_futures=True)


def heavy(fn: F) -> F:
    """Run a synchronous route in the app's :class:`Admission` pool (``app.state.admission``).

    The route keeps its signature (its parameters, dependencies and OpenAPI description) plus
    one ``Request`` parameter, by which the pool is found.
    """
    hints = typing.get_type_hints(fn, include_extras=True)  # the route module's names
    sig = inspect.signature(fn)
    params = [
        p.replace(annotation=hints.get(p.name, p.annotation)) for p in sig.parameters.values()
    ]
    # FastAPI passes the request to one parameter only: the route's own if it has one.
    own = next((p.name for p in params if p.annotation is Request), None)
    if own is None:
        params.append(
            inspect.Parameter(_REQUEST, inspect.Parameter.KEYWORD_ONLY, annotation=Request)
        )

    @functools.wraps(fn)
    async def run(*args: Any, **kwargs: Any) -> Any:
        request: Request = kwargs[own] if own else kwargs.pop(_REQUEST)
        admission: Admission = request.app.state.admission
        return await admission.run(functools.partial(fn, *args, **kwargs))

    run.__signature__ = sig.replace(  # type: ignore[attr-defined]
        parameters=params, return_annotation=hints.get("return", sig.return_annotation)
    )
    del run.__wrapped__  # FastAPI reads __signature__, not the wrapped route's
    run.__heavy__ = True  # type: ignore[attr-defined]  # OpenAPI lists its 503
    return typing.cast(F, run)
