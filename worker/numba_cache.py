"""Where numba keeps the compiled kernels: a directory keyed by the worker's source code.

numba keys a cached kernel by the file that defines it (its path and modification time), not by
the files of the functions it calls and compiles into itself. A kernel whose callee changed in
another module would load stale machine code from the cache and compute with old code, and a
fresh checkout (CI, a new machine) would compute something else. Keying the whole cache by a
hash of every source file of ``worker/`` makes any change compile afresh, and identical sources
share one cache wherever they are installed.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:  # not POSIX: no lock, each process compiles what it lacks
    fcntl = None  # type: ignore[assignment]

__all__ = ["configure", "exclusive", "mark_done", "marked_done", "on_disk", "source_key"]

_ROOT = Path(__file__).resolve().parent


def source_key() -> str:
    """A short hash of every ``.py`` file of the worker package (paths and contents)."""
    h = hashlib.sha256()
    for path in sorted(_ROOT.rglob("*.py")):
        h.update(path.relative_to(_ROOT).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _writable(directory: Path) -> bool:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError:
        return False
    return True


def configure() -> str | None:
    """Point numba's cache at ``<base>/numba-<source key>``; return it (None: numba's default).

    The base is ``NUMBA_CACHE_DIR`` when set, else the package's own ``__pycache__`` (where
    numba would cache anyway; older keys there are removed), else the user's cache directory.
    """
    from numba.core import config

    key = f"numba-{source_key()}"
    given = os.environ.get("NUMBA_CACHE_DIR")
    local = _ROOT / "__pycache__"
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "impactcell"
    for base in [Path(given)] if given else [local, user]:
        target = base / key
        if _writable(target):
            if base == local:
                for old in local.glob("numba-*"):
                    if old.name != key:
                        shutil.rmtree(old, ignore_errors=True)
            # Read when each @njit(cache=True) function is defined, so this must run before the
            # kernel modules are imported (worker/__init__.py calls it first).
            config.CACHE_DIR = str(target)
            return str(target)
    return None


def on_disk(function: object) -> bool | None:
    """Whether a ``@njit(cache=True)`` function is in numba's on-disk cache (None: unknown)."""
    try:
        return bool(function._cache._cache_file._load_index())  # type: ignore[attr-defined]
    except Exception:  # numba internals: a missing attribute means we cannot tell
        return None


def _mark(name: str, suffix: str = ".done") -> Path | None:
    from numba.core import config

    return Path(config.CACHE_DIR) / f"{name}{suffix}" if config.CACHE_DIR else None


@contextlib.contextmanager
def exclusive(name: str, on_wait: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold the cache directory's lock ``name`` (an advisory ``flock``, released when the
    process ends however it ends). Processes sharing the cache compile a method one at a time:
    the second waits here, then finds the kernels on disk and loads them. ``on_wait`` is called
    once if another process holds the lock. No lock where the cache has no directory, the lock
    file cannot be opened, or the system has no ``flock``: then both compile, as without it."""
    path = _mark(name, ".lock")
    fd = None
    if path is not None and fcntl is not None:
        with contextlib.suppress(OSError):  # read-only is enough for flock
            fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o666)
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                if on_wait is not None:
                    on_wait()
                fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        if fd is not None:
            os.close(fd)  # closing the file releases the lock


def mark_done(name: str) -> None:
    """Record in the cache directory that ``name`` (a warm-up) finished: all it compiles is
    there, for these sources (the directory is keyed by them). Nothing where it cannot."""
    path = _mark(name)
    if path is not None:
        with contextlib.suppress(OSError):  # a read-only cache: then nothing is ready
            path.touch()


def marked_done(name: str) -> bool:
    """Whether :func:`mark_done` recorded ``name`` for these sources."""
    path = _mark(name)
    return path is not None and path.exists()
