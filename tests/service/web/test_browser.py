"""The web page in a real browser (headless Chromium) against a real ``impactcell serve``: the
home page lists a study, the study page draws its charts, a bad study shows its problems beside
the text, cancel and delete work, and with a token the page asks for it once."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from service.client import Client
from tests.service.helpers import FAST_SOLVER, SLOW_SOLVER, TABLE1_CELL, Server, tiny_study

# a real server, a real cluster, a real browser; `page` comes first in every signature, so a
# missing browser skips before a server or cluster is started
pytestmark = pytest.mark.slow

TOKEN = "web-token"
# True once the element's text matches the pattern (a polled predicate in the page).
_HAS_TEXT = """([s, p]) => {
    const e = document.querySelector(s);
    return e !== null && new RegExp(p).test(e.textContent);
}"""


@pytest.fixture
def server(tmp_path: Path, dask_address: str) -> Iterator[Server]:
    srv = Server(tmp_path / "data", dask_address)
    yield srv
    srv.stop()


def _expect_text(page: Any, selector: str, pattern: str, timeout: float = 60_000) -> None:
    page.wait_for_function(_HAS_TEXT, arg=[selector, pattern], timeout=timeout)


def _expect_label(page: Any, selector: str, label: str, timeout: float = 60_000) -> None:
    """Wait until the element's ``aria-label`` (a chart's title) is ``label``."""
    page.wait_for_function(
        "([s, t]) => document.querySelector(s)?.getAttribute('aria-label') === t",
        arg=[selector, label], timeout=timeout,
    )  # fmt: skip


def _expect_count(page: Any, selector: str, n: int, timeout: float = 60_000) -> None:
    """Wait until exactly ``n`` elements match: the curves are drawn after their slices are
    fetched, which may be after the map is drawn."""
    page.wait_for_function(
        "([s, n]) => document.querySelectorAll(s).length === n", arg=[selector, n], timeout=timeout
    )


def test_home_lists_the_study_and_its_page_draws_the_charts(page: Any, server: Server) -> None:
    with Client(server.url) as c:
        rec = c.submit(tiny_study(name="web-map", num=6, gaps=(0.1, 0.5)))
        c.wait(rec["id"], progress=False, timeout=120, poll=0.2)
    page.goto(f"{server.url}/")
    link = page.get_by_role("link", name="web-map")
    link.wait_for()
    assert "finished" in page.locator(f'tr[data-id="{rec["id"]}"]').inner_text()
    _expect_text(page, "#studies-summary", "1 study")
    link.click()
    page.wait_for_url(re.compile(f"#/studies/{rec['id']}$"))
    _expect_text(page, "#study-live", "finished, 100 %")
    chart = page.locator('#map-chart svg[data-chart="map"]')
    chart.wait_for()
    assert int(chart.get_attribute("data-points")) == 12  # 6 γ_r × 2 gaps, every one finite
    _expect_count(page, "#curve-chart svg path[data-series]", 4)  # Γ and Γ_lin, 2 gaps
    page.locator("#mass-chart svg").wait_for()
    assert "grid:" in page.locator("#definition").inner_text()
    # Hover shows the values; the keyboard moves the read-out.
    chart.hover(position={"x": 300, "y": 40})
    assert re.search(r"γ_r = .*Γ \(dB\) = ", page.locator("#tooltip").inner_text())
    chart.focus()
    page.keyboard.press("End")
    assert "γ_r = 3" in page.locator("#map-chart .readout").inner_text()
    # Another variable from the menu: the impact effect, threshold −1 dB.
    page.select_option("#map-variable", "impact_effect_db")
    page.wait_for_function(
        "() => document.querySelector('#band-edges')?.textContent.includes('Γ − Γ_lin < -1 dB')"
    )
    # Every form control has a label a screen reader can read.
    unlabelled = page.evaluate(
        "() => [...document.querySelectorAll('select, input, textarea')]"
        ".filter(e => !e.labels?.length && !e.getAttribute('aria-label')).map(e => e.id)"
    )
    assert unlabelled == []
    with page.expect_download() as dl:
        page.get_by_role("button", name="Band edges CSV").click()
    assert dl.value.suggested_filename == f"{rec['id']}-bands.csv"
    # every request of the study page was answered: no 4xx (e.g. an adaptive-only variable
    # asked of a grid study), no console error
    assert page.console_errors == []


def test_a_bad_study_shows_its_problems_beside_the_text(page: Any, server: Server) -> None:
    page.goto(f"{server.url}/#/submit")
    page.fill("#study-text", "name: bad\ngrid:\n  gamma_r: [1.0, 2.0]\n  gap: -1\n  theta: 0.3\n"
              "  sigma: 0.05\n  gamma_s: 1.0\n")  # fmt: skip
    page.get_by_role("button", name="Submit study").click()
    item = page.locator("#problem-list li").first
    item.wait_for()
    assert re.match(r"grid\.gap \(line 4\): gap must be >= 0, got -1", item.inner_text())
    assert page.get_attribute("#study-text", "aria-invalid") == "true"
    assert any("422" in e for e in page.console_errors)  # the refused submission
    page.console_errors.clear()
    # The example opens its page, settles at every point and draws its map without an error.
    page.get_by_role("button", name="Insert the example").click()
    page.get_by_role("button", name="Submit study").click()
    page.wait_for_url(re.compile(r"#/studies/[0-9a-f]+$"))
    _expect_text(page, "h1", "my-first-study")
    _expect_text(page, "#study-live", "finished, 100 %", timeout=120_000)
    chart = page.locator('#map-chart svg[data-chart="map"]')
    chart.wait_for()
    assert int(chart.get_attribute("data-points")) == 24  # 12 γ_r × 2 gaps, every one finite
    for glyph in ("□", "✖"):  # no unsettled or failed point
        assert page.locator("#map-chart text", has_text=glyph).count() == 0
    _expect_count(page, "#curve-chart svg path[data-series]", 4)
    assert page.console_errors == []


def test_cancel_then_delete(page: Any, server: Server) -> None:
    page.on("dialog", lambda d: d.accept())  # the "delete?" confirmation
    with Client(server.url) as c:
        d = tiny_study(name="web-slow", num=150, gaps=(0.1, 0.3, 0.5, 0.7), **SLOW_SOLVER)
        rec = c.submit(d)
        page.goto(f"{server.url}/#/studies/{rec['id']}")
        _expect_text(page, "#study-live", "^(queued|running)")
        page.get_by_role("button", name="Cancel").click()
        _expect_text(page, "#study-live", "^cancelled", timeout=30_000)
        assert c.get(rec["id"])["status"] == "cancelled"
        assert page.get_by_role("button", name="Resume").is_enabled()
        page.get_by_role("button", name="Delete…").click()
        page.wait_for_url(re.compile(r"#/$"))
        _expect_text(page, "#studies-summary", "No studies yet")
        assert c.list().total == 0


def test_with_a_token_the_page_asks_for_it_once(page: Any, tmp_path: Path,
                                                dask_address: str) -> None:  # fmt: skip
    srv = Server(tmp_path / "data", dask_address, token=TOKEN)
    try:
        with Client(srv.url, token=TOKEN) as c:
            c.submit(tiny_study(name="web-token", num=4, gaps=(0.1,)))
        page.goto(f"{srv.url}/")
        dialog = page.locator("#token-dialog")
        dialog.wait_for(state="visible")
        page.fill("#token-input", "wrong")
        page.keyboard.press("Enter")
        _expect_text(page, "#token-why", "refused")
        page.fill("#token-input", TOKEN)
        page.get_by_role("button", name="Use token").click()
        page.get_by_role("link", name="web-token").click()
        page.locator('#map-chart svg[data-chart="map"]').wait_for()
        assert not dialog.is_visible()  # kept for the tab: never asked again
        assert page.evaluate("sessionStorage.getItem('impactcell.token')") == TOKEN
    finally:
        srv.stop()


def test_regressions_list_the_moved_points(page: Any, server: Server) -> None:
    moved = {
        "kind": "value", "variable": "transmittance_db", "coords": {"gamma_r": 1.2, "gap": 0.1},
        "old": -3.0, "new": -2.5, "delta": 0.5, "tolerance": "abs 0.1", "regression": True,
        "note": "",
    }  # fmt: skip
    study = {"study": "tiny", "status": "failed", "ok": False, "points": 12, "regressions": 1,
             "changes": [moved]}  # fmt: skip
    report = {"ok": False, "summary": "1 of 1 studies failed",
              "started": "2026-01-02T02:00:00+00:00", "studies": [study]}  # fmt: skip
    with Client(server.url) as c:
        c.record_regression(report, markdown="# Nightly regression: FAILED\n")
    page.goto(f"{server.url}/#/regressions")
    run = page.locator("details.run").first
    run.wait_for()
    assert "failed" in run.inner_text() and "1 of 1 studies failed" in run.inner_text()
    run.locator("summary").click()
    row = page.locator("table.moved tbody tr").first
    row.wait_for()
    cells = [c.strip() for c in row.locator("td").all_inner_texts()]
    assert cells[:6] == ["tiny", "γ_r = 1.2, gap g̃ = 0.1", "transmittance_db", "value", "-3",
                         "-2.5"]  # fmt: skip


def test_an_adaptive_study_page_draws_its_samples_and_located_edges(
    page: Any, server: Server
) -> None:
    from tests.service.studies.test_adaptive_studies import adaptive_study

    with Client(server.url) as c:
        rec = c.submit(adaptive_study("web-adaptive"))
        rec = c.wait(rec["id"], progress=False, timeout=180, poll=0.2)
    page.goto(f"{server.url}/#/studies/{rec['id']}")
    chart = page.locator('#map-chart svg[data-chart="map"]')
    chart.wait_for()
    # the map shows the union of the lines' samples; no cell is marked failed for a value a
    # line did not take, and the edges listed are the located ones
    assert page.locator("#map-chart text", has_text="✖").count() == 0
    _expect_text(page, "#band-edges", r"\d")
    _expect_count(page, "#curve-chart svg path[data-series]", 4)
    # each line's curve runs through its own samples: one unbroken path (a single move-to)
    d = page.locator("#curve-chart svg path[data-series]").first.get_attribute("d")
    assert d.count("M") == 1
    assert page.console_errors == []


def test_a_chain_study_page_draws_every_cells_transmittance(page: Any, server: Server) -> None:
    from tests.service.studies.test_chain_studies import chain_study

    with Client(server.url) as c:
        rec = c.wait(c.submit(chain_study())["id"], progress=False, timeout=180, poll=0.2)
    page.goto(f"{server.url}/#/studies/{rec['id']}")
    page.locator('#map-chart svg[data-chart="map"]').wait_for()
    # cells N is the map's y: a Γ_j and a Γ_j,lin curve per N, over the cells j = 1, 2
    _expect_count(page, "#cell-chart svg path[data-series]", 4)
    _expect_label(page, "#cell-chart svg", "Γ_j along the chain at γ_r = 1.6")
    series = page.locator("#cell-chart svg path[data-series]").evaluate_all(
        "ps => ps.map(p => p.getAttribute('data-series'))"
    )
    assert {"cells N = 1", "cells N = 2", "cells N = 2 (Γ_j,lin)"} <= set(series)
    page.select_option("#cell-at", "2.5")
    _expect_label(page, "#cell-chart svg", "Γ_j along the chain at γ_r = 2.5")
    assert page.locator("#cell-at-label").inner_text() == "at γ_r ="
    assert page.console_errors == []


def test_a_physical_study_page_reads_in_prefixed_si_units(page: Any, server: Server) -> None:
    study = {
        "name": "web-si",
        "solver": FAST_SOLVER,
        "physical": TABLE1_CELL,
        "grid": {"base_amplitude_m": [0.00025, 0.0005, 0.001], "frequency_hz": [12, 20, 30]},
    }
    with Client(server.url) as c:
        rec = c.wait(c.submit(study)["id"], progress=False, timeout=120, poll=0.2)
    page.goto(f"{server.url}/#/studies/{rec['id']}")
    page.locator('#map-chart svg[data-chart="map"]').wait_for()
    _expect_count(page, "#curve-chart svg path[data-series]", 6)  # Γ and Γ_lin, 3 amplitudes
    series = page.locator("#curve-chart svg path[data-series]").evaluate_all(
        "ps => ps.map(p => p.getAttribute('data-series'))"
    )
    assert {"U_g = 0.25 mm", "U_g = 0.5 mm", "U_g = 1 mm"} <= set(series)
    assert page.locator("#map-chart svg text", has_text="U_g (mm)").count() == 1
    assert not any("base_amplitude_m" in s or "e-4" in s for s in series)
    assert page.console_errors == []


def test_the_api_docs_render_every_operation_with_the_authorize_button(
    page: Any, tmp_path: Path, dask_address: str
) -> None:
    """Swagger UI at /docs reads the service's OpenAPI 3.1 (served offline), lists every
    operation and offers Authorize for the token; no render error."""
    srv = Server(tmp_path / "data", dask_address, token=TOKEN)
    try:
        spec = httpx.get(f"{srv.url}/openapi.json", timeout=10).json()
        assert spec["openapi"].startswith("3.1")
        ops = sum(len(v) for v in spec["paths"].values())
        page.goto(f"{srv.url}/docs")
        page.wait_for_function(
            "n => document.querySelectorAll('.opblock').length >= n", arg=ops, timeout=60_000
        )
        assert page.locator(".opblock").count() == ops
        body = page.inner_text("body")
        assert "Unable to render" not in body and page.locator(".errors-wrapper").count() == 0
        assert page.locator("button.authorize").first.is_visible()
    finally:
        srv.stop()
