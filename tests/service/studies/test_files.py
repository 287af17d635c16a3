"""service.studies.files: the one study-file reader, and the errors each caller reports."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.regression.suite import SuiteError, load_suite
from service.studies.files import StudyFileError, parse_study_text, read_study_file
from service.studies.schema import StudyError, load_study


def test_yaml_and_json_files_read_alike(tmp_path: Path) -> None:
    (tmp_path / "a.yaml").write_text("name: a\ngrid: {gamma_r: 1e-3}\n")
    (tmp_path / "a.json").write_text('{"name": "a", "grid": {"gamma_r": 1e-3}}')
    # YAML 1.1 would read 1e-3 as text; the reader reads it as the number JSON does
    assert read_study_file(tmp_path / "a.yaml") == read_study_file(tmp_path / "a.json")
    assert read_study_file(tmp_path / "a.yaml")["grid"]["gamma_r"] == 0.001


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


# --------------------------------------------------------------------------- hostile text

from service.studies.files import MAX_DEPTH, HugeInteger  # noqa: E402

_GRID = '"grid": {"gamma_r": 1.0, "gap": 0.1, "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0}'


@pytest.mark.parametrize("digits", [401, 5001, 900_000])
def test_huge_json_and_yaml_integers_are_kept_unconverted(digits: int) -> None:
    literal = "1" + "0" * (digits - 1)
    for text, fmt in ((f'{{"a": {literal}, "b": -{literal}}}', "json"),
                      (f"a: {literal}\nb: -{literal}\n", "yaml")):  # fmt: skip
        # never converted: int() is quadratic in the length and refused past 4300 digits
        data = parse_study_text(text, fmt)
        assert isinstance(data["a"], HugeInteger) and data["a"] == float("inf")
        assert data["b"] == float("-inf")
        assert repr(data["a"]) == f"an integer of {digits:,} digits"
    assert parse_study_text('{"a": 400}', "json") == {"a": 400}


def test_long_sexagesimal_yaml_integers_cost_nothing() -> None:
    # YAML 1.1 reads 1:2:3 as base 60; 100k parts would be a quadratic big-int computation
    data = parse_study_text("a: 1" + ":30" * 100_000 + "\n", "yaml")
    assert isinstance(data["a"], HugeInteger)
    assert parse_study_text("a: 1:30\n", "yaml") == {"a": 90}


def _nested(fmt: str, depth: int) -> str:
    if fmt == "json":
        return '{"name": "x", "description": ' + "[" * depth + "]" * depth + ", " + _GRID + "}"
    return "name: x\ndescription: " + "[" * depth + "]" * depth + "\n"


@pytest.mark.parametrize("fmt", ["json", "yaml"])
@pytest.mark.parametrize("depth", [MAX_DEPTH, MAX_DEPTH + 1, 20_000, 100_000])
def test_deep_nesting_is_refused_naming_where_it_is(fmt: str, depth: int) -> None:
    # the top-level mapping is a level too, so MAX_DEPTH lists inside it are one too many
    text = _nested(fmt, depth)
    with pytest.raises(StudyFileError) as info:
        parse_study_text(text, fmt)
    msg = str(info.value)
    assert msg.startswith(f"nested more than {MAX_DEPTH} levels deep at description[0][0]"), msg
    assert "(line " in msg and "column " in msg
    assert not isinstance(info.value.cause, RecursionError)


@pytest.mark.parametrize("fmt", ["json", "yaml"])
def test_nesting_up_to_the_limit_is_read(fmt: str) -> None:
    # the top-level mapping is one level, so MAX_DEPTH - 1 lists fit inside it
    data = parse_study_text(_nested(fmt, MAX_DEPTH - 1), fmt)
    inner = data["description"]
    for _ in range(MAX_DEPTH - 2):
        inner = inner[0]
    assert inner == []


def test_json_strings_with_brackets_do_not_count_as_nesting() -> None:
    text = '{"name": "' + "[{" * 10_000 + '\\"' + '", ' + _GRID + "}"
    assert parse_study_text(text, "json")["name"].startswith("[{[{")


def test_deep_json_path_names_keys_and_indices() -> None:
    text = '{"grid": {"gamma_r": [1, 2, ' + '{"a": ' * 40 + "1" + "}" * 40 + "]}}"
    with pytest.raises(StudyFileError, match=r"at grid\.gamma_r\[2\]\.a\.a\.a…"):
        parse_study_text(text, "json")


def test_yaml_aliases_cannot_nest_deeper_than_the_text() -> None:
    # each anchor is shallow, but aliases stack them: 8 levels × 5 = 40 levels of data
    lines = ["a0: &a0 [[[[[[[[1]]]]]]]]"]
    lines += [f"a{i}: &a{i} [[[[[[[[*a{i - 1}]]]]]]]]" for i in range(1, 5)]
    with pytest.raises(StudyFileError, match=f"nested more than {MAX_DEPTH} levels deep"):
        parse_study_text("\n".join(lines) + "\n", "yaml")
    # and an alias bomb (shared nodes) costs no more than its text
    bomb = ["l0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    bomb += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, 9)]
    data = parse_study_text("\n".join(bomb) + "\n", "yaml")
    assert data["l8"][0][0] is data["l6"]


def test_a_deep_study_file_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "deep.yaml"
    p.write_text(_nested("yaml", 50_000))
    with pytest.raises(StudyFileError, match=r"deep\.yaml: nested more than 32 levels"):
        load_study(p)
