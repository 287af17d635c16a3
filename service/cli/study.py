"""``impactcell run | show | studies``: parameter studies from the command line, without a
service."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from service.cli.common import positive_int, probe_scheduler, settings_from_flags
from service.studies.limits import DEFAULT_CHUNK_SIZE, DEFAULT_MAX_POINTS

__all__ = ["add_commands"]


def _cmd_run(args: argparse.Namespace) -> int:
    # --out, --scheduler and --max-points over IMPACTCELL_DATA_DIR, _SCHEDULER, _MAX_POINTS.
    settings = settings_from_flags(
        {"data_dir": "--out"},
        data_dir=args.out, scheduler=args.scheduler, max_points=args.max_points,
    )  # fmt: skip
    if not settings.scheduler and not args.serial:
        from service.studies import forkserver

        # The embedded cluster's workers are forked from a process that loads the simulator
        # and its kernels on the other core while this one imports and reads the study.
        forkserver.start()

    from service.api.catalogue import Catalogue
    from service.api.points import SqlPointStore
    from service.studies.runner import run_study
    from service.studies.schema import load_study
    from service.studies.shipped import resolve_study_file

    study = load_study(resolve_study_file(args.study), max_points=settings.max_points)
    if settings.scheduler and not args.serial:
        # dask waits 30 s for a scheduler that is down; a probe says so in milliseconds.
        probe_scheduler(
            settings.scheduler, "--scheduler" if args.scheduler else "IMPACTCELL_SCHEDULER"
        )
    bar: Any = None
    progress = None
    if not args.no_progress:
        from tqdm import tqdm

        def progress(done: int, total: int) -> None:
            nonlocal bar
            if bar is None:
                bar = tqdm(
                    total=total,
                    initial=done,
                    unit="pt",
                    desc=study.name,
                    file=sys.stderr,
                    dynamic_ncols=True,
                    smoothing=0.1,
                )
            else:
                bar.update(done - bar.n)

    # The point store of the catalogue database (a SQLite file in the data dir by default):
    # points it knows are not computed again.
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    catalogue = Catalogue(settings.catalogue_url())
    try:
        s = run_study(
            study,
            settings.data_dir,
            scheduler=settings.scheduler,
            workers=args.workers,
            chunk_size=args.chunk_size,
            serial=args.serial,
            progress=progress,
            points=SqlPointStore(catalogue.engine),
        )
    finally:
        catalogue.close()
        if bar is not None:
            bar.close()
    if args.json:
        print(json.dumps({**s.__dict__, "path": str(s.path)}))
        return 0
    print(f"study      {study.name} ({s.study_id})")
    print(f"points     {s.points:,}{' (already complete)' if s.cached else ''}")
    print(f"computed   {s.computed:,}")
    print(f"reused     {s.reused:,} (the point store, or an earlier run's chunks)")
    print(f"failed     {s.failed:,}")
    print(f"irregular  {s.irregular:,}")
    print(f"unsettled  {s.unsettled:,}")
    print(f"time       {s.wall_s:.2f} s wall, {s.kernel_s:.2f} s in kernels")
    print(f"file       {s.path}")
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    import numpy as np

    from service.studies.dataset import open_results, summarize
    from service.studies.variables import OUTCOMES

    ds = open_results(args.file)
    # Any NetCDF file opens; only a study's results have these (older ones lack ``outcome``).
    if "failed" not in ds or "study_id" not in ds.attrs:
        raise ValueError(
            f"{args.file} is not an impactcell results file (no 'failed' variable or "
            "'study_id' attribute); `impactcell run` writes them to DIR/studies/<id>/results.nc"
        )
    if args.json:
        print(json.dumps({**summarize(ds), "attrs": {k: str(v) for k, v in ds.attrs.items()}}))
        return 0
    counts = summarize(ds)
    a = ds.attrs
    print(f"study      {a.get('study_name', '?')} ({a.get('study_id', '?')})")
    print(
        f"created    {a.get('created', '?')}  solver {a.get('solver_version', '?')}  "
        f"impactcell {a.get('impactcell_version', '?')}  git {a.get('git_commit', '?')}"
    )
    outcomes = "  ".join(f"{k} {counts[k]:,}" for k in OUTCOMES if k != "failed" and k in counts)
    print(f"points     {counts['points']:,}  failed {counts['failed']:,}  {outcomes}".rstrip())
    sizes = ", ".join(f"{k}={v}" for k, v in ds.sizes.items() if k != "stop")
    print(f"dimensions {sizes or '-'}")
    for name, c in ds.coords.items():
        if name == "stop":
            continue
        v = c.values
        rng = f"{v.item():g}" if v.ndim == 0 else f"{np.min(v):g} … {np.max(v):g} ({v.size})"
        print(f"  {name:<22} {rng:<28} {c.attrs.get('units', '')}")
    print("variables")
    for name, v in ds.data_vars.items():
        vals = v.values
        if vals.dtype.kind == "f" and np.isfinite(vals).any():
            stat = f"{np.nanmin(vals):.4g} … {np.nanmax(vals):.4g}"
        else:
            stat = ""
        print(f"  {name:<22} {stat:<28} {v.attrs.get('units', '')}")
    return 0


def _cmd_studies(args: argparse.Namespace) -> int:
    from service.studies.schema import StudyError, load_study
    from service.studies.shipped import shipped_studies

    rows = []
    for name, path in shipped_studies().items():
        try:
            study = load_study(path)
        except StudyError as exc:  # a shipped file that does not validate: say so, list the rest
            rows.append({"name": name, "points": None, "description": f"invalid: {exc}"})
            continue
        first = study.description.strip().splitlines()[0] if study.description.strip() else ""
        rows.append({"name": name, "points": study.size, "description": first})
    if args.json:
        print(json.dumps(rows))
        return 0
    width = max((len(r["name"]) for r in rows), default=0)
    for r in rows:
        points = "?" if r["points"] is None else f"{r['points']:,}"
        print(f"{r['name']:<{width}}  {points:>7} points  {r['description']}")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``run``, ``show`` and ``studies``."""
    p = sub.add_parser("run", help="run (or resume) a parameter study")
    p.add_argument(
        "study",
        help="study file (.yaml, .yml or .json), or the name of a shipped study "
        "(`impactcell studies` lists them); a file that exists wins",
    )
    p.add_argument("--out", default=None, help="data root (default $IMPACTCELL_DATA_DIR or ./data)")
    p.add_argument(
        "--scheduler",
        default=None,
        help="dask scheduler address, e.g. tcp://host:8786 (default "
        "$IMPACTCELL_SCHEDULER, else an embedded LocalCluster)",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="worker processes of the embedded cluster (default: one per core)",
    )
    p.add_argument(
        "--chunk-size",
        type=positive_int,
        default=None,
        help=f"points per dask task (default {DEFAULT_CHUNK_SIZE}, less for small studies)",
    )
    p.add_argument(
        "--max-points",
        type=positive_int,
        default=None,
        help=f"grid size limit (default $IMPACTCELL_MAX_POINTS or {DEFAULT_MAX_POINTS:,})",
    )
    p.add_argument("--serial", action="store_true", help="run in this process, without dask")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="summary as one JSON object")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("show", help="summarise a results file")
    p.add_argument("file", help="results file (.nc)")
    p.add_argument("--json", action="store_true", help="summary as one JSON object")
    p.set_defaults(func=_cmd_show)

    p = sub.add_parser(
        "studies",
        help="list the shipped studies (names for `impactcell run NAME`)",
        description="The studies shipped with the package: name, points, one-line description.",
    )
    p.add_argument("--json", action="store_true", help="the list as one JSON array")
    p.set_defaults(func=_cmd_studies)
