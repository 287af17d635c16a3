"""service.api.settings: the one reader of IMPACTCELL_* variables; flags over environment."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.api.settings import DEFAULT_URL, Settings
from service.cli.common import settings_from_flags
from service.studies.chunks import data_root


def test_flags_win_over_the_environment_over_the_default(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("IMPACTCELL_DATA_DIR", "IMPACTCELL_URL", "IMPACTCELL_MAX_POINTS"):
        monkeypatch.delenv(name, raising=False)
    s = settings_from_flags(data_dir=None, url=None)
    assert (s.data_dir, s.url, s.max_points) == (Path("data"), DEFAULT_URL, None)
    monkeypatch.setenv("IMPACTCELL_DATA_DIR", "/env/data")
    monkeypatch.setenv("IMPACTCELL_URL", "http://env:1")
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "10")
    s = settings_from_flags(data_dir=None, url=None, max_points=None)
    assert (s.data_dir, s.url, s.max_points) == (Path("/env/data"), "http://env:1", 10)
    s = settings_from_flags(data_dir="/flag", url="http://flag:2", max_points=20)
    assert (s.data_dir, s.url, s.max_points) == (Path("/flag"), "http://flag:2", 20)


def test_bad_values_name_the_field(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "many")
    with pytest.raises(ValueError, match="IMPACTCELL_MAX_POINTS .many.: must be a valid integer"):
        settings_from_flags()
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "0")
    with pytest.raises(ValueError, match=r"^IMPACTCELL_MAX_POINTS '0': must be greater than or eq"):
        settings_from_flags()  # one line, naming the variable the user set


def test_the_store_defaults_to_the_settings_data_dir() -> None:
    assert data_root(None) == Settings.model_fields["data_dir"].default
