"""Provenance of results: the code's git commit, whether its tree was dirty, and versions.

Looked up once per process (``functools.cache``): the git commit and status come from one
``git`` call each the first time they are asked for, never per request or per dataset. Outside
a git checkout (an installed package) they are ``unknown``.
"""

from __future__ import annotations

import re
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path

from worker.cpu import fingerprint

__all__ = ["git_commit", "git_dirty", "package_version", "provenance_attrs", "versions"]

# The folder holding the packages: the repository root in a checkout.
_SOURCE = Path(__file__).resolve().parents[2]
# Libraries whose versions go into every dataset (beside impactcell's own).
_LIBRARIES = ("numpy", "numba", "xarray", "dask")


def _git(*args: str) -> str | None:
    """``git args`` in the source folder: its stdout, or None if git fails."""
    try:
        out = subprocess.run(
            ["git", *args], cwd=_SOURCE, capture_output=True, text=True, timeout=5, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout if out.returncode == 0 else None


@cache
def git_commit() -> str:
    """The commit of the source tree (40 hex digits), or ``unknown``."""
    text = (_git("rev-parse", "HEAD") or "").strip()
    return text if re.fullmatch(r"[0-9a-f]{40}", text) else "unknown"


@cache
def git_dirty() -> str:
    """``yes`` if tracked files differ from the commit, ``no`` if not, else ``unknown``."""
    out = _git("status", "--porcelain", "--untracked-files=no")
    if out is None:
        return "unknown"
    return "yes" if out.strip() else "no"


@cache
def package_version(name: str = "impactcell") -> str:
    """The installed version of a distribution (``unknown`` when not installed)."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "unknown"


def versions() -> dict[str, str]:
    """impactcell's version and those of the libraries that shape the numbers."""
    return {name: package_version(name) for name in ("impactcell", *_LIBRARIES)}


def provenance_attrs() -> dict[str, str]:
    """Dataset attributes: ``impactcell_version``, ``git_commit``, ``git_dirty``,
    ``<library>_version`` for numpy, numba, xarray and dask, and what decides a point's last
    bits (``worker.cpu.fingerprint``: ``numba_cpu``, ``blas_kernels``, ``blas_threads``,
    ``numpy_simd``, ``machine``, ``libc``, the scipy and llvmlite versions). Every worker that
    computes a point of the run is checked to have this same fingerprint before it computes
    (``service.studies.tasks.chunk_task``), so these are the workers' too."""
    v = versions()
    return {
        "impactcell_version": v["impactcell"],
        "git_commit": git_commit(),
        "git_dirty": git_dirty(),
        **{f"{name}_version": v[name] for name in _LIBRARIES},
        **fingerprint(),
    }
