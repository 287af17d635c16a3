"""service.studies.files: the one study-file reader, and the errors each caller reports."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.regression.suite import SuiteError, load_suite
from service.studies.files import StudyFileError, parse_study_text, read_study_file
from service.studies.schema import StudyError, load_study


def test_yaml_and_json_files_read_alike(tmp_path: Path) -> None:
    (tmp_path / "a.yaml").write_text("name: a\ngrid: {gamma_r: 1e-3}\n")
    (tmp_path / "a.json").write_text('{"name": "a", "grid": {"gamma_r": "1e-3"}}')
    assert read_study_file(tmp_path / "a.yaml") == read_study_file(tmp_path / "a.json")


def test_yaml_is_loaded_safely() -> None:
    with pytest.raises(StudyFileError, match="not valid YAML"):
        parse_study_text("!!python/object/apply:os.system ['true']", "yaml")


def test_errors_name_the_file_and_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(StudyFileError, match=r"cannot read study file .*nope\.yaml: No such file"):
        load_study(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.json"
    bad.write_text("{name: 1")
    with pytest.raises(StudyFileError, match=r"bad\.json: not valid JSON: Expecting property"):
        load_study(bad)
    (tmp_path / "list.yaml").write_text("- 1\n")
    with pytest.raises(StudyError, match="a study file must be a mapping of keys to values"):
        load_study(tmp_path / "list.yaml")


def test_suite_reports_the_error_underneath(tmp_path: Path) -> None:
    (tmp_path / "broken.yaml").write_text("name: [unclosed\n")
    with pytest.raises(SuiteError) as info:
        load_suite(tmp_path)
    (problem,) = info.value.problems
    assert problem.startswith(f"{tmp_path / 'broken.yaml'}: cannot read: while parsing")
