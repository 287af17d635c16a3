"""The web page's files as the service serves them (fast: no server, no browser): ``/`` for
browsers, the assets and their types, nothing loaded from elsewhere, open without the token."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient

from service.api.app import OPEN_ROUTES
from service.api.web.routes import OPEN_PATHS, STATIC, wants_html
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from service.studies.variables import outcome_names
from tests.service.helpers import API_TOKEN

TOKEN = API_TOKEN
HTML = {"Accept": "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8"}
# Identifiers that look like URLs but are never requested (the SVG namespace).
NOT_REQUESTS = {"http://www.w3.org/2000/svg"}
TYPES = {".js": "text/javascript", ".css": "text/css", ".svg": "image/svg+xml"}


@pytest.fixture
def tc(token_client: TestClient) -> TestClient:
    return token_client


def test_home_is_the_page_for_browsers_and_an_index_otherwise(tc: TestClient) -> None:
    r = tc.get("/", headers=HTML)  # no token: the shell holds no data
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert '<script src="ui/app.js"' in r.text and 'id="token-dialog"' in r.text
    csp = r.headers["content-security-policy"]
    assert "connect-src 'self'" in csp and "script-src 'self'" in csp
    index = tc.get("/", headers={"Accept": "application/json"})
    assert index.status_code == 200 and index.json()["studies"] == "/studies"
    assert tc.get("/").headers["content-type"] == "application/json"  # curl's */*
    assert tc.get("/studies").status_code == 401  # the data still needs the token
    ok = tc.get("/studies", headers={"Authorization": f"Bearer {TOKEN}"})
    assert ok.status_code == 200


def test_every_asset_the_page_names_is_served_with_its_type(tc: TestClient) -> None:
    html = tc.get("/", headers=HTML).text
    refs = re.findall(r'(?:src|href)="(ui/[^"]+)"', html)
    assert {"ui/app.js", "ui/charts.js", "ui/app.css", "ui/favicon.svg"} <= set(refs)
    for ref in refs:
        r = tc.get(f"/{ref}")
        assert r.status_code == 200, ref
        assert r.headers["content-type"].startswith(TYPES[Path(ref).suffix]), ref
        assert r.headers["x-content-type-options"] == "nosniff"
    for bad in ("/ui/nope.js", "/ui/index.html", "/ui/..%2Froutes.py", "/ui/%2e%2e"):
        assert tc.get(bad).status_code == 404, bad


def test_nothing_is_loaded_from_other_hosts() -> None:
    files = sorted(STATIC.iterdir())
    assert {f.suffix for f in files} == {".html", ".js", ".css", ".svg"}
    for f in files:
        urls = set(re.findall(r"""(?:https?:)?//[\w.-]+\.[a-z]{2,}[^\s"'`<>)]*""", f.read_text()))
        assert urls <= NOT_REQUESTS, (f.name, urls - NOT_REQUESTS)
        assert "@import" not in f.read_text() and "cdn" not in f.read_text().lower(), f.name


def test_the_page_paths_are_open_routes() -> None:
    assert set(OPEN_PATHS) <= set(OPEN_ROUTES)


@pytest.mark.parametrize(
    ("accept", "html"),
    [
        ("text/html,application/xhtml+xml,*/*;q=0.8", True),  # Chrome, Firefox
        ("application/xhtml+xml", True),
        ("text/html;q=0", False),
        ("*/*", False),
        ("application/json", False),
        ("", False),
    ],
)
def test_wants_html(accept: str, html: bool) -> None:
    assert wants_html(accept) is html


def _example() -> str:
    """The study text the page's "Insert the example" button inserts (app.js ``EXAMPLE``)."""
    js = (STATIC / "app.js").read_text("utf-8")
    body = re.search(r"const EXAMPLE = \[(.*?)\]\.join\(\"\\n\"\)", js, re.S)
    assert body, "app.js defines EXAMPLE as an array of lines"
    return "\n".join(json.loads(s) for s in re.findall(r'"(?:[^"\\]|\\.)*"', body.group(1)))


@pytest.mark.slow  # the whole example study, serial (a few seconds)
def test_the_example_study_settles_at_every_point(tmp_path: Path) -> None:
    study = parse_study(yaml.safe_load(_example()), source="the web page's example")
    assert study.name == "my-first-study"
    ds = open_results(run_study(study, tmp_path, serial=True).path)
    names = outcome_names(ds["outcome"])
    assert names.size == 24
    # every point ends in a steady state the results can stand on: none unsettled or failed
    assert set(np.unique(names)) <= {"linear", "periodic", "irregular"}, np.unique(names)
