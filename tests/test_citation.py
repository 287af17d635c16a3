"""LICENSE and CITATION.cff say what pyproject.toml says, and cite the paper implemented."""

from __future__ import annotations

import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_the_license_file_is_the_declared_license() -> None:
    assert PROJECT["license"]["text"] == "MIT"
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")


def test_the_citation_file_cites_this_version_and_the_paper() -> None:
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == PROJECT["version"] and cff["license"] == "MIT"
    paper = cff["preferred-citation"]
    assert "cantilever beam in mass impacting metamaterial" in paper["title"].lower()
    assert [a["family-names"] for a in paper["authors"]] == ["Sethi", "Banerjee", "Manna"]
