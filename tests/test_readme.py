"""The README is for users: short, current, and its tutorial works as written."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from service.studies.schema import parse_study

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _section(title: str) -> str:
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", README, re.S | re.M)
    assert m, f"README has no section {title!r}"
    return m.group(1)


def test_the_readme_is_short_and_tells_no_history() -> None:
    assert len(README.splitlines()) <= 300
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", README), "a dated run belongs in CHANGELOG.md"
    assert not re.search(r"version \d+", README, re.I), "version stories belong in CHANGELOG.md"
    assert "before" not in _section("Speed").lower()


def test_every_speed_figure_names_its_command() -> None:
    rows = [r for r in _section("Speed").splitlines() if r.startswith("| ") and "---" not in r]
    body = rows[1:]  # after the header
    assert 1 <= len(body) <= 8
    for row in body:
        command = row.rstrip(" |").rsplit("|", 1)[1].strip()
        assert command == "same" or command.startswith("`"), row


def test_the_tutorial_study_is_valid_as_written() -> None:
    tutorial = _section("Ten minutes: from my cell to my figure")
    block = re.search(r"```yaml\n(.*?)```", tutorial, re.S)
    assert block, "the tutorial's study file is missing"
    study = parse_study(yaml.safe_load(block.group(1)), source="README tutorial")
    assert study.size == 240  # the size the tutorial promises
    assert "240 points" in tutorial


def test_every_local_link_of_the_readme_exists() -> None:
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README):
        if "://" not in target:
            assert (ROOT / target).exists(), target
