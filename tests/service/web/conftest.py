"""Fixtures of the web page tests: headless Chromium from the OS, driven by Playwright.

The browser is Debian's ``chromium`` (``/usr/bin/chromium``, or ``IMPACTCELL_CHROMIUM``), never
one Playwright downloads. Without it the browser tests skip with the reason, except in CI
(``IMPACTCELL_CI`` set, as ``.ci/run`` does), where they fail instead.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

CHROMIUM = os.environ.get("IMPACTCELL_CHROMIUM", "/usr/bin/chromium")


def _missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    if importlib.util.find_spec("playwright") is None:
        return "Playwright for Python is not installed (pip install -e '.[test]')"
    if not Path(CHROMIUM).is_file():
        return f"no Chromium at {CHROMIUM} (Debian: apt-get install chromium)"
    return None


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """One headless Chromium for the session."""
    why = _missing()
    if why:
        if os.environ.get("IMPACTCELL_CI"):
            pytest.fail(f"the browser tests must run in CI (IMPACTCELL_CI is set): {why}")
        pytest.skip(why)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, headless=True)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    """A fresh tab (own session storage) at 1280 × 800 that records what leaves the service:
    requests to other hosts and script errors are test failures. Console errors (a refused
    request among them: Chromium logs every 4xx and 5xx) are kept in ``console_errors`` for
    tests to assert on (a refused submission is one on purpose)."""
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    context.set_default_timeout(30_000)
    p = context.new_page()
    p.foreign: list[str] = []  # type: ignore[attr-defined]
    p.errors: list[str] = []  # type: ignore[attr-defined]
    p.console_errors: list[str] = []  # type: ignore[attr-defined]
    p.on("pageerror", lambda exc: p.errors.append(str(exc)))
    p.on("console", lambda m: p.console_errors.append(f"{m.text} ({m.location.get('url')})")
         if m.type == "error" else None)  # fmt: skip
    p.on("request", lambda r: None if r.url.startswith(("http://127.0.0.1:", "blob:", "data:"))
         else p.foreign.append(r.url))  # fmt: skip
    try:
        yield p
        assert p.foreign == [], f"requests left the machine: {p.foreign}"
        assert p.errors == [], f"script errors: {p.errors}"
    finally:
        context.close()
