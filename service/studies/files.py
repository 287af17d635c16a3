"""The one reader of study files and study text: YAML (safe loading) or JSON.

Every way a study definition comes in goes through here: ``impactcell run`` and
:func:`service.studies.schema.load_study` (a file), the nightly suite (a folder of files), and
``POST /studies`` (a request body, whose content type says which format it is).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Literal

__all__ = ["STUDY_SUFFIXES", "StudyFileError", "file_format", "parse_study_text", "read_study_file"]

#: Suffixes of study files (``.json`` is JSON, the others YAML).
STUDY_SUFFIXES = (".yaml", ".yml", ".json")

Format = Literal["json", "yaml"]


class StudyFileError(ValueError):
    """Study text that cannot be read or parsed; ``cause`` is the underlying error."""

    def __init__(self, message: str, cause: BaseException) -> None:
        super().__init__(message)
        self.cause = cause


def file_format(path: str | os.PathLike[str]) -> Format:
    """``json`` for a ``.json`` file, else ``yaml``."""
    return "json" if Path(path).suffix.lower() == ".json" else "yaml"


def parse_study_text(text: str, fmt: Format) -> Any:
    """Parse study text (YAML with ``yaml.safe_load``, or JSON) into plain data.

    Raises
    ------
    StudyFileError
        ``not valid YAML: ...`` or ``not valid JSON: ...``.
    """
    try:
        if fmt == "json":
            return json.loads(text)
        import yaml

        return yaml.safe_load(text)
    except Exception as exc:  # json's ValueError, yaml.YAMLError
        raise StudyFileError(f"not valid {fmt.upper()}: {exc}", exc) from None


def read_study_file(path: str | os.PathLike[str]) -> Any:
    """Read and parse a study file (``.yaml``, ``.yml`` or ``.json``) into plain data.

    Raises
    ------
    StudyFileError
        ``cannot read study file PATH: ...`` or ``PATH: not valid YAML: ...`` (or JSON).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise StudyFileError(f"cannot read study file {p}: {exc.strerror}", exc) from None
    try:
        return parse_study_text(text, file_format(p))
    except StudyFileError as exc:
        raise StudyFileError(f"{p}: {exc}", exc.cause) from None
