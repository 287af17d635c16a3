"""Shared route dependencies: settings, catalogue, job manager, auth, study lookup."""

from __future__ import annotations

import hmac
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Path, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.api.catalogue import Catalogue
from service.api.jobs import JobManager
from service.api.settings import Settings
from service.studies.chunks import is_study_id

__all__ = [
    "CatalogueDep",
    "JobsDep",
    "SettingsDep",
    "StudyId",
    "bearer_scheme",
    "require_token",
    "study_or_404",
]


# async: attribute lookups, answered in the event loop; a sync dependency would take a trip
# through the thread pool (and the GIL) for each, which a busy heavy-read pool makes slow.
async def _settings(request: Request) -> Settings:
    return request.app.state.settings


async def _catalogue(request: Request) -> Catalogue:
    return request.app.state.catalogue


async def _jobs(request: Request) -> JobManager:
    return request.app.state.jobs


SettingsDep = Annotated[Settings, Depends(_settings)]
CatalogueDep = Annotated[Catalogue, Depends(_catalogue)]
JobsDep = Annotated[JobManager, Depends(_jobs)]
StudyId = Annotated[str, Path(description="study id (hex content hash)", max_length=64)]


# Declares the bearer scheme in the OpenAPI (components.securitySchemes and each protected
# operation's security), so /docs shows an Authorize button. auto_error=False: the check and
# its 401 body stay ours (and with no token configured the routes are open).
bearer_scheme = HTTPBearer(
    auto_error=False,
    scheme_name="bearer",
    description="`IMPACTCELL_API_TOKEN` of the service, when it has one",
)


async def require_token(
    request: Request,
    _credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)] = None,
) -> None:
    """Bearer-token check when ``IMPACTCELL_API_TOKEN`` is set (constant-time comparison)."""
    # The raw header is compared, not ``_credentials``: HTTPBearer drops headers it cannot
    # parse, and every malformed header must get the same 401 as a wrong token.
    token = request.app.state.settings.api_token
    if not token:
        return
    header = request.headers.get("authorization", "")
    scheme, _, given = header.partition(" ")
    ok = scheme.lower() == "bearer" and hmac.compare_digest(
        given.strip().encode("utf-8", "surrogateescape"), token.encode("utf-8")
    )
    if not ok:
        raise HTTPException(
            401, "missing or wrong bearer token", headers={"WWW-Authenticate": "Bearer"}
        )


def study_or_404(catalogue: Catalogue, study_id: str) -> dict[str, Any]:
    """The study's record; 404 for unknown or malformed ids (no path is built from the text)."""
    if not is_study_id(study_id):
        raise HTTPException(404, f"no study with id {study_id!r} (ids are hex digests)")
    rec = catalogue.get_study(study_id)
    if rec is None:
        raise HTTPException(404, f"no study with id {study_id!r}")
    return rec
