"""Settings: one pydantic-settings object, from ``IMPACTCELL_*`` variables and the CLI.

The only place that reads ``IMPACTCELL_*`` variables (the Python client, which may not import
the service, reads ``IMPACTCELL_API_TOKEN`` itself). The service reads it once at start; every
command of the CLI builds one from the environment and its flags (a flag wins over the
environment, the environment over the default) and passes its values down.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import Field, ValidationInfo, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from worker.limits import POINT_STEPS, POINT_STEPS_MAX, POINT_WALL_S, POINT_WALL_S_MAX

if TYPE_CHECKING:
    from worker.solvers.settings import PointLimits

__all__ = ["DEFAULT_PORT", "DEFAULT_URL", "Settings", "validate_cron"]

DEFAULT_PORT = 8000
DEFAULT_URL = f"http://127.0.0.1:{DEFAULT_PORT}"
_ORIGIN = re.compile(r"https?://[A-Za-z0-9.\-\[\]:]+/?")
_HOST = re.compile(r"\*|(\*\.)?[A-Za-z0-9.\-]+|\[?[0-9A-Fa-f:]+\]?")


def _split(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def validate_cron(expr: str) -> str:
    """A standard 5-field cron expression (minute hour day month weekday), normalised."""
    from croniter import croniter

    text = " ".join(str(expr).split())
    if len(text.split(" ")) != 5 or not croniter.is_valid(text):
        raise ValueError(
            f"nightly_cron must be a 5-field cron expression (minute hour day-of-month month "
            f"day-of-week), e.g. '0 2 * * *'; got {expr!r}"
        )
    return text


class Settings(BaseSettings):
    """Everything the service reads from its environment (prefix ``IMPACTCELL_``).

    Command-line options override these.
    """

    model_config = SettingsConfigDict(env_prefix="IMPACTCELL_", extra="ignore")

    host: str = "127.0.0.1"
    port: int = Field(DEFAULT_PORT, ge=0, le=65535)
    data_dir: Path = Path("data")  # the store's default root too (service.studies.chunks)
    # Any SQLAlchemy URL; default: a SQLite file in the data dir.
    database_url: str | None = None
    # tcp://host:port of a dask scheduler; default: an embedded LocalCluster.
    scheduler: str | None = None
    workers: int | None = Field(None, ge=1, description="processes of the embedded cluster")
    # When set, every route except /health needs "Authorization: Bearer <token>".
    api_token: str | None = None
    max_body_bytes: int = Field(1_000_000, ge=1024)
    # Grid-size limit of a study; unset = service.studies.limits.DEFAULT_MAX_POINTS.
    max_points: int | None = Field(None, ge=1)
    # Cron expression (5 fields) for the nightly regression suite; unset = no schedule.
    nightly_cron: str | None = None
    # The suite the service runs (cron, POST /regressions), its baselines in ../baselines;
    # unset = the shipped suite (service.studies.shipped).
    nightly_dir: Path | None = None
    # The service the CLI's client commands (submit, status) talk to.
    url: str = DEFAULT_URL
    # Budget of one point (worker.simulate.PointLimits): over it, the point is failed with
    # the reason, so one pathological point never holds a worker for long.
    point_time_limit_s: float = Field(POINT_WALL_S, gt=0, le=POINT_WALL_S_MAX)
    point_step_limit: int = Field(POINT_STEPS, ge=1, le=POINT_STEPS_MAX)
    # Wall-time budget of one /timeseries recomputation (run on the cluster, then cached).
    timeseries_time_limit_s: float = Field(60.0, gt=0, le=3600)
    # Studies run at once, sharing the cluster chunk by chunk (the rest wait in order).
    max_running_studies: int = Field(4, ge=1, le=64)
    # A running study belongs to one service process: its lease in the catalogue, renewed
    # every ttl/3; another process takes it over only after the lease expired (a crash).
    lease_ttl_s: float = Field(30.0, ge=2, le=3600)
    # A chunk or results file that cannot be stored (database unreachable, disk full or
    # read-only) is retried with backoff from 0.5 s, doubling to at most this many seconds
    # between tries, for as long as it takes; meanwhile its study shows ``waiting``.
    outage_backoff_s: float = Field(30.0, ge=1, le=3600)
    # Host names (comma-separated) the service answers to; others get 400, which stops DNS
    # rebinding. Unset: the loopback names, and the address it binds if that is a specific one.
    # "*" answers every name (only behind a proxy that checks Host itself).
    allowed_hosts: str | None = None
    # Origins (scheme://host[:port], comma-separated) besides the service's own whose pages
    # may change state (POST, PUT, PATCH, DELETE); e.g. the public origin of a reverse proxy.
    allowed_origins: str | None = None
    # Heavy reads (plots, datasets, slices, maps, /timeseries, /points) run at most this many
    # at once, in a pool of their own; unset: the number of CPU cores.
    heavy_workers: int | None = Field(None, ge=1, le=256)
    # Heavy reads waiting for the pool beyond these get 503 with Retry-After at once.
    heavy_queue: int = Field(16, ge=0, le=10_000)

    @field_validator(
        "api_token", "database_url", "scheduler", "nightly_cron", "allowed_hosts",
        "allowed_origins", mode="before",
    )  # fmt: skip
    @classmethod
    def _empty_is_unset(cls, v: object) -> object:
        # compose files pass "${VAR:-}": an empty string means "not set", not "token ''".
        return None if isinstance(v, str) and not v.strip() else v

    @field_validator("nightly_cron")
    @classmethod
    def _cron(cls, v: str | None) -> str | None:
        if v is None:
            return v
        return validate_cron(v)

    @field_validator("allowed_hosts", "allowed_origins")
    @classmethod
    def _names(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is None:
            return v
        names = _split(v)
        for name in names:
            if info.field_name == "allowed_origins" and not _ORIGIN.fullmatch(name):
                raise ValueError(
                    f"allowed_origins must be comma-separated origins like "
                    f"https://impactcell.example.org or http://localhost:8000; got {name!r}"
                )
            if info.field_name == "allowed_hosts" and not _HOST.fullmatch(name):
                raise ValueError(
                    f"allowed_hosts must be comma-separated host names or addresses (no "
                    f"scheme, no port), '*.example.org' or '*'; got {name!r}"
                )
        return ",".join(names)

    def host_names(self) -> tuple[str, ...]:
        """The host names the service answers to (lower case; ``*`` for any)."""
        if self.allowed_hosts:
            return tuple(n.lower().strip("[]") for n in _split(self.allowed_hosts))
        names = ["localhost", "127.0.0.1", "::1"]
        bound = self.host.strip("[]").lower()
        if bound not in ("", "0.0.0.0", "::") and bound not in names:
            names.append(bound)
        return tuple(names)

    def origins(self) -> tuple[str, ...]:
        """The configured origins allowed to change state besides the service's own."""
        return tuple(o.lower().rstrip("/") for o in _split(self.allowed_origins or ""))

    def heavy_pool_size(self) -> int:
        """How many heavy reads run at once (``heavy_workers``, default the CPU cores)."""
        return self.heavy_workers or max(1, os.cpu_count() or 1)

    def point_limits(self) -> PointLimits:
        """The budget of one point."""
        from worker.solvers.settings import PointLimits  # not at import: the CLI starts fast

        return PointLimits(wall_s=self.point_time_limit_s, steps=self.point_step_limit)

    def catalogue_url(self) -> str:
        """The catalogue's SQLAlchemy URL (a SQLite file in the data dir by default)."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'catalogue.sqlite').resolve()}"
