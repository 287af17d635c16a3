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
    assert {"name", "points", "adaptive", "description"} == set(rows[0])
    assert [r["adaptive"] for r in rows] == [load_study(p).is_adaptive for p in shipped.values()]


ADAPTIVE = {
    **tiny_study(name="adaptive-tiny"),
    "adaptive": {"axis": "gamma_r", "target": "band_edges", "threshold_db": 0, "tol": 0.05,
                 "min_width": 0.5, "max_points": 30},
    "grid": {"gamma_r": {"start": 0.5, "stop": 3.0, "num": 2}, "gap": 0.1, "theta": 0.3,
             "sigma": 0.05, "gamma_s": 1.0},
}  # fmt: skip


@pytest.mark.slow  # runs a (small) adaptive study
def test_an_adaptive_study_is_announced_with_the_most_it_may_take(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "adaptive-tiny.yaml"
    f.write_text(yaml.safe_dump(ADAPTIVE))
    monkeypatch.setattr("service.studies.shipped.shipped_studies", lambda: {f.stem: f})
    assert main(["studies"]) == 0
    assert "adaptive-tiny  up to 30 points" in capsys.readouterr().out
    assert main(["run", str(f), "--serial", "--no-progress", "--out", str(tmp_path / "d")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("points"))
    taken = int(line.split()[1].replace(",", ""))
    assert 2 <= taken <= 30 and line.endswith(f"{taken:,} (adaptive: up to 30 allowed)")


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


def test_the_docs_list_what_impactcell_studies_lists(capsys: pytest.CaptureFixture[str]) -> None:
    import re

    text = (Path(__file__).resolve().parents[3] / "docs" / "studies.md").read_text()
    section = text.split("## Shipped studies", 1)[1].split("\n## ", 1)[0]
    documented = {
        m.group(1): int(m.group(2).replace(",", ""))
        for m in re.finditer(r"^\| `([\w-]+)` \| ([\d,]+) \|", section, re.MULTILINE)
    }
    assert main(["studies", "--json"]) == 0
    listed = {r["name"]: r["points"] for r in json.loads(capsys.readouterr().out)}
    assert documented == listed
