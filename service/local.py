"""Run a study in this process, without a service: the Python call behind ``impactcell run``.

>>> from service.local import run
>>> ds = run("mycell.yaml")  # a study file, a shipped study's name, a dict or a Study
>>> ds["transmittance_db"].sel(gap=0.2)

The study runs on an embedded dask ``LocalCluster`` (or the scheduler given), its results file
is written to ``DATA/studies/<id>/results.nc`` and its points to the catalogue's point store,
exactly as ``impactcell run`` does: a point the store already knows is not computed again, and
a finished study is read back from its file. Settings not given come from the ``IMPACTCELL_*``
variables (``IMPACTCELL_DATA_DIR``, ``IMPACTCELL_SCHEDULER``, ``IMPACTCELL_MAX_POINTS``,
``IMPACTCELL_DATABASE_URL``), then the defaults (``./data``, an embedded cluster).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping
from typing import Any

import xarray as xr

from service.api.settings import Settings
from service.studies.schema import Study
from service.studies.summary import RunSummary

__all__ = ["execute", "load", "progress_bar", "run"]

StudyLike = Study | Mapping[str, Any] | str | os.PathLike[str]
Progress = Callable[[int, int], None]


def load(study: StudyLike, *, max_points: int | None = None) -> Study:
    """A validated study from a :class:`Study`, a definition (a mapping, as a study file
    holds), a study file's path or a shipped study's name.

    Raises
    ------
    service.studies.schema.StudyError
        Every problem of the definition, each with its path (a ``ValueError``).
    ValueError
        A file that cannot be read, or a name that is neither a file nor a shipped study.
    """
    from service.studies.schema import load_study, parse_study
    from service.studies.shipped import resolve_study_file

    if isinstance(study, Study):
        return study
    if isinstance(study, Mapping):
        return parse_study(study, max_points=max_points)
    return load_study(resolve_study_file(study), max_points=max_points)


def progress_bar(name: str) -> tuple[Progress, Callable[[], None]]:
    """A tqdm progress bar on stderr fed by a run's ``progress(done, total)``, and its close.

    An adaptive study's total is the most it may compute; the bar's total follows it down.
    """
    from tqdm import tqdm

    bar: Any = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, initial=done, unit="pt", desc=name, file=sys.stderr,
                       dynamic_ncols=True, smoothing=0.1)  # fmt: skip
            return
        if total != bar.total:
            bar.total = total
        bar.update(done - bar.n)

    def close() -> None:
        if bar is not None:
            bar.close()

    return progress, close


def execute(
    study: Study,
    settings: Settings,
    *,
    workers: int | None = None,
    chunk_size: int | None = None,
    serial: bool = False,
    progress: Progress | None = None,
) -> RunSummary:
    """Run (or resume) a validated study with the data dir, scheduler and catalogue database
    of ``settings``; its points go to, and are taken from, the catalogue's point store."""
    from service.api.catalogue import Catalogue
    from service.api.points import SqlPointStore
    from service.studies.runner import run_study

    # The point store of the catalogue database (a SQLite file in the data dir by default).
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    catalogue = Catalogue(settings.catalogue_url())
    try:
        return run_study(
            study, settings.data_dir, scheduler=settings.scheduler, workers=workers,
            chunk_size=chunk_size, serial=serial, progress=progress,
            points=SqlPointStore(catalogue.engine),
        )  # fmt: skip
    finally:
        catalogue.close()


def run(
    study: StudyLike,
    *,
    data_dir: str | os.PathLike[str] | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    serial: bool = False,
    max_points: int | None = None,
    progress: bool | Progress = False,
) -> xr.Dataset:
    """Run a study in this process and return its results as an in-memory xarray Dataset.

    Parameters
    ----------
    study : Study, mapping, path or str
        A study file (``.yaml``, ``.yml``, ``.json``), a shipped study's name (``"quick"``), a
        definition as a dict, or a :class:`Study`.
    data_dir : path, optional
        Data root (default ``$IMPACTCELL_DATA_DIR`` or ``./data``): the results file is
        ``data_dir/studies/<id>/results.nc``.
    scheduler : str, optional
        ``tcp://host:port`` of a dask scheduler (default ``$IMPACTCELL_SCHEDULER``, else an
        embedded ``LocalCluster``, started for the run and closed after it).
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    serial : bool
        Run in this process without dask.
    max_points : int, optional
        The point limit (default ``$IMPACTCELL_MAX_POINTS`` or 1,000,000).
    progress : bool or callable
        ``True``: a progress bar on stderr; a callable is called as ``progress(done, total)``.

    Raises
    ------
    ValueError
        A study that does not validate (every problem, with its path), a file that cannot be
        read, a bad setting.
    """
    given = {"data_dir": data_dir, "scheduler": scheduler, "max_points": max_points}
    settings = Settings(**{k: v for k, v in given.items() if v is not None})
    s = load(study, max_points=settings.max_points)
    close: Callable[[], None] | None = None
    if progress is True:
        progress, close = progress_bar(s.name)
    try:
        summary = execute(s, settings, workers=workers, serial=serial,
                          progress=progress or None)  # fmt: skip
    finally:
        if close is not None:
            close()
    from service.studies.dataset import open_results

    return open_results(summary.path)
