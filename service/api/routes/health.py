"""``/health``: liveness, versions, queue counts and the latest nightly result (no auth)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from service.api.deps import CatalogueDep, SettingsDep
from service.api.schemas import Health
from service.studies.provenance import package_version
from worker.simulate import SOLVER_VERSION

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
def health(settings: SettingsDep, catalogue: CatalogueDep) -> dict[str, Any]:
    """Service is up; counts of studies by status; the latest nightly regression result."""
    return {
        "status": "ok",
        "version": package_version(),
        "solver_version": SOLVER_VERSION,
        "studies": catalogue.status_counts(),
        "nightly_cron": settings.nightly_cron,
        "nightly": catalogue.latest_regression(),
    }
