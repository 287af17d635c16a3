"""``impactcell run``: settings from its flags over IMPACTCELL_* variables (exit 2 when bad)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from service.cli import main
from tests.service.helpers import tiny_study


@pytest.fixture
def study_file(tmp_path: Path) -> Path:
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(tiny_study(num=8)))  # 16 points
    return f


def test_point_limit_from_the_flag_then_the_environment(
    study_file: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "10")
    assert main(["run", str(study_file), "--out", str(study_file.parent)]) == 2
    assert "has 16 points, more than the limit of 10" in capsys.readouterr().err
    assert main(["run", str(study_file), "--max-points", "12"]) == 2
    assert "more than the limit of 12" in capsys.readouterr().err


def test_a_bad_variable_exits_2_naming_the_field(
    study_file: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "lots")
    assert main(["run", str(study_file)]) == 2
    assert "max_points" in capsys.readouterr().err
