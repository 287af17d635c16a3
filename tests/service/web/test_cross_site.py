"""Cross-site requests in a real browser against a real ``impactcell serve`` without a token: a
page of another origin (a second HTTP server on another port) tries to submit a study, start a
nightly run and cancel a study; every attempt is refused and nothing changes, while the
service's own page still cancels. And 50 concurrent plot requests leave ``/health`` quick."""

from __future__ import annotations

import http.server
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from service.api.server import free_port
from tests.service.helpers import FAST_SOLVER, JSON_BODY, SLOW_SOLVER, Server, tiny_study

# a real server, a real cluster, a real browser; `page` comes first where there is one, so a
# missing browser skips before a server or cluster is started
pytestmark = pytest.mark.slow

# What the other origin's page does: the attacks of issue 63, each awaited; no-cors requests
# send no Content-Type (a Blob without a type) or a simple one, and their answers are opaque.
_ATTACK = """<!doctype html><meta charset="utf-8"><title>attack</title><script>
const S = "%(service)s";
const study = JSON.stringify(%(study)s);
async function go() {
  const tries = [
    fetch(S + "/studies", {method: "POST", mode: "no-cors", body: new Blob([study])}),
    fetch(S + "/studies", {method: "POST", mode: "no-cors", body: study,
                           headers: {"Content-Type": "text/plain"}}),
    fetch(S + "/regressions", {method: "POST", mode: "no-cors"}),
    fetch(S + "/studies/%(sid)s/cancel", {method: "POST", mode: "no-cors"}),
    fetch(S + "/studies/%(sid)s/cancel", {method: "POST", mode: "cors",
                                          headers: {"Content-Type": "application/json"}})
      .catch(() => "blocked"),
  ];
  await Promise.allSettled(tries);
  const f = document.createElement("form");  // a plain form post, last
  f.method = "POST"; f.action = S + "/studies/%(sid)s/cancel"; f.target = "sink";
  document.body.append(f);
  f.submit();
}
</script><iframe name="sink"></iframe><button id="go" onclick="go().then(() =>
  document.title = 'sent')">go</button>"""


@pytest.fixture
def server(tmp_path: Path, dask_address: str) -> Iterator[Server]:
    srv = Server(tmp_path / "data", dask_address)
    yield srv
    srv.stop()


@pytest.fixture
def other_origin(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """A second HTTP server (another port: another origin) serving the files of a folder."""
    folder = tmp_path / "site"
    folder.mkdir()

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a: Any, **kw: Any) -> None:
            super().__init__(*a, directory=str(folder), **kw)

        def log_message(self, *a: Any) -> None:
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", free_port()), Quiet)
    t = threading.Thread(target=httpd.serve_forever, daemon=True)
    t.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}", folder
    httpd.shutdown()
    httpd.server_close()


def test_a_page_of_another_origin_changes_nothing(
    page: Any, server: Server, other_origin: tuple[str, Path]
) -> None:
    base, folder = other_origin
    d = tiny_study(name="victim", num=150, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)
    sid = httpx.post(f"{server.url}/studies", json=d).json()["id"]
    before = httpx.get(f"{server.url}/studies/{sid}").json()["status"]
    assert before in ("queued", "running")
    (folder / "attack.html").write_text(
        _ATTACK % {"service": server.url, "sid": sid, "study": tiny_study(name="planted")}
    )
    answers: list[tuple[str, str, int]] = []
    page.on("response", lambda r: answers.append((r.request.method, r.url, r.status))
            if r.url.startswith(server.url) else None)  # fmt: skip
    page.goto(f"{base}/attack.html")
    page.click("#go")
    page.wait_for_function("document.title === 'sent'")
    deadline = time.monotonic() + 10
    while sum(1 for m, *_ in answers if m == "POST") < 5 and time.monotonic() < deadline:
        page.wait_for_timeout(100)
    posts = [(url.removeprefix(server.url), status) for m, url, status in answers if m == "POST"]
    # every request that reached the service was refused (the cors one never left: its
    # preflight OPTIONS is not allowed, so the browser did not send it)
    assert len(posts) >= 5, answers
    assert all(status == 403 for _, status in posts), posts
    assert {u for u, _ in posts} == {"/studies", "/regressions", f"/studies/{sid}/cancel"}
    # nothing changed: one study, still going; no nightly run
    studies = httpx.get(f"{server.url}/studies").json()
    assert studies["total"] == 1 and studies["items"][0]["status"] in ("queued", "running")
    assert httpx.get(f"{server.url}/regressions").json()["total"] == 0
    # a DNS-rebound name reaches the service, and is refused
    r = httpx.get(f"{server.url}/studies", headers={"Host": f"rebound.example:{server.port}"})
    assert r.status_code == 400
    # the service's own page still cancels
    page.goto(f"{server.url}/#/studies/{sid}")
    page.get_by_role("button", name="Cancel").click()
    page.wait_for_function(
        "() => /^cancelled/.test(document.querySelector('#study-live')?.textContent || '')",
        timeout=30_000,
    )
    assert httpx.get(f"{server.url}/studies/{sid}").json()["status"] == "cancelled"


def test_fifty_concurrent_plots_leave_health_quick(tmp_path: Path, dask_address: str) -> None:
    env = {"IMPACTCELL_HEAVY_WORKERS": "2", "IMPACTCELL_HEAVY_QUEUE": "16"}
    srv = Server(tmp_path / "data", dask_address, env=env)
    try:
        d = tiny_study(name="plots", num=24, gaps=(0.1, 0.3, 0.5), **FAST_SOLVER)
        sid = httpx.post(f"{srv.url}/studies", json=d).json()["id"]
        t0 = time.monotonic()
        while httpx.get(f"{srv.url}/studies/{sid}").json()["status"] != "finished":
            assert time.monotonic() - t0 < 60, "the study did not finish"
            time.sleep(0.2)
        kinds = ["transmittance.png", "bandgap.png", "transmittance.svg", "bandgap.svg"]
        answers: list[httpx.Response | Exception] = []
        go = threading.Barrier(51)
        # clients made before the burst: httpx.get sets up an SSL context per call, holding
        # this process's GIL; 50 at once would slow the prober here, not the service
        many = httpx.Client(limits=httpx.Limits(max_connections=50), timeout=120)
        probe = httpx.Client(timeout=30)

        def plot(i: int) -> None:
            go.wait()
            try:
                answers.append(many.get(f"{srv.url}/studies/{sid}/plots/{kinds[i % 4]}"))
            except httpx.HTTPError as exc:
                answers.append(exc)

        threads = [threading.Thread(target=plot, args=(i,)) for i in range(50)]
        for t in threads:
            t.start()
        go.wait()
        health: list[float] = []
        while any(t.is_alive() for t in threads) or len(health) < 5:
            t1 = time.monotonic()
            assert probe.get(f"{srv.url}/health").status_code == 200
            health.append(time.monotonic() - t1)
            time.sleep(0.05)
        for t in threads:
            t.join()
        many.close()
        probe.close()
        assert max(health) < 1.0, health
        assert len(answers) == 50 and all(isinstance(r, httpx.Response) for r in answers)
        codes = [r.status_code for r in answers]  # type: ignore[union-attr]
        assert set(codes) <= {200, 503}, codes
        for r in answers:
            if r.status_code == 503:  # type: ignore[union-attr]
                assert int(r.headers["retry-after"]) >= 1  # type: ignore[union-attr]
        assert codes.count(200) >= 18  # the pool and its queue: every admitted one answered
        assert httpx.post(f"{srv.url}/studies/{sid}/cancel", headers=JSON_BODY).status_code == 409
    finally:
        srv.stop()
