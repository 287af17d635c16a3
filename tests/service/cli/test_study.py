"""``impactcell run``: settings from its flags over IMPACTCELL_* variables (exit 2 when bad);
shipped studies by name (``impactcell run quick``, ``impactcell studies``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from service.cli import main
from service.studies.shipped import shipped_studies
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
    assert "IMPACTCELL_MAX_POINTS 'lots': must be a valid integer" in capsys.readouterr().err
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "0")  # a flag wins over a bad variable
    assert main(["run", str(study_file), "--max-points", "5", "--scheduler", ""]) == 2
    assert "more than the limit of 5" in capsys.readouterr().err


# --------------------------------------------------------------------------- shipped studies


def test_studies_lists_every_shipped_study_with_its_description(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from service.studies.schema import load_study

    assert main(["studies"]) == 0
    lines = capsys.readouterr().out.splitlines()
    shipped = shipped_studies()
    assert len(lines) == len(shipped)
    for line, (name, path) in zip(lines, shipped.items(), strict=True):
        study = load_study(path)
        assert line.startswith(name + " ")
        assert f"{study.size:,} points" in line
        assert line.endswith(study.description.strip().splitlines()[0])
    assert main(["studies", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == list(shipped)
    assert {"name", "points", "description"} == set(rows[0])


def test_an_unknown_study_name_lists_the_shipped_ones(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["run", "quik", "--serial"]) == 2
    err = capsys.readouterr().err
    assert "'quik' is neither a study file nor a shipped study" in err
    assert ", ".join(shipped_studies()) in err  # every shipped name, sorted
    assert not (tmp_path / "data").exists()


@pytest.mark.slow
def test_run_a_shipped_study_by_name_from_any_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)  # no studies/ folder here
    out = tmp_path / "out"
    args = ["run", "paper-fig6-theta-sweep", "--serial", "--no-progress", "--json"]
    assert main([*args, "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["points"] == 30 and Path(summary["path"]).is_file()
    assert Path(summary["path"]).is_relative_to(out)


def test_run_help_gives_the_runners_chunk_size(capsys: pytest.CaptureFixture[str]) -> None:
    # The help is written out (the command's modules stay light to import): it must say what
    # the runner does.
    from service.studies.runner import DEFAULT_CHUNK_SIZE

    with pytest.raises(SystemExit) as exc:
        main(["run", "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"points per dask task (default {DEFAULT_CHUNK_SIZE}, less for small studies)" in text
