"""Running the nightly suite (embedded or through a service URL), and writing baselines.

Baselines are ``<baselines>/<study-file-stem>.nc``: the comparison variables and coordinates of
a results file, with its provenance attributes and ``baseline_created``. Results are always
computed fresh: embedded runs go to a new timestamped folder, and through a service every study
carries the run's tag (``nightly-<time>``, part of the study id), so each run is a new study.

The pieces of a run (:func:`new_run_dir`, :func:`tagged`, :func:`evaluate`,
:func:`not_run`, :func:`make_report`) are shared with the service's own nightly run
(:mod:`service.api.nightly`), which gets its datasets from its job queue instead.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import xarray as xr

from service.regression.compare import StudyComparison, compare, outcomes_of, provenance_of
from service.regression.report import NightlyReport
from service.regression.spec import RegressionSpec
from service.regression.suite import SuiteEntry, SuiteError, load_suite, suite_folders
from service.studies.chunks import atomic_write, data_root
from service.studies.dataset import encoding, open_results, summarize, write_netcdf
from service.studies.provenance import git_dirty
from service.studies.schema import Study, study_from_canonical
from service.studies.shipped import ShippedStudyError, baselines_dir, in_source_checkout

__all__ = [
    "check_baseline_folder",
    "check_baselines",
    "check_service",
    "evaluate",
    "make_report",
    "new_run_dir",
    "not_run",
    "run_suite",
    "tagged",
    "write_baseline",
]


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def write_baseline(
    ds: xr.Dataset, path: str | os.PathLike[str], spec: RegressionSpec, *, source: str = ""
) -> Path:
    """Write the comparison variables and coordinates of ``ds`` as a baseline (atomic, zlib).

    The results' global attributes (version, git commit, solver version and settings, study)
    are kept, the study without its run tag (a baseline outlives the run it was cut from);
    ``baseline_created``, ``baseline_source`` and ``git_dirty`` are added.
    """
    keep = [v for v in spec.variables() if v in ds.data_vars]
    out = ds[keep]
    if "stop" in out.coords and not any("stop" in out[v].dims for v in keep):
        out = out.drop_vars("stop")
    out.attrs = {
        **ds.attrs,
        **_untagged(ds.attrs),
        "baseline_created": _now(),
        "baseline_source": source,
        "baseline_variables": " ".join(keep),
        "git_dirty": git_dirty(),
    }
    p = Path(path)
    enc = encoding(out)
    atomic_write(p, lambda tmp: write_netcdf(out, tmp, enc))
    os.chmod(p, 0o644)  # a shared, committed file (the temporary file was private)
    return p


def _untagged(attrs: dict[str, Any]) -> dict[str, Any]:
    """``study`` and ``study_id`` attributes without the run tag (a baseline outlives its run)."""
    try:
        definition = json.loads(str(attrs.get("study", "")))
    except ValueError:
        return {}
    if not isinstance(definition, dict) or "tag" not in definition:
        return {}
    del definition["tag"]
    study = study_from_canonical(definition, source="baseline")
    return {"study": study.canonical_json(), "study_id": study.id}


def new_run_dir(data_dir: str | os.PathLike[str] | None = None) -> Path:
    """A new folder ``<data_dir>/nightly/<UTC time>[-n]`` for one run, created here.

    Its name is the run's identity: unique in the data dir even for runs in the same second
    (the tag of a run through a service is ``nightly-<name>``).
    """
    base = data_root(data_dir) / "nightly"
    base.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    d, i = base / stamp, 1
    while True:
        try:
            d.mkdir()
            return d
        except FileExistsError:
            d, i = base / f"{stamp}-{i}", i + 1


def tagged(study: Study, tag: str) -> Study:
    """``study`` with the run tag ``tag``: the same definition, a new id (a fresh run)."""
    return study_from_canonical({**study.canonical(), "tag": tag})


def check_baseline_folder(base_dir: Path, update: bool) -> None:
    """Refuse a baseline folder that is not a folder, or writing into installed package data.

    Raises
    ------
    SuiteError
        ``base_dir`` exists and is not a folder; or ``update`` and ``base_dir`` is the shipped
        baselines of an installed package (not a source checkout's ``studies/baselines``).
    """
    if base_dir.exists() and not base_dir.is_dir():
        raise SuiteError([f"baselines {base_dir} is not a folder"])
    if not update:
        return
    try:
        shipped, checkout = baselines_dir(), in_source_checkout()
    except ShippedStudyError:  # no shipped studies installed: base_dir is not theirs
        return
    if not checkout and _same(base_dir, shipped):
        raise SuiteError([
            f"--update-baseline writes baselines, and {base_dir} is the installed package's "
            "copy of the shipped baselines, not a source checkout's studies/baselines; give "
            "the folder to write with --baselines DIR (in a checkout: its studies/baselines)"
        ])  # fmt: skip


def check_baselines(entries: list[SuiteEntry], base_dir: Path, update: bool) -> None:
    """:func:`check_baseline_folder`, and (unless updating) a baseline for every study.

    Checked before anything runs: a run without its baselines could compare nothing.

    Raises
    ------
    SuiteError
        The folder is unusable, or (not updating) it or some study's baseline is missing.
    """
    check_baseline_folder(base_dir, update)
    if update:
        return
    if not base_dir.is_dir():
        raise SuiteError([
            f"baseline folder {base_dir} does not exist; give the right one with --baselines DIR, "
            "or create the baselines with --update-baseline"
        ])  # fmt: skip
    missing = [f"{e.stem}.nc" for e in entries if not (base_dir / f"{e.stem}.nc").is_file()]
    if missing:
        raise SuiteError([
            f"no baseline in {base_dir} for {', '.join(missing)}; create "
            f"{'it' if len(missing) == 1 else 'them'} with --update-baseline"
        ])  # fmt: skip


def check_service(url: str, token: str | None, *, timeout: float = 10.0) -> None:
    """Check that the service at ``url`` answers and accepts ``token``, before any work.

    Raises
    ------
    SuiteError
        Naming the address: not reachable, not an impactcell service, or the token refused.
    """
    import httpx

    from service.client import Client, ClientError

    try:
        with Client(url, token=token, timeout=timeout) as c:
            c.health()
            c.regressions()  # a route behind the token: a wrong token is found now
    except httpx.HTTPError as exc:
        reason = str(exc).strip() or type(exc).__name__
        if reason.startswith("[Errno"):  # "[Errno 111] Connection refused": the words only
            reason = reason.split("]", 1)[-1].strip()
        reason = reason.splitlines()[0]
        raise SuiteError([f"cannot reach the impactcell service at {url}: {reason}"]) from None
    except ClientError as exc:
        raise SuiteError([f"the service at {url} refused the request: {exc}"]) from None
    except ValueError as exc:  # an answer that is not JSON: not an impactcell service
        raise SuiteError([f"{url} does not answer like an impactcell service: {exc}"]) from None


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except OSError:
        return False


def run_suite(
    directory: str | os.PathLike[str] | None = None,
    baselines: str | os.PathLike[str] | None = None,
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
    directory : path, optional
        The suite folder (default the shipped suite, ``studies/nightly``).
    baselines : path, optional
        Baseline folder: ``<file stem>.nc`` per study. Default: the ``baselines`` folder beside
        ``directory``; for the shipped suite the shipped baselines (``studies/baselines``), which
        ``update_baseline`` writes only in a source checkout.
    url, token : str, optional
        Run on an impactcell service (``service.client.Client``) instead of embedded: every
        study is submitted with the run's tag, so the service computes it afresh.
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
        The suite folder or a study file in it is bad, the baseline folder cannot be used or
        (not updating) lacks a study's baseline, or the ``url`` service cannot be reached or
        refuses the token: found before anything runs.

    With ``url``, the finished report is also catalogued on that service
    (``POST /regressions/reports``): ``report.catalogued`` is its URL, or
    ``report.catalogue_error`` says why not.
    """
    t0 = time.perf_counter()
    started = _now()
    suite_dir, base_dir = suite_folders(directory, baselines)
    entries = load_suite(suite_dir, max_points=max_points)
    check_baselines(entries, base_dir, update_baseline)
    if url is not None:
        check_service(url, token)
    run_dir = new_run_dir(data_dir)
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
        elif not serial:
            from service.studies.runner import make_client

            # every method's kernels: the suite's studies use all three
            client, cluster = make_client(scheduler, workers, method=None)
        for k, entry in enumerate(entries, 1):
            t = time.perf_counter()
            cmp = _run_one(entry, base_dir, run_dir, url, client, serial, update_baseline)
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

    mode = url or (
        "embedded, serial" if serial else f"dask {scheduler}" if scheduler else "embedded"
    )
    report = make_report(
        entries, results, suite_dir, base_dir, mode=mode, update=update_baseline,
        started=started, wall_s=time.perf_counter() - t0, report_dir=reports,
    )  # fmt: skip
    if url is not None:
        _catalogue(report, url, token, say)
    return report


MAX_POSTED_CHANGES = 200  # per study, in the copy a service catalogues (report.json has all)


def _catalogue(
    report: NightlyReport, url: str, token: str | None, say: Callable[[str], None]
) -> None:
    """Store the report of a run through ``url`` in that service's catalogue (``GET
    /regressions``), as ``report.catalogued``; a failure is kept in ``report.catalogue_error``
    (the run itself is done and its report written)."""
    from service.client import Client

    data = report.to_json()
    for study in data["studies"]:
        changes = study.get("changes") or []
        if len(changes) > MAX_POSTED_CHANGES:  # keep the body under the service's size limit
            study["changes"] = changes[:MAX_POSTED_CHANGES]
            study["changes_omitted"] = len(changes) - MAX_POSTED_CHANGES
    try:
        with Client(url, token=token) as c:
            rec = c.record_regression(data, report.to_markdown())
    except Exception as exc:  # noqa: BLE001 - reported; the run's verdict stands
        report.catalogue_error = f"{type(exc).__name__}: {exc}"
        say(f"could not catalogue the report on {url}: {report.catalogue_error}")
        return
    report.catalogued = f"{url.rstrip('/')}/regressions/{rec['id']}"
    say(f"report catalogued as {report.catalogued}")


def make_report(
    entries: list[SuiteEntry],
    results: list[StudyComparison],
    suite_dir: Path,
    base_dir: Path,
    *,
    mode: str,
    update: bool,
    started: str,
    wall_s: float,
    report_dir: str | os.PathLike[str],
) -> NightlyReport:
    """The report of a run (noting baselines without a suite file), written to ``report_dir``."""
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
        mode=mode,
        update_baseline=update,
        started=started,
        wall_s=round(wall_s, 3),
        notes=notes,
    )
    report.write(report_dir)
    return report


def not_run(entry: SuiteEntry, message: str, *, status: str = "error") -> StudyComparison:
    """The comparison of a study whose run did not finish (``error`` or ``cancelled``)."""
    return StudyComparison(
        study=entry.stem,
        name=entry.study.name,
        study_id=entry.study.id,
        points=entry.study.size,
        status=status,
        error=message,
    )


def _run_one(
    entry: SuiteEntry,
    base_dir: Path,
    run_dir: Path,
    url: str | None,
    client: Any,
    serial: bool,
    update: bool,
) -> StudyComparison:
    """Run one study, compare it with its baseline, write the baseline when updating."""
    try:
        if url is not None:
            # The service returns an identical earlier study as it is: the run's tag (part of
            # the study id, ignored by the comparison) makes this a fresh run of today's code.
            # The file's own definition is sent (a canonical one fills in defaults that the
            # input rules refuse, e.g. model.xi beside an xi axis).
            rec = client.submit({**entry.definition, "tag": f"nightly-{run_dir.name}"})
            client.wait(rec["id"], progress=False)
            ds = client.dataset(rec["id"])
            where = f"{url} study {rec['id']}"
        else:
            from service.studies.runner import run_study

            summary = run_study(entry.study, run_dir / "runs", client=client, serial=serial)
            ds = open_results(summary.path)
            where = str(summary.path)
    except Exception as exc:  # a run that could not finish is reported, not raised
        return not_run(entry, f"run failed: {type(exc).__name__}: {exc}")
    return evaluate(entry, ds, where, base_dir, update=update)


def evaluate(
    entry: SuiteEntry, ds: xr.Dataset, where: str, base_dir: Path, *, update: bool = False
) -> StudyComparison:
    """Compare a study's finished dataset with its baseline; write the baseline when updating.

    ``where`` says where the results are (a path, or a service and study id) for the report.
    A missing or unreadable baseline is reported, never raised.
    """
    bpath = base_dir / f"{entry.stem}.nc"
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
