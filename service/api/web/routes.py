"""``GET /`` (the page, for browsers) and ``GET /ui/{path}`` (its JS, CSS and icon).

The shell loads without the token: it holds no data, and it is what asks for the token. Files
are looked up by name in a fixed table built from the package's ``static`` folder, so no path
is ever built from request text.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import JSONResponse, Response

from service.studies.provenance import package_version

__all__ = ["CSP", "OPEN_PATHS", "STATIC", "router", "wants_html"]

STATIC = Path(__file__).resolve().parent / "static"
#: The paths of this router, open like /docs (the README and app.OPEN_ROUTES list them).
OPEN_PATHS = ("/", "/ui/{path}")
_TYPES = {
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
}
#: The browser itself refuses any request that would leave the service (no CDN, no beacon).
CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; form-action 'none'; base-uri 'none'; frame-ancestors 'none'"
)
# Revalidate on every load: a new version of the service never runs an old script.
_HEADERS = {"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"}

router = APIRouter(include_in_schema=False)


def _files() -> dict[str, Path]:
    return {p.name: p for p in sorted(STATIC.iterdir()) if p.suffix in _TYPES}


_FILES = _files()


def wants_html(accept: str) -> bool:
    """Whether an ``Accept`` header asks for HTML (browsers do; ``*/*`` alone does not)."""
    for part in accept.lower().split(","):
        kind, *params = (p.strip() for p in part.split(";"))
        if kind in ("text/html", "application/xhtml+xml"):
            q = next((p[2:] for p in params if p.startswith("q=")), "1")
            try:
                return float(q) > 0
            except ValueError:
                return True
    return False


@router.get("/")
def home(request: Request) -> Response:
    """The web page for browsers; a small JSON index of the service for everything else."""
    if wants_html(request.headers.get("accept", "")):
        html = (STATIC / "index.html").read_bytes()
        headers = {**_HEADERS, "Content-Security-Policy": CSP}
        return Response(html, media_type="text/html; charset=utf-8", headers=headers)
    index: dict[str, Any] = {
        "service": "impactcell",
        "version": package_version(),
        "page": "/ (Accept: text/html)",
        "docs": "/docs",
        "openapi": "/openapi.json",
        "health": "/health",
        "studies": "/studies",
        "regressions": "/regressions",
        "points": "/points",
    }
    return JSONResponse(index)


@router.get("/ui/{path}")
def asset(path: str) -> Response:
    """A file of the page (JS, CSS, icon), by name."""
    file = _FILES.get(path)
    if file is None:
        raise HTTPException(404, f"no file {path!r} of the web page")
    return Response(file.read_bytes(), media_type=_TYPES[file.suffix], headers=_HEADERS)
