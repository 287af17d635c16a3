"""The nightly regression suite on a cron schedule, run once per slot across service processes.

Each service process with ``IMPACTCELL_NIGHTLY_CRON`` set runs a small thread that sleeps until
the next slot of the expression. At the slot, every process tries to take the catalogue lease
``nightly:<slot time>``; only the one that gets it runs the suite, so N processes on one
catalogue still run it once per slot. The run itself is the service's
(:class:`service.api.nightly.NightlyRunner`: the suite's studies go through the service's own
job queue and cluster). The report is stored in the catalogue (``GET /regressions``) and the
latest outcome shows in ``GET /health``.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import socket
import threading
import uuid
from collections.abc import Callable
from typing import Any

from service.api.catalogue import Catalogue
from service.api.settings import Settings, validate_cron

__all__ = ["NightlyScheduler", "next_slot", "record_run", "run_nightly_once"]

log = logging.getLogger("impactcell.schedule")

LEASE_TTL_S = 24 * 3600.0  # a slot's lease outlives any run of the suite


def next_slot(expr: str, after: dt.datetime) -> dt.datetime:
    """The first time strictly after ``after`` that matches the cron expression (UTC)."""
    from croniter import croniter

    return croniter(validate_cron(expr), after).get_next(dt.datetime)


def run_nightly_once(
    catalogue: Catalogue,
    slot: dt.datetime,
    holder: str,
    run: Callable[[], dict[str, Any]],
    trigger: str = "cron",
) -> int | None:
    """Run the suite for ``slot`` if this holder wins its lease; returns the report id or None."""
    lease = f"nightly:{slot.astimezone(dt.UTC).isoformat(timespec='minutes')}"
    if not catalogue.acquire_lease(lease, holder, LEASE_TTL_S):
        log.info("nightly %s: another process holds the lease", lease)
        return None
    reg_id = catalogue.add_regression(trigger)
    record_run(catalogue, reg_id, run)
    return reg_id


def record_run(catalogue: Catalogue, reg_id: int, run: Callable[[], dict[str, Any]]) -> None:
    """Run the suite and store its outcome as regression run ``reg_id`` (created before).

    ``run`` returns ``{"ok": bool, "report": dict, "markdown": str}``; an exception is recorded
    as a run that could not happen (``ok`` false, with the error), never raised.
    """
    try:
        out = run()
    except Exception as exc:  # noqa: BLE001 - recorded as the run's outcome
        log.exception("nightly run failed")
        error = f"{type(exc).__name__}: {exc}"
        catalogue.finish_regression(
            reg_id, ok=False, summary="the suite could not run", error=error
        )
        return
    report = out.get("report") or {}
    summary = report.get("summary") or ("no regressions" if out["ok"] else "regressions found")
    catalogue.finish_regression(
        reg_id, ok=bool(out["ok"]), summary=str(summary), report=report,
        markdown=out.get("markdown", ""),
    )  # fmt: skip


class NightlyScheduler:
    """A thread that runs the suite at every slot of ``settings.nightly_cron``.

    ``run`` runs the suite once and returns its outcome (the service passes
    :meth:`service.api.nightly.NightlyRunner.run`).
    """

    def __init__(
        self,
        settings: Settings,
        catalogue: Catalogue,
        run: Callable[[], dict[str, Any]],
        clock: Callable[[], dt.datetime] | None = None,
    ) -> None:
        if not settings.nightly_cron:
            raise ValueError("nightly_cron is not set")
        self.expr = settings.nightly_cron
        self.catalogue = catalogue
        self.run = run
        self.clock = clock or (lambda: dt.datetime.now(dt.UTC))
        self.holder = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="impactcell-nightly", daemon=True)
        self.runs: list[int] = []  # report ids this process produced

    def start(self) -> None:
        """Start the schedule thread."""
        self._thread.start()

    def stop(self) -> None:
        """Stop waiting for the next slot (a run in progress finishes first)."""
        self._stop.set()
        self._thread.join(5)

    def _loop(self) -> None:
        slot = next_slot(self.expr, self.clock())
        while not self._stop.is_set():
            wait = (slot - self.clock()).total_seconds()
            if wait > 0:
                self._stop.wait(min(wait, 60.0))  # re-check the clock at least every minute
                continue
            rid = run_nightly_once(self.catalogue, slot, self.holder, self.run)
            if rid is not None:
                self.runs.append(rid)
            slot = next_slot(self.expr, max(self.clock(), slot))
