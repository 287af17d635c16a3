"""The shipped studies: the one accessor of the package data installed from ``studies/``.

The repository's top-level ``studies/`` folder (study files, ``nightly/`` suite, ``baselines/``)
is installed as the data package :data:`PACKAGE` (``pyproject.toml`` maps it with
``package-dir``), so an installed package finds them from any folder: in a source checkout with
an editable install the package *is* the repository's ``studies/`` folder, in a wheel install it
is a folder of site-packages. Every reader of shipped files (``impactcell run NAME``,
``impactcell studies``, ``impactcell demo``, the nightly suite and the service's schedule) goes
through here.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from service.studies.files import STUDY_SUFFIXES

__all__ = [
    "PACKAGE",
    "ShippedStudyError",
    "baselines_dir",
    "in_source_checkout",
    "resolve_study_file",
    "shipped_root",
    "shipped_studies",
    "suite_dir",
]

#: The import name of the data package made from the repository's ``studies/`` folder.
PACKAGE = "service.shipped"


class ShippedStudyError(ValueError):
    """A shipped study or folder that cannot be found (the message lists what there is)."""


def shipped_root() -> Path:
    """The folder of the shipped studies (``studies/`` in a source checkout).

    Raises
    ------
    ShippedStudyError
        The data package is not installed (an editable install made before it existed: run
        ``pip install -e .`` again) or is not a plain folder (a zipped install).
    """
    try:
        root = resources.files(PACKAGE)
    except ModuleNotFoundError:
        raise ShippedStudyError(
            f"the shipped studies (package {PACKAGE}) are not installed; install the package "
            "again (`pip install -e .` in a source checkout, or `pip install impactcell`)"
        ) from None
    if not isinstance(root, Path):
        raise ShippedStudyError(
            f"the shipped studies (package {PACKAGE}) are not a folder on disk ({root}); "
            "install the package unzipped"
        )
    return root


def shipped_studies() -> dict[str, Path]:
    """Shipped study files by name (file name without suffix), sorted by name."""
    root = shipped_root()
    files = (p for p in root.iterdir() if p.is_file() and p.suffix.lower() in STUDY_SUFFIXES)
    return {p.stem: p for p in sorted(files)}


def resolve_study_file(name_or_path: str | os.PathLike[str]) -> Path:
    """A study file given as a path or as the name of a shipped study.

    A path that exists wins; otherwise the text names a shipped study, with or without its
    suffix (``quick`` or ``quick.yaml``).

    Raises
    ------
    ShippedStudyError
        Neither a file nor a shipped name; the message lists the shipped names.
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    text = str(name_or_path)
    shipped = shipped_studies()
    stem = path.stem if path.suffix.lower() in STUDY_SUFFIXES else text
    if path.parent == Path(".") and stem in shipped:
        return shipped[stem]
    raise ShippedStudyError(
        f"study {text!r} is neither a study file nor a shipped study; shipped studies: "
        f"{', '.join(shipped) or 'none'} (`impactcell studies` lists them)"
    )


def suite_dir() -> Path:
    """The shipped nightly suite folder (``studies/nightly``)."""
    return shipped_root() / "nightly"


def baselines_dir() -> Path:
    """The shipped baselines folder (``studies/baselines``)."""
    return shipped_root() / "baselines"


def in_source_checkout() -> bool:
    """Whether the shipped files are a source checkout's ``studies/`` folder (editable install).

    Baselines are written there deliberately (``impactcell nightly --update-baseline``); an
    installed package's copy in site-packages is never written to.
    """
    root = shipped_root()
    return root.name == "studies" and (root.parent / "pyproject.toml").is_file()
