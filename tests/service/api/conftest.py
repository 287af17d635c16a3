"""Fixtures of the API tests."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.service.api.test_results import QUICK, Served


@pytest.fixture
def served(tmp_path: Path) -> Iterator[Served]:
    """The app without its job runner, with the 36-point ``QUICK`` study submitted."""
    app = Served(tmp_path, QUICK)
    try:
        yield app
    finally:
        app.close()
