"""/docs and the token: an Authorize button (bearer security scheme), Swagger UI served by the
service itself (works offline), and exactly the open routes docs/service.md lists."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.routing import BaseRoute, Mount

from service.api.app import OPEN_ROUTES
from tests.service.helpers import API_TOKEN, JSON_BODY

SERVICE_DOC = Path(__file__).resolve().parents[3] / "docs" / "service.md"
TOKEN = API_TOKEN
# A value for every path parameter a route may have (a well-formed id that does not exist).
PATH_VALUES = {"study_id": "abcdef0123456789", "kind": "transmittance", "fmt": "png",
               "reg_id": "1", "path": "swagger-ui.css"}  # fmt: skip


@pytest.fixture
def tc(token_client: TestClient) -> TestClient:
    return token_client


def _routes(app: Any) -> list[tuple[BaseRoute, str, set[str]]]:
    """Every route of the app as (route, path, methods), included routers flattened (FastAPI
    >= 0.16x keeps them as included-router objects in ``app.routes``)."""
    try:
        from fastapi.routing import iter_route_contexts
    except ImportError:  # older FastAPI: app.routes is already flat
        return [(r, r.path, set(getattr(r, "methods", None) or ())) for r in app.routes]
    return [(c.original_route, str(c.path), set(c.methods or ()))
            for c in iter_route_contexts(app.routes)]  # fmt: skip


def _url(path: str) -> str:
    return re.sub(r"\{(\w+)(?::\w+)?\}", lambda m: PATH_VALUES[m.group(1)], path)


def test_openapi_declares_the_bearer_scheme_on_protected_operations(tc: TestClient) -> None:
    spec = tc.get("/openapi.json").json()
    assert spec["components"]["securitySchemes"]["bearer"] == {
        "type": "http", "scheme": "bearer",
        "description": "`IMPACTCELL_API_TOKEN` of the service, when it has one",
    }  # fmt: skip
    protected = 0
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            if path == "/health":
                assert "security" not in op
            else:
                assert op.get("security") == [{"bearer": []}], (method, path)
                protected += 1
    assert protected >= 10


def test_swagger_ui_is_served_locally(tc: TestClient) -> None:
    html = tc.get("/docs")
    assert html.status_code == 200 and "SwaggerUIBundle" in html.text
    refs = re.findall(r'(?:src|href)="([^"]+)"', html.text)
    assert refs and all(r.startswith("/docs/assets/") for r in refs), refs  # no CDN
    assert "https://" not in html.text and "http://" not in html.text
    js = tc.get("/docs/assets/swagger-ui-bundle.js")
    assert js.status_code == 200 and len(js.content) > 100_000
    assert "javascript" in js.headers["content-type"]
    # Swagger UI 5 reads OpenAPI 3.1 (4.x shows "Unable to render this definition")
    assert tc.get("/openapi.json").json()["openapi"].startswith("3.1")
    assert re.search(rb'"5\.\d+\.\d+"', js.content), "not Swagger UI 5 (tests/service/web)"
    css = tc.get("/docs/assets/swagger-ui.css")
    assert css.status_code == 200 and "text/css" in css.headers["content-type"]
    assert tc.get("/redoc").status_code == 404  # no redoc (it would load from a CDN)


def test_every_route_but_the_open_ones_needs_the_token(tc: TestClient) -> None:
    checked_open: set[str] = set()
    checked_closed = 0
    for route, path, methods in _routes(tc.app):
        if isinstance(route, Mount):
            assert path in OPEN_ROUTES, f"mount {path} is not an open route"
            r = tc.get(f"{path}/swagger-ui.css")
            assert r.status_code == 200, path
            checked_open.add(path)
            continue
        assert methods, f"route {path} has no methods"
        for method in sorted(methods - {"HEAD"}):
            r = tc.request(method, _url(path), headers=JSON_BODY)
            if path in OPEN_ROUTES:
                assert r.status_code != 401, (method, path)
                checked_open.add(path)
            else:
                assert r.status_code == 401, (method, path, r.status_code, r.text)
                assert r.json() == {"detail": "missing or wrong bearer token"}
                assert r.headers["www-authenticate"] == "Bearer"
                checked_closed += 1
    assert checked_open == set(OPEN_ROUTES)
    assert checked_closed >= 10
    ok = tc.get("/studies", headers={"Authorization": f"Bearer {TOKEN}"})
    assert ok.status_code == 200
    for header in (f"Basic {TOKEN}", "Bearer", f"Bearer {TOKEN}x", TOKEN):
        r = tc.get("/studies", headers={"Authorization": header})
        assert r.status_code == 401, header


def test_the_service_doc_lists_exactly_the_open_routes() -> None:
    text = SERVICE_DOC.read_text(encoding="utf-8")
    m = re.search(r"Open routes \(no token\): (.+?)\.\n", text)
    assert m, "the sentence of docs/service.md listing the open routes is missing"
    listed = set(re.findall(r"`([^`]+)`", m.group(1)))
    assert listed == {p if p != "/docs/assets" else "/docs/assets/*" for p in OPEN_ROUTES}
