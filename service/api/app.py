"""The FastAPI application: settings, catalogue, job manager, routes, errors, limits."""

from __future__ import annotations

import importlib.util
import logging
import sys
import uuid
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.api.admission import Admission
from service.api.catalogue import Catalogue
from service.api.deps import require_token
from service.api.guard import STATE_CHANGING, Guard
from service.api.jobs import JobManager
from service.api.nightly import NightlyRunner
from service.api.routes import health, points, regressions, results, studies, timeseries
from service.api.schemas import ErrorOut
from service.api.settings import Settings
from service.api.web import router as web_router
from service.studies.provenance import package_version

__all__ = ["OPEN_ROUTES", "create_app"]

#: Paths served without the token even when one is set: liveness, and the API's description
#: (Swagger UI loads the schema without credentials; the token is entered in its Authorize
#: dialog), and the web page's shell (``/``, ``/ui/*``: no data; it asks for the token).
#: Everything else answers 401 without ``Authorization: Bearer <token>``.
OPEN_ROUTES = ("/health", "/docs", "/openapi.json", "/docs/assets", "/", "/ui/{path}")
_ASSETS = "/docs/assets"  # Swagger UI's JS and CSS, from the swagger-ui-py package

log = logging.getLogger("impactcell.app")

ASGIApp = Callable[[dict, Callable, Callable], Awaitable[None]]


class BodyLimit:
    """413 for request bodies over the limit, whether or not Content-Length is given."""

    def __init__(self, app: ASGIApp, limit: Callable[[], int]) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit()
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    too_big = int(value) > limit
                except ValueError:
                    too_big = False
                if too_big:
                    await _too_large(limit, send)
                    return
        seen = 0

        async def limited() -> dict:
            nonlocal seen
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > limit:
                    raise _TooLarge
            return msg

        try:
            await self.app(scope, limited, send)
        except _TooLarge:
            await _too_large(limit, send)


class _TooLarge(Exception):
    pass


async def _too_large(limit: int, send: Callable) -> None:
    body = f'{{"detail": "request body larger than {limit} bytes"}}'.encode()
    await send({"type": "http.response.start", "status": 413,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode())]})  # fmt: skip
    await send({"type": "http.response.body", "body": body})


def create_app(settings: Settings | None = None, *, run_jobs: bool = True) -> FastAPI:
    """Build the application. ``run_jobs=False`` leaves the runner thread off (API tests)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        catalogue = Catalogue(settings.catalogue_url())
        jobs = JobManager(settings, catalogue)
        admission = Admission(settings.heavy_pool_size(), settings.heavy_queue)
        app.state.admission = admission
        # Heavy reads hold the GIL in pure Python (matplotlib, xarray): every light request
        # (/health) waits a switch interval at each handoff, 5 ms by default; 1 ms keeps it
        # quick while the pool is busy, at a small cost to the heavy reads.
        sys.setswitchinterval(min(sys.getswitchinterval(), 0.001))
        admission.prepare(_warm_plots)
        app.state.settings = settings
        app.state.catalogue = catalogue
        app.state.jobs = jobs
        if run_jobs:
            jobs.start()
        # The nightly suite runs through this service's own queue (cron or POST /regressions).
        runner = NightlyRunner(settings, catalogue, jobs)
        app.state.nightly_runner = runner
        nightly = None
        if settings.nightly_cron:
            from service.api.schedule import NightlyScheduler

            nightly = NightlyScheduler(settings, catalogue, run=runner.run)
            nightly.start()
        app.state.nightly = nightly
        try:
            yield
        finally:
            runner.stop()  # a run in progress cancels its unfinished studies and reports it
            if nightly is not None:
                nightly.stop()
            jobs.stop()
            admission.close()
            catalogue.close()

    app = FastAPI(
        title="impactcell",
        version=package_version(),
        summary="Parameter studies of an impacting beam-in-mass metamaterial cell",
        description=(
            "Submit study definitions (grids over gaps, θ, σ, γ_s, γ_r, …), follow their "
            "progress, fetch NetCDF datasets, JSON/CSV slices, bandgap maps and figures. When "
            "`IMPACTCELL_API_TOKEN` is set, every route except `/health`, `/docs` (with its "
            "assets) and `/openapi.json` needs `Authorization: Bearer <token>` (the Authorize "
            "button here)."
        ),
        lifespan=lifespan,
        docs_url=None,  # served below from local assets: no CDN, works offline
        redoc_url=None,
    )
    app.state.settings = settings
    auth = [Depends(require_token)]
    app.include_router(health.router)
    app.include_router(web_router)  # the page's files only; its data comes from the API
    app.include_router(studies.router, dependencies=auth)
    app.include_router(results.router, dependencies=auth)
    app.include_router(timeseries.router, dependencies=auth)
    app.include_router(regressions.router, dependencies=auth)
    app.include_router(points.router, dependencies=auth)
    _add_docs(app)
    app.add_middleware(BodyLimit, limit=lambda: settings.max_body_bytes)
    app.add_middleware(Guard, settings=lambda: settings)  # outermost: before the body is read
    _describe_errors(app)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        body: dict[str, Any] = (
            exc.detail if isinstance(exc.detail, dict) else {"detail": str(exc.detail)}
        )
        return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        problems = []
        for e in exc.errors():
            loc = ".".join(str(p) for p in e.get("loc", ()))
            got = e.get("input")
            msg = str(e.get("msg", "invalid"))
            if got is not None and not isinstance(got, dict | list):
                msg += f", got {str(got)[:80]!r}"
            problems.append({"path": loc, "message": msg})
        detail = "; ".join(f"{p['path']}: {p['message']}" for p in problems) or "invalid request"
        return JSONResponse({"detail": detail, "problems": problems}, status_code=422)

    @app.exception_handler(Exception)
    async def _crash(request: Request, exc: Exception) -> JSONResponse:
        # The message can hold SQL with its parameters, server paths or data: the log gets
        # it, the response only a reference to find it there.
        ref = uuid.uuid4().hex[:12]
        log.exception("unhandled error %s on %s %s", ref, request.method, request.url.path)
        return JSONResponse(
            {"detail": f"internal error ({type(exc).__name__}); the service's log has it "
             f"under reference {ref}"},
            status_code=500,
        )  # fmt: skip

    return app


def _warm_plots() -> None:
    """Draw a figure once in the heavy-read pool at start (:func:`plots.warm_up`)."""
    from service.analysis import plots

    plots.warm_up()


#: Responses every operation may give besides its own (the guard's and the admission pool's).
_COMMON_ERRORS = {
    "400": "the Host header names a host this service does not answer to",
    "422": "invalid request: every problem, with the path of its field",
}
_CHANGE_ERRORS = {
    "403": "a page of another origin tried to change state (its Origin is not allowed)",
    "415": "no JSON or YAML Content-Type (every request that changes state needs one)",
}
_HEAVY_ERROR = {"503": "busy: too many heavy requests running or queued (see Retry-After)"}


def _describe_errors(app: FastAPI) -> None:
    """OpenAPI as the service answers: every error body is ``ErrorOut`` (FastAPI's default
    422 schema, ``HTTPValidationError``, is not what ``_invalid`` sends), and each operation
    lists the guard's and the admission pool's statuses."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, summary=app.summary,
                             description=app.description, routes=app.routes)  # fmt: skip
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        for name in ("HTTPValidationError", "ValidationError"):
            components.pop(name, None)
        components.update(_error_schemas())
        ref = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorOut"}}}
        heavy_ops = {id(r.endpoint) for r in _flat_routes(app.routes) if _is_heavy(r)}
        for path, ops in schema.get("paths", {}).items():
            for method, op in ops.items():
                route = _route_of(app, path, method)
                extra = dict(_COMMON_ERRORS)
                if method.upper() in STATE_CHANGING:
                    extra.update(_CHANGE_ERRORS)
                if route is not None and id(route.endpoint) in heavy_ops:
                    extra.update(_HEAVY_ERROR)
                responses = op.setdefault("responses", {})
                for code, text in extra.items():
                    responses.setdefault(code, {"description": text})
                for code, resp in responses.items():
                    if code.startswith(("4", "5")):
                        resp["content"] = ref
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def _error_schemas() -> dict[str, Any]:
    from pydantic.json_schema import models_json_schema

    _, defs = models_json_schema([(ErrorOut, "serialization")],
                                 ref_template="#/components/schemas/{model}")  # fmt: skip
    return defs["$defs"]


def _is_heavy(route: Any) -> bool:
    return getattr(getattr(route, "endpoint", None), "__heavy__", False)


def _flat_routes(routes: list[Any]) -> list[Any]:
    """Every route, those of included routers too (held apart by newer FastAPI versions; the
    routers here are included without a prefix of their own, so their paths are complete)."""
    out = []
    for r in routes:
        inner = getattr(getattr(r, "original_router", None), "routes", None)
        out += _flat_routes(inner) if inner is not None else [r]
    return out


def _route_of(app: FastAPI, path: str, method: str) -> Any:
    for r in _flat_routes(app.routes):
        if getattr(r, "path", None) == path and method.upper() in getattr(r, "methods", ()):
            return r
    return None


def swagger_ui_assets() -> Path:
    """The folder of Swagger UI's files in the ``swagger-ui-py`` package (found, not imported:
    the package's own module loads web-framework glue the service does not need)."""
    spec = importlib.util.find_spec("swagger_ui")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("swagger-ui-py is not installed (a dependency of impactcell)")
    return Path(next(iter(spec.submodule_search_locations))) / "static"


def _add_docs(app: FastAPI) -> None:
    """Swagger UI at ``/docs`` with its JS and CSS served by the service itself: Swagger UI 5
    from the ``swagger-ui-py`` package, which reads the OpenAPI 3.1 that FastAPI writes."""
    app.mount(_ASSETS, StaticFiles(directory=swagger_ui_assets()), name="swagger-ui-assets")

    @app.get("/docs", include_in_schema=False)
    async def _docs(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "").rstrip("/")
        return get_swagger_ui_html(
            openapi_url=f"{root}{app.openapi_url}",
            title=f"{app.title} API",
            swagger_js_url=f"{root}{_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{root}{_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{root}{_ASSETS}/favicon-32x32.png",
            swagger_ui_parameters={"persistAuthorization": True},
        )
