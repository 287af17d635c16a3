"""Screenshots of the web page for the README: ``python docs/screenshots/make.py``.

Starts ``impactcell serve`` on a small dask cluster in a temporary folder, runs a small study
to the end and leaves a slow one running, then saves 1280 × 800 PNGs of the home page, a
study page and the submit page (with a bad study's problems) next to this file. Needs
Playwright and Debian's chromium (``IMPACTCELL_CHROMIUM`` for another path), as the tests.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))  # run as a script from anywhere: the repository's packages

from service.client import Client  # noqa: E402
from tests.service.helpers import SLOW_SOLVER, Server, tiny_study  # noqa: E402

CHROMIUM = os.environ.get("IMPACTCELL_CHROMIUM", "/usr/bin/chromium")
BAD = """\
name: bad-gap
grid:
  gamma_r: {start: 0.5, stop: 3.0, num: 40}
  gap: [0.1, -0.5]
  theta: 0.3
  sigma: 0.05
  gamma_s: 1.0
  omega: 2
"""


def main() -> None:
    """Run the studies and save ``home.png``, ``study.png`` and ``submit.png``."""
    from dask.distributed import LocalCluster
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as cluster:  # fmt: skip
        srv = Server(Path(tmp) / "data", cluster.scheduler_address)
        try:
            with Client(srv.url) as c:
                done = c.submit(tiny_study(name="fig5-gaps", num=40, gaps=(0.1, 0.3, 0.5, 1.0)))
                c.wait(done["id"], progress=False, timeout=300, poll=0.5)
                slow = c.submit(tiny_study(name="wide-sweep", num=200, gaps=(0.1, 0.2, 0.3),
                                           **SLOW_SOLVER))  # fmt: skip
                time.sleep(8)  # long enough for a rate and an ETA
                _shoot(sync_playwright, srv.url, done["id"])
                c.cancel(slow["id"])
        finally:
            srv.stop()


def _shoot(sync_playwright: object, url: str, study_id: str) -> None:
    with sync_playwright() as pw:  # type: ignore[operator]
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{url}/")
        page.locator("#studies tbody tr").nth(1).wait_for()
        page.wait_for_timeout(2500)  # one more poll: rate and ETA of the running study
        _save(page, "home.png")

        page.goto(f"{url}/#/studies/{study_id}")
        page.locator("#mass-chart svg").wait_for()
        page.evaluate("window.scrollTo(0, document.querySelector('#results').offsetTop - 8)")
        page.locator('#map-chart svg[data-chart="map"]').hover(position={"x": 560, "y": 70})
        _save(page, "study.png")

        page.goto(f"{url}/#/submit")
        page.fill("#study-text", BAD)
        page.get_by_role("button", name="Submit study").click()
        page.locator("#problem-list li").first.wait_for()
        _save(page, "submit.png")
        browser.close()


def _save(page: object, name: str) -> None:
    path = HERE / name
    page.mouse.move(0, 0) if name != "study.png" else None  # type: ignore[attr-defined]
    page.screenshot(path=str(path))  # type: ignore[attr-defined]
    print(f"{path.relative_to(ROOT)}: {path.stat().st_size / 1024:.0f} KB")


if __name__ == "__main__":
    main()
