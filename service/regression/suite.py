"""The nightly suite: a folder of study files, each with its ``regression:`` block.

A suite is a folder of study files (the shipped one is ``studies/nightly/*.yaml``, found through
:mod:`service.studies.shipped`). :func:`load_suite` reads every one
(:func:`service.studies.files.read_study_file`), splits off the ``regression:`` block
(:class:`~service.regression.spec.RegressionSpec`) and validates the rest as a study, reporting
every problem of every file at once. Each study's baseline is named by its file's stem.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from service.regression.spec import RegressionSpec
from service.studies.files import STUDY_SUFFIXES, read_study_file
from service.studies.schema import Study, StudyError, parse_study, validation_problems
from service.studies.shipped import baselines_dir, suite_dir
from service.studies.variables import VARIABLES

__all__ = [
    "SuiteEntry",
    "SuiteError",
    "load_suite",
    "suite_folders",
]


class SuiteError(ValueError):
    """Every problem with a suite folder, each with its file and path in the file."""

    def __init__(self, problems: Sequence[str]) -> None:
        self.problems = list(problems)
        super().__init__("nightly suite: " + "\n".join(self.problems))


@dataclass(frozen=True)
class SuiteEntry:
    """One study file of the suite."""

    path: Path
    study: Study
    spec: RegressionSpec
    definition: dict[str, Any]  # the file's study definition without ``regression``

    @property
    def stem(self) -> str:
        """The file name without suffix: the baseline's name."""
        return self.path.stem


def suite_folders(
    directory: str | os.PathLike[str] | None = None,
    baselines: str | os.PathLike[str] | None = None,
) -> tuple[Path, Path]:
    """The suite folder and the baseline folder of a run.

    ``directory`` defaults to the shipped suite (``studies/nightly``), ``baselines`` to the
    ``baselines`` folder beside the suite folder (for the shipped suite: the shipped baselines,
    ``studies/baselines``).
    """
    suite = suite_dir() if directory is None else Path(directory)
    if baselines is not None:
        return suite, Path(baselines)
    return suite, (baselines_dir() if directory is None else suite.parent / "baselines")


def load_suite(
    directory: str | os.PathLike[str] | None = None, *, max_points: int | None = None
) -> list[SuiteEntry]:
    """Read and validate every study file in ``directory`` (sorted by name; default the
    shipped suite).

    ``max_points`` limits each study's grid size (default that of
    :func:`~service.studies.schema.parse_study`).

    Raises
    ------
    SuiteError
        Listing every problem of every file (a ``ValueError``).
    """
    folder = suite_folders(directory)[0]
    if not folder.is_dir():
        raise SuiteError([f"suite folder {folder} does not exist"])
    files = sorted(
        p for p in folder.iterdir() if p.suffix.lower() in STUDY_SUFFIXES and p.is_file()
    )
    if not files:
        raise SuiteError([f"no study files ({', '.join(STUDY_SUFFIXES)}) in {folder}"])
    problems: list[str] = []
    entries: list[SuiteEntry] = []
    stems: dict[str, Path] = {}
    for path in files:
        if path.stem in stems:
            problems.append(
                f"{path}: same name as {stems[path.stem].name}; baselines are named by file stem"
            )
            continue
        stems[path.stem] = path
        try:
            data = read_study_file(path)
        except Exception as exc:  # unreadable, not UTF-8, not YAML/JSON: the error underneath
            problems.append(f"{path}: cannot read: {getattr(exc, 'cause', exc)}")
            continue
        if not isinstance(data, Mapping):
            problems.append(f"{path}: a study file must be a mapping of keys to values")
            continue
        definition = {k: v for k, v in data.items() if k != "regression"}
        errs: list[str] = []
        spec: RegressionSpec | None = None
        block = data.get("regression")
        try:
            spec = RegressionSpec.model_validate({} if block is None else block)
        except ValidationError as exc:
            for where, message in validation_problems(exc):
                errs.append(f"regression{'.' + where if where else ''}: {message}")
        study: Study | None = None
        try:
            study = parse_study(definition, max_points=max_points, source=str(path))
        except StudyError as exc:
            errs += [f"{p}: {m}" if p else m for p, m in exc.problems]
        if study is not None and spec is not None:
            groups = {g for g, on in study.outputs.model_dump().items() if on}
            for name in spec.variables():
                group = VARIABLES[name].group
                if group and group not in groups:
                    errs.append(
                        f"outputs.{group}: the regression compares {name}; switch "
                        f"{group} on (or drop {name} from the regression block)"
                    )
        if errs:
            problems += [f"{path}: {e}" for e in errs]
            continue
        assert study is not None and spec is not None
        entries.append(SuiteEntry(path=path, study=study, spec=spec, definition=definition))
    if problems:
        raise SuiteError(problems)
    return entries
