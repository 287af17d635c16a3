"""Bad requests to ``POST /studies``: every one a 4xx naming the field, none a 500, none slow,
none stalling the event loop (issue 13, items 2 and 7).

Fast tests use the app in process (TestClient, no jobs); the slow ones start a real uvicorn
server on 127.0.0.1 and poll ``/health`` while the bad bodies are posted.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from unittest import mock

import httpx
import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.routes import studies as route
from service.api.server import free_port
from service.api.settings import Settings
from service.studies.files import MAX_DEPTH
from service.studies.grid import MAX_AXIS_VALUES, Range
from tests.service.helpers import tiny_study

GRID = '"grid": {"gamma_r": 1.0, "gap": 0.1, "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0}'
YAML_GRID = "grid: {gamma_r: 1.0, gap: 0.1, theta: 0.3, sigma: 0.05, gamma_s: 1.0}\n"
JSON = {"content-type": "application/json"}
YAML = {"content-type": "application/yaml"}


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return Settings(data_dir=tmp_path / "data", database_url=f"sqlite:///{tmp_path / 'c.db'}",
                    **kw)  # fmt: skip


@pytest.fixture
def http(tmp_path: Path) -> Iterator[TestClient]:
    """The app in process, no runner: 5xx would be returned, not raised."""
    with TestClient(create_app(_settings(tmp_path), run_jobs=False),
                    raise_server_exceptions=False) as tc:  # fmt: skip
        yield tc


def _huge_grid(num: int) -> dict[str, Any]:
    d = tiny_study()
    d["grid"]["gamma_r"] = {"start": 0.1, "stop": 6, "num": num}
    return d


def _problems(r: httpx.Response) -> dict[str, str]:
    return {p["path"]: p["message"] for p in r.json()["problems"]}


# --------------------------------------------------------------------------- huge grids


@pytest.mark.parametrize("num", [10_000_000, 10**9])
def test_a_huge_axis_is_a_422_naming_it_and_nothing_is_built(http: TestClient, num: int) -> None:
    with mock.patch.object(Range, "values", side_effect=AssertionError("built")) as values:
        r = http.post("/studies", json=_huge_grid(num))
    assert r.status_code == 422
    assert values.call_count == 0
    assert _problems(r) == {
        "grid.gamma_r.num": f"num must be an integer in 1…{MAX_AXIS_VALUES:,}, got {num}"
    }


def test_a_grid_over_the_point_limit_is_a_422_naming_axes_sizes_and_limit(
    http: TestClient,
) -> None:
    d = _huge_grid(MAX_AXIS_VALUES)
    d["grid"]["theta"] = {"start": 0.1, "stop": 1.0, "num": 1000}
    with mock.patch.object(Range, "values", side_effect=AssertionError("built")) as values:
        r = http.post("/studies", json=d)
    assert r.status_code == 422 and values.call_count == 0
    msg = _problems(r)["grid"]
    assert msg == ("has 2,000,000,000 points, more than the limit of 2,000,000 "
                   "(gap 2 × theta 1,000 × gamma_r 1,000,000)")  # fmt: skip


# --------------------------------------------------------------------------- huge numbers


@pytest.mark.parametrize("digits", [401, 5001])
def test_huge_json_integers_are_422s_naming_the_field(http: TestClient, digits: int) -> None:
    big = "1" + "0" * (digits - 1)
    body = (
        '{"name": "x", "model": {"modes": BIG}, "solver": {"max_periods": BIG}, '
        '"grid": {"gamma_r": [1.0, BIG], "gap": 0.1, "theta": BIG, "sigma": 0.05, '
        '"gamma_s": {"start": 1, "stop": BIG, "num": 2}}}'
    ).replace("BIG", big)
    r = http.post("/studies", content=body.encode(), headers=JSON)
    assert r.status_code == 422, r.text
    got = _problems(r)
    assert set(got) == {"model.modes", "solver.max_periods", "grid.gamma_r", "grid.theta",
                        "grid.gamma_s"}  # fmt: skip
    assert "modes must be an integer in 1…30, got an integer of" in got["model.modes"]
    assert "theta must be finite, got an integer of" in got["grid.theta"]
    assert got["grid.gamma_r"].endswith("allowed range [1e-06, 1000] (value 1)")
    assert "(range stop)" in got["grid.gamma_s"]
    assert all(len(m) < 200 for m in got.values())  # never the number in full


def test_huge_yaml_integers_are_422s_naming_the_field(http: TestClient) -> None:
    big = "1" + "0" * 5000
    body = f"name: x\nmodel: {{modes: {big}}}\n" + YAML_GRID.replace("0.3", big)
    r = http.post("/studies", content=body.encode(), headers=YAML)
    assert r.status_code == 422, r.text
    assert set(_problems(r)) == {"model.modes", "grid.theta"}


@pytest.mark.parametrize(
    ("field", "value", "path", "text"),
    [
        ("gamma_r", "1e308", "grid.gamma_r", "gamma_r must be <= 1000, got 1e+308; allowed range"),
        ("gamma_r", "NaN", "grid.gamma_r", "gamma_r must be finite, got nan; allowed range"),
        ("theta", "Infinity", "grid.theta", "theta must be finite, got inf; allowed range"),
        ("sigma", "-1e-3", "grid.sigma", "sigma must be > 0, got -0.001; allowed range"),
        ("gap", "1e300", "grid.gap", "gap must be <= 1e+12, got 1e+300"),
    ],
)
def test_non_finite_and_out_of_range_values_are_422s(http, field, value, path, text) -> None:
    # JSON text, since NaN and Infinity are what a JSON body carries (json.dumps would too)
    grid = {"gamma_r": "1.0", "gap": "0.1", "theta": "0.3", "sigma": "0.05", "gamma_s": "1.0"}
    grid[field] = value
    body = '{"name": "x", "grid": {' + ", ".join(f'"{k}": {v}' for k, v in grid.items()) + "}}"
    r = http.post("/studies", content=body.encode(), headers=JSON)
    assert r.status_code == 422, r.text
    assert text in _problems(r)[path]


def test_solver_budgets_over_the_caps_are_422s(http: TestClient) -> None:
    d = tiny_study(max_periods=10**7)
    r = http.post("/studies", json=d)
    assert r.status_code == 422
    assert _problems(r)["solver.max_periods"].startswith("max_periods must be an integer in 2…")


# --------------------------------------------------------------------------- deep nesting


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 20_000, 100_000])
@pytest.mark.parametrize("fmt", ["json", "yaml"])
def test_deep_nesting_is_a_400_naming_where(http: TestClient, fmt: str, depth: int) -> None:
    if fmt == "json":
        body, headers = '{"name": "x", "description": ' + "[" * depth + "]" * depth + ", " + \
            GRID + "}", JSON  # fmt: skip
    else:
        body, headers = "name: x\ndescription: " + "[" * depth + "]" * depth + "\n", YAML
    r = http.post("/studies", content=body.encode(), headers=headers)
    assert r.status_code == 400, r.text
    assert r.json()["detail"].startswith(
        f"request body is nested more than {MAX_DEPTH} levels deep at description[0][0]"
    )


# --------------------------------------------------------------------------- off the loop


def test_parsing_and_validation_run_off_the_event_loop(http: TestClient) -> None:
    seen: list[bool] = []

    def on_loop() -> bool:
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return False
        return True

    real_text = route.parse_study_text
    real_study = route.parse_study

    def text(*a: Any, **kw: Any) -> Any:
        seen.append(on_loop())
        return real_text(*a, **kw)

    def study(*a: Any, **kw: Any) -> Any:
        seen.append(on_loop())
        return real_study(*a, **kw)

    with mock.patch.object(route, "parse_study_text", text), \
            mock.patch.object(route, "parse_study", study):  # fmt: skip
        r = http.post("/studies", json=tiny_study())
    assert r.status_code == 202
    assert seen == [False, False]  # both ran in a worker thread, not on the loop


# --------------------------------------------------------------------------- a real server


class _Server:
    """The service (no runner) under uvicorn in a thread of this process."""

    def __init__(self, settings: Settings) -> None:
        import uvicorn

        self.port = free_port()
        config = uvicorn.Config(create_app(settings, run_jobs=False), host="127.0.0.1",
                                port=self.port, log_level="warning")  # fmt: skip
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.url = f"http://127.0.0.1:{self.port}"

    def __enter__(self) -> _Server:
        self.thread.start()
        t0 = time.monotonic()
        while not self.server.started:
            assert self.thread.is_alive() and time.monotonic() - t0 < 60
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(30)


def _while_polling_health(url: str, post: Any) -> tuple[Any, list[float]]:
    """Run ``post()`` while another thread polls /health; the poll times while it ran."""
    times: list[float] = []
    stop = threading.Event()

    def poll() -> None:
        with httpx.Client(base_url=url, timeout=30) as c:
            while not stop.is_set():
                t0 = time.monotonic()
                assert c.get("/health").status_code == 200
                times.append(time.monotonic() - t0)
                time.sleep(0.02)

    poller = threading.Thread(target=poll, daemon=True)
    poller.start()
    time.sleep(0.3)  # a few polls before
    try:
        result = post()
        time.sleep(0.3)  # and a few after
    finally:
        stop.set()
        poller.join(30)
    return result, times


@pytest.mark.slow
def test_health_keeps_answering_while_bad_bodies_are_posted(tmp_path: Path) -> None:
    depth = 499_999  # the deepest body under the 1 MB limit
    bodies = [
        ("/studies", _huge_grid(10**9), None),
        ("/studies", None, ("[" * depth + "]" * depth, "application/json")),
        ("/studies", None, ("a: " + "[" * depth + "]" * depth, "application/yaml")),
        (
            "/studies",
            None,
            ('{"name": "x", "model": {"modes": 1' + "0" * 900_000 + "}}", "application/json"),
        ),  # fmt: skip
    ]
    with _Server(_settings(tmp_path)) as srv, httpx.Client(base_url=srv.url, timeout=120) as c:
        for path, js, raw in bodies:

            def post(path: str = path, js: Any = js, raw: Any = raw) -> httpx.Response:
                if js is not None:
                    return c.post(path, json=js)
                return c.post(path, content=raw[0].encode(), headers={"content-type": raw[1]})

            r, times = _while_polling_health(srv.url, post)
            assert 400 <= r.status_code < 500, (r.status_code, r.text[:200])
            assert len(times) >= 5
            assert max(times) < 2.0, times


@pytest.mark.slow
def test_health_keeps_answering_while_a_large_valid_body_is_validated(tmp_path: Path) -> None:
    # 60,000 listed frequencies (~1 MB): real validation work, done in a worker thread
    d = tiny_study()
    d["grid"]["gamma_r"] = [round(0.5 + i * 1e-5, 6) for i in range(60_000)]
    with _Server(_settings(tmp_path, max_body_bytes=2_000_000)) as srv, \
            httpx.Client(base_url=srv.url, timeout=120) as c:  # fmt: skip
        r, times = _while_polling_health(srv.url, lambda: c.post("/studies", json=d))
    assert r.status_code == 202, r.text[:200]
    assert r.json()["points_total"] == 120_000
    assert len(times) >= 5 and max(times) < 2.0, times
