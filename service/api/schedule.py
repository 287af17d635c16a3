"""The nightly regression suite on a cron schedule, run once per slot across service processes.

Each service process with ``IMPACTCELL_NIGHTLY_CRON`` set runs a small thread that sleeps until
the next slot of the expression. At the slot, every process tries to take the catalogue lease
``nightly:<slot time>``; only the one that gets it runs the suite, so N processes on one
catalogue still run it once per slot. The run itself is the service's
(:class:`service.api.nightly.NightlyRunner`: the suite's studies go through the service's own
job queue and cluster). The report is stored in the catalogue (``GET /regressions``) and the
latest outcome shows in ``GET /health``.

While a run goes on, its process holds the catalogue lease ``nightly-run:<id>`` and renews it
(a heartbeat). A run whose process died leaves its row without an outcome; the next service
start (:func:`recover_interrupted`) ends such a row as not ok and ``interrupted`` once its lease
has expired or its holder is known to be dead, never while another live process runs it.
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

__all__ = [
    "PROCESS_HOLDER",
    "NightlyScheduler",
    "next_slot",
    "record_run",
    "recover_interrupted",
    "Heartbeat",
    "run_lease",
    "run_nightly_once",
]

log = logging.getLogger("impactcell.schedule")

LEASE_TTL_S = 24 * 3600.0  # a slot's lease outlives any run of the suite
RUN_LEASE_TTL_S = 120.0  # a run's heartbeat lease: renewed every third of this
# A run's row is written a moment before its lease is taken: a row without a lease is only
# taken for abandoned after this long.
RUN_LEASE_GRACE_S = 60.0
INTERRUPTED = "interrupted"

# This process as a lease holder: host, pid and a nonce (a restarted process may reuse the pid).
PROCESS_HOLDER = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def run_lease(reg_id: int) -> str:
    """The name of the heartbeat lease of regression run ``reg_id``."""
    return f"nightly-run:{int(reg_id)}"


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
    as a run that could not happen (``ok`` false, with the error), never raised. Meanwhile this
    process holds the run's heartbeat lease (:func:`run_lease`), so that no other process takes
    the run for interrupted.
    """
    with Heartbeat(catalogue, run_lease(reg_id)):
        _record(catalogue, reg_id, run)


def _record(catalogue: Catalogue, reg_id: int, run: Callable[[], dict[str, Any]]) -> None:
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


class Heartbeat:
    """Hold a lease and renew it every third of its lifetime until the block ends."""

    def __init__(self, catalogue: Catalogue, name: str, ttl_s: float | None = None) -> None:
        self.catalogue, self.name = catalogue, name
        self.ttl_s = RUN_LEASE_TTL_S if ttl_s is None else ttl_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name=f"heartbeat {name}", daemon=True)

    def __enter__(self) -> Heartbeat:
        self.catalogue.acquire_lease(self.name, PROCESS_HOLDER, self.ttl_s)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        try:
            self.catalogue.release_lease(self.name, PROCESS_HOLDER)
        except Exception:  # noqa: BLE001 - an unreleased lease just expires
            log.warning("could not release lease %s", self.name, exc_info=True)

    def _beat(self) -> None:
        while not self._stop.wait(self.ttl_s / 3):
            try:
                self.catalogue.acquire_lease(self.name, PROCESS_HOLDER, self.ttl_s)
            except Exception:  # noqa: BLE001 - a catalogue hiccup: try again at the next beat
                log.warning("could not renew lease %s", self.name, exc_info=True)


def _holder_dead(holder: str) -> bool:
    """Whether a lease holder is a process known to be gone (on this host only)."""
    host, _, rest = holder.partition(":")
    pid_text, _, nonce = rest.partition(":")
    if host != socket.gethostname() or not pid_text.isdigit():
        return False  # another host's process: only its lease's expiry tells
    if holder == PROCESS_HOLDER:
        return False
    pid = int(pid_text)
    if pid == os.getpid():
        return True  # this pid, another nonce: an earlier process that had our pid
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # exists, owned by someone else
        return False
    return False


def recover_interrupted(
    catalogue: Catalogue, now: dt.datetime | None = None
) -> tuple[list[int], dt.datetime | None]:
    """End the regression runs whose process died before they finished (service start).

    A run without an outcome is interrupted when its heartbeat lease has expired, its holder
    is a dead process of this host, or it has no lease and is older than a grace period. It is
    stored with ``ok`` false and a summary and error saying ``interrupted``.

    Returns the ids ended here, and when to look again (a run whose lease is still alive, held
    maybe by a process that has just died), or None.
    """
    now = now or dt.datetime.now(dt.UTC)
    ended: list[int] = []
    again: dt.datetime | None = None
    for rec in catalogue.unfinished_regressions():
        reg_id = int(rec["id"])
        lease = catalogue.lease(run_lease(reg_id))
        started = dt.datetime.fromisoformat(rec["started_at"])
        if lease is None:
            due = started + dt.timedelta(seconds=RUN_LEASE_GRACE_S)
            why = "no process holds it"
        else:
            due = lease["expires_at"]
            why = f"its process ({lease['holder']}) stopped renewing it"
            if _holder_dead(lease["holder"]):
                due, why = now, f"its process ({lease['holder']}) is gone"
        if due > now:
            again = due if again is None else min(again, due)
            continue
        error = (
            f"{INTERRUPTED}: the process running this nightly run ended before it finished "
            f"({why}); its studies may have run on, but nothing was compared"
        )
        markdown = (
            "# Nightly regression: INTERRUPTED\n\n"
            f"Started {rec['started_at']} ({rec['trigger']}); {error}.\n"
        )
        if catalogue.interrupt_regression(
            reg_id, summary=f"{INTERRUPTED}: the run did not finish", error=error,
            markdown=markdown,
        ):  # fmt: skip
            log.warning("nightly run %d marked interrupted: %s", reg_id, why)
            ended.append(reg_id)
    return ended, again


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
        self.holder = f"{PROCESS_HOLDER}:{uuid.uuid4().hex[:8]}"  # one per scheduler
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
