"""Running the nightly suite (embedded or through a service URL), and writing baselines.

Baselines are ``<baselines>/<study-file-stem>.nc``: the comparison variables and coordinates of
a results file, with its provenance attributes and ``baseline_created``. Results are always
computed fresh: embedded runs go to a new timestamped folder, and through a service each run is
a new study.
"""

from __future__ import annotations

import datetime as _dt
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import xarray as xr

from service.regression.compare import StudyComparison, compare, outcomes_of, provenance_of
from service.regression.report import NightlyReport
from service.regression.spec import RegressionSpec
from service.regression.suite import (
    DEFAULT_BASELINES,
    DEFAULT_SUITE,
    SuiteEntry,
    SuiteError,
    load_suite,
    resolve,
)
from service.studies.chunks import atomic_write, data_root
from service.studies.dataset import encoding, open_results, summarize
from service.studies.provenance import git_dirty

__all__ = ["run_suite", "write_baseline"]


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def write_baseline(
    ds: xr.Dataset, path: str | os.PathLike[str], spec: RegressionSpec, *, source: str = ""
) -> Path:
    """Write the comparison variables and coordinates of ``ds`` as a baseline (atomic, zlib).

    The results' global attributes (version, git commit, solver version and settings, study)
    are kept; ``baseline_created``, ``baseline_source`` and ``git_dirty`` are added.
    """
    keep = [v for v in spec.variables() if v in ds.data_vars]
    out = ds[keep]
    if "stop" in out.coords and not any("stop" in out[v].dims for v in keep):
        out = out.drop_vars("stop")
    out.attrs = {
        **ds.attrs,
        "baseline_created": _now(),
        "baseline_source": source,
        "baseline_variables": " ".join(keep),
        "git_dirty": git_dirty(),
    }
    p = Path(path)
    enc = encoding(out)
    atomic_write(p, lambda tmp: out.to_netcdf(tmp, engine="netcdf4", encoding=enc))
    os.chmod(p, 0o644)  # a shared, committed file (the temporary file was private)
    return p


def _stamp_dir(base: Path) -> Path:
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    d, i = base / stamp, 1
    while d.exists():
        d, i = base / f"{stamp}-{i}", i + 1
    return d


def _embedded_client(workers: int | None) -> tuple[Any, Any]:
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=40,
    )
    return Client(cluster), cluster


def run_suite(
    directory: str | os.PathLike[str] = DEFAULT_SUITE,
    baselines: str | os.PathLike[str] = DEFAULT_BASELINES,
    url: str | None = None,
    token: str | None = None,
    data_dir: str | os.PathLike[str] | None = None,
    update_baseline: bool = False,
    report_dir: str | os.PathLike[str] | None = None,
    workers: int | None = None,
    *,
    serial: bool = False,
    scheduler: str | None = None,
    max_points: int | None = None,
    log: Callable[[str], None] | None = None,
) -> NightlyReport:
    """Run every study of the suite, compare with the baselines, write the reports.

    Parameters
    ----------
    directory : path
        The suite folder (default ``studies/nightly``).
    baselines : path
        Baseline folder (default ``studies/baselines``): ``<file stem>.nc`` per study.
    url, token : str, optional
        Run on an impactcell service (``service.client.Client``) instead of embedded.
    data_dir : path, optional
        Data root (``Settings.data_dir``; default ``./data``). Embedded runs go to a fresh
        ``<data_dir>/nightly/<timestamp>/runs`` so results are never reused from an earlier run.
    update_baseline : bool
        Write the new results as baselines (the report lists what changed as ``updated``).
    report_dir : path, optional
        Where ``report.json`` and ``report.md`` go (default ``<data_dir>/nightly/<timestamp>``).
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    serial : bool
        Embedded, in this process, without dask.
    scheduler : str, optional
        ``tcp://host:port`` of a dask scheduler to run on instead of an embedded cluster.
    max_points : int, optional
        Grid-size limit of every study (``Settings.max_points``; default the schema's).
    log : callable, optional
        Called with one line of progress per study.

    Raises
    ------
    SuiteError
        The suite folder or a study file in it is bad (nothing is run).
    """
    t0 = time.perf_counter()
    started = _now()
    entries = load_suite(directory, max_points=max_points)
    suite_dir = entries[0].path.parent
    base_dir = resolve(baselines, DEFAULT_BASELINES)
    if base_dir.exists() and not base_dir.is_dir():
        raise SuiteError([f"baselines {base_dir} is not a folder"])
    run_dir = _stamp_dir(data_root(data_dir) / "nightly")
    reports = Path(report_dir) if report_dir is not None else run_dir
    say = log or (lambda _msg: None)

    client: Any = None
    cluster: Any = None
    results: list[StudyComparison] = []
    try:
        if url is not None:
            try:
                from service.client import Client
            except ImportError as exc:
                raise ValueError(
                    f"--url needs service.client, which cannot be imported: {exc}"
                ) from None
            client = Client(url, token=token)
        elif not serial and scheduler:
            from dask.distributed import Client as DaskClient

            client = DaskClient(scheduler, timeout="30s")
        elif not serial:
            client, cluster = _embedded_client(workers)
        for k, entry in enumerate(entries, 1):
            t = time.perf_counter()
            cmp = _run_one(entry, base_dir, run_dir / "runs", url, client, serial, update_baseline)
            cmp.wall_s = round(time.perf_counter() - t, 3)
            results.append(cmp)
            say(
                f"[{k}/{len(entries)}] {entry.stem}: {entry.study.size} points, "
                f"{cmp.wall_s:.1f} s, {cmp.status}"
                + (f" ({len(cmp.regressions)} changed points)" if cmp.regressions else "")
            )
    finally:
        if cluster is not None:
            client.close()
            cluster.close()
        elif client is not None and hasattr(client, "close"):
            client.close()

    notes = []
    if base_dir.is_dir():
        stems = {e.stem for e in entries}
        orphans = sorted(p.name for p in base_dir.glob("*.nc") if p.stem not in stems)
        if orphans:
            notes.append(f"baselines without a suite file (not used): {', '.join(orphans)}")
    report = NightlyReport(
        studies=results,
        suite=str(suite_dir),
        baselines=str(base_dir),
        mode=url
        or ("embedded, serial" if serial else f"dask {scheduler}" if scheduler else "embedded"),
        update_baseline=update_baseline,
        started=started,
        wall_s=round(time.perf_counter() - t0, 3),
        notes=notes,
    )
    report.write(reports)
    return report


def _run_one(
    entry: SuiteEntry,
    base_dir: Path,
    run_root: Path,
    url: str | None,
    client: Any,
    serial: bool,
    update: bool,
) -> StudyComparison:
    """Run one study, compare it with its baseline, write the baseline when updating."""
    bpath = base_dir / f"{entry.stem}.nc"
    label = {"study": entry.stem, "name": entry.study.name, "baseline": str(bpath)}
    try:
        if url is not None:
            # The service returns an identical earlier study as is; a run tag in the
            # description (ignored by the comparison) makes this a fresh run of today's code.
            definition = entry.study.canonical()
            tag = f"nightly run {run_root.parent.name}"
            definition["description"] = f"{definition.get('description') or ''} [{tag}]".strip()
            rec = client.submit(definition)
            client.wait(rec["id"], progress=False)
            ds = client.dataset(rec["id"])
            where = f"{url} study {rec['id']}"
        else:
            from service.studies.runner import run_study

            summary = run_study(entry.study, run_root, client=client, serial=serial)
            ds = open_results(summary.path)
            where = str(summary.path)
    except Exception as exc:  # a run that could not finish is reported, not raised
        return StudyComparison(
            **label,
            study_id=entry.study.id,
            points=entry.study.size,
            status="error",
            error=f"run failed: {type(exc).__name__}: {exc}",
        )

    old: xr.Dataset | None = None
    unreadable = ""
    if bpath.exists():
        try:
            old = open_results(bpath)
        except ValueError as exc:
            unreadable = str(exc)
    if old is not None:
        try:
            cmp = compare(ds, old, entry.spec, study=entry.stem)
        except Exception as exc:  # a malformed baseline: report it, go on with the suite
            cmp = StudyComparison(
                study=entry.stem,
                name=entry.study.name,
                study_id=entry.study.id,
                points=entry.study.size,
                status="error",
                error=f"cannot compare with {bpath}: {type(exc).__name__}: {exc}",
            )
            unreadable = cmp.error
    else:
        cmp = StudyComparison(
            study=entry.stem,
            name=entry.study.name,
            study_id=str(ds.attrs.get("study_id", entry.study.id)),
            points=int(ds["failed"].size),
            counts={"new": summarize(ds, outcomes_of(ds))},
            new_info=provenance_of(ds),
            status="error" if unreadable else "missing-baseline",
            error=unreadable
            or f"no baseline {bpath}; create it with `impactcell nightly --update-baseline`",
        )
    cmp.baseline, cmp.results = str(bpath), where
    if update:
        if cmp.error and (old is not None or unreadable):
            cmp.notes.append(f"replaced a baseline that could not be compared: {cmp.error}")
        cmp.error = None
        cmp.status = "updated" if bpath.exists() else "created"
        write_baseline(ds, bpath, entry.spec, source=str(entry.path.name))
    return cmp
