"""The shipped studies as package data, and the run tag of a study (part of its id)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import xarray as xr

from service.regression.suite import load_suite
from service.studies.schema import StudyError, load_study, parse_study, study_from_canonical
from service.studies.shipped import (
    PACKAGE,
    ShippedStudyError,
    baselines_dir,
    in_source_checkout,
    resolve_study_file,
    shipped_root,
    shipped_studies,
    suite_dir,
)
from tests.service.helpers import tiny_study

ROOT = Path(__file__).resolve().parents[3]
SHIPPED = ("chain-cells", "chain-graded", "chain-uniform-gaps", "demo-fig5",
           "experiment-table1", "hysteresis-frequency-sweep", "hysteresis-gap-sweep",
           "paper-fig5-gaps", "paper-fig5-second-band",
           "paper-fig5-theta1", "paper-fig6-effective-mass", "paper-fig6-theta-sweep",
           "quick", "restitution-gamma")  # fmt: skip


def test_the_package_data_is_the_repositorys_studies_folder() -> None:
    # This checkout is installed editable (README, .ci/run): the package is studies/ itself.
    assert shipped_root() == ROOT / "studies"
    assert in_source_checkout()
    assert tuple(shipped_studies()) == SHIPPED
    assert all(p.parent == ROOT / "studies" for p in shipped_studies().values())
    assert suite_dir() == ROOT / "studies" / "nightly"
    assert baselines_dir() == ROOT / "studies" / "baselines"
    assert PACKAGE == "service.shipped"


def test_every_shipped_study_loads_and_has_a_one_line_description() -> None:
    for name, path in shipped_studies().items():
        study = load_study(path)
        assert study.name == name
        assert study.description.strip(), f"{name} has no description"


def test_every_nightly_study_has_its_baseline() -> None:
    stems = {p.stem for p in suite_dir().glob("*.yaml")}
    assert stems and stems == {p.stem for p in baselines_dir().glob("*.nc")}


def test_a_path_that_exists_wins_over_a_shipped_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve_study_file("quick") == ROOT / "studies" / "quick.yaml"
    assert resolve_study_file("quick.yaml") == ROOT / "studies" / "quick.yaml"
    (tmp_path / "quick.yaml").write_text("name: mine\n")
    assert resolve_study_file("quick.yaml") == Path("quick.yaml")
    assert resolve_study_file(tmp_path / "quick.yaml") == tmp_path / "quick.yaml"
    assert resolve_study_file("quick") == ROOT / "studies" / "quick.yaml"  # no file "quick"


@pytest.mark.parametrize("text", ["nope", "quick.yml.bak", "elsewhere/quick.yaml", "nightly"])
def test_an_unknown_name_lists_the_shipped_ones(text: str) -> None:
    with pytest.raises(ShippedStudyError) as err:
        resolve_study_file(text)
    msg = str(err.value)
    assert repr(text) in msg and "neither a study file nor a shipped study" in msg
    assert ", ".join(SHIPPED) in msg and "impactcell studies" in msg


# --------------------------------------------------------------------------- the run tag


def test_no_tag_keeps_the_id_of_every_shipped_baseline() -> None:
    # Baselines were cut before the tag existed: their recorded ids are today's ids.
    for path in sorted(baselines_dir().glob("*.nc")):
        with xr.open_dataset(path) as ds:
            definition = json.loads(ds.attrs["study"])
            study_id = ds.attrs["study_id"]
        study = study_from_canonical(definition)
        assert "tag" not in study.canonical()
        assert study.id == study_id, path.name


def test_a_canonical_definition_reads_back_even_where_the_input_rules_refuse_it() -> None:
    # paper-params varies xi (model.xi is a default in the canonical form), table1 is physical.
    entries = {e.stem: e for e in load_suite()}
    for name in ("paper-params", "table1"):
        study = entries[name].study
        with pytest.raises(StudyError, match="xi"):
            parse_study(study.canonical())
        again = study_from_canonical(json.loads(study.canonical_json()))
        assert again.id == study.id and again.size == study.size
    with pytest.raises(StudyError) as err:
        study_from_canonical({**study.canonical(), "grid": {"frequency_hz": "x"}})
    assert any(p.startswith("grid.frequency_hz") for p, _ in err.value.problems)


def test_a_tag_is_part_of_the_identity() -> None:
    plain = parse_study(tiny_study())
    a = parse_study({**tiny_study(), "tag": "nightly-20260101T020000Z"})
    b = parse_study({**tiny_study(), "tag": "nightly-20260102T020000Z"})
    assert a.canonical()["tag"] == "nightly-20260101T020000Z"
    assert len({plain.id, a.id, b.id}) == 3
    assert parse_study(a.canonical()).id == a.id
    assert parse_study({**tiny_study(), "tag": None}).id == plain.id  # null is no tag


@pytest.mark.parametrize(
    ("tag", "expected"),
    [("", "at least 1 character"), ("x" * 101, "at most 100 characters"), (3, "valid string")],
)
def test_a_bad_tag_names_the_field(tag: object, expected: str) -> None:
    with pytest.raises(StudyError) as err:
        parse_study({**tiny_study(), "tag": tag})
    assert any(p == "tag" and expected in m for p, m in err.value.problems), err.value.problems
