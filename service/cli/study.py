"""``impactcell run | show | plot | studies``: parameter studies from the command line, without
a service."""

from __future__ import annotations

import argparse
import json
import re
from typing import Any

from service.cli.common import finite_float, positive_int, probe_scheduler, settings_from_flags
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

    from service.local import execute, load, progress_bar

    study = load(args.study, max_points=settings.max_points)
    if settings.scheduler and not args.serial:
        # dask waits 30 s for a scheduler that is down; a probe says so in milliseconds.
        probe_scheduler(
            settings.scheduler, "--scheduler" if args.scheduler else "IMPACTCELL_SCHEDULER"
        )
    progress, close = progress_bar(study.name) if not args.no_progress else (None, None)
    try:
        s = execute(study, settings, workers=args.workers, chunk_size=args.chunk_size,
                    serial=args.serial, progress=progress)  # fmt: skip
    finally:
        if close is not None:
            close()
    if args.json:
        print(json.dumps({**s.__dict__, "path": str(s.path)}))
        return 0
    print(f"study      {study.name} ({s.study_id})")
    most = f" (adaptive: up to {study.size:,} allowed)" if study.is_adaptive else ""
    print(f"points     {s.points:,}{' (already complete)' if s.cached else ''}{most}")
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


# Figures `impactcell plot` draws (service.analysis.figures.KINDS; listed here so that --help
# does not import matplotlib and xarray: tests/service/cli check the two agree).
PLOT_KINDS = ("bandgap", "transmittance", "impact-effect", "effective-mass", "hysteresis")
# The option names of service.analysis.figures.figure -> the flags of `impactcell plot`.
_PLOT_FLAGS = {"x": "--x", "y": "--y", "hue": "--hue", "threshold_db": "--threshold-db",
               "variable": "--variable", "reference": "--reference", "jump_db": "--jump-db",
               "tol_db": "--tol-db", "kind": "--kind", "format": "--out"}  # fmt: skip


def _results_of(source: str, data_dir: str | None) -> Any:
    """The results dataset of a results file, or of a study id in the data dir."""
    from pathlib import Path

    from service.studies.chunks import RESULTS_FILE, is_study_id, study_folder
    from service.studies.dataset import open_results

    path = Path(source)
    if not path.exists() and is_study_id(source):
        settings = settings_from_flags(data_dir=data_dir)
        path = study_folder(settings.data_dir, source) / RESULTS_FILE
        if not path.is_file():
            raise ValueError(
                f"study {source} has no results file in {settings.data_dir} ({path}): it has "
                "not finished there, or its data dir is another (--data-dir)"
            )
    ds = open_results(path)
    if "failed" not in ds or "study_id" not in ds.attrs:
        raise ValueError(f"{source} is not an impactcell results file (`impactcell show` tells)")
    return ds


def _selection(pairs: list[str]) -> dict[str, str]:
    """``--sel NAME=VALUE`` flags as a selection (the values are checked against the axes)."""
    sel: dict[str, str] = {}
    for pair in pairs:
        name, eq, value = pair.partition("=")
        if not eq or not name.strip() or not value.strip():
            raise ValueError(f"--sel {pair!r} is not NAME=VALUE, e.g. --sel theta=0.3")
        sel[name.strip()] = value.strip()
    return sel


def _cmd_plot(args: argparse.Namespace) -> int:
    from pathlib import Path

    from service.analysis.figures import describe, figure, map_variable
    from service.analysis.selection import AnalysisError
    from service.cli.simulate import in_flag_terms

    out = Path(args.out or f"{args.kind}.png")
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in ("png", "svg"):
        raise ValueError(f"--out {out}: the file name must end in .png or .svg")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: no such folder {out.parent}")
    sel = _selection(args.sel)
    ds = _results_of(args.results, args.data_dir)
    default = "impact_effect_db" if args.kind == "impact-effect" else "transmittance_db"
    try:
        variable = map_variable(args.variable or default, args.reference)
        image, view, drawn = figure(
            ds, args.kind, fmt, sel, x=args.x, y=args.y, hue=args.hue,
            threshold_db=args.threshold_db, nearest=args.nearest, variable=variable,
            jump_db=args.jump_db, tol_db=args.tol_db,
        )  # fmt: skip
    except AnalysisError as exc:
        text = in_flag_terms(str(exc), _PLOT_FLAGS).replace("nearest=true", "--nearest")
        # "jump_db=0.0 must be positive" -> "--jump-db 0.0 must be positive"
        raise ValueError(re.sub(r"(--[\w-]+)=", r"\1 ", text)) from None
    out.write_bytes(image)
    shown = describe(view)
    axes = " × ".join(a for a in (shown["x"], shown["y"]) if a)
    fixed = ", ".join(f"{k} = {v}" for k, v in shown["fixed"].items())
    print(f"{out}  {args.kind} over {axes}" + (f"; fixed at their first value: {fixed}" if fixed
                                                else ""))  # fmt: skip
    if args.kind in ("bandgap", "impact-effect") and drawn is not None:
        for line in _band_lines(drawn):
            print(line)
    return 0


def _band_lines(m: Any) -> list[str]:
    """What a bandgap map found: what its bands mean, then its bands in x per value of y."""
    from service.analysis.bands import bandgap_json
    from service.cli.service import _spans

    doc = bandgap_json(m)
    lines = [f"bands: {doc['threshold']['meaning']}"]
    for row in doc["edges"]:
        y = row["y"]
        shown = f"{y:g}" if isinstance(y, float | int) else str(y)
        where = "" if doc["y"] is None else f"{doc['y']} {shown}: "
        lines.append(f"  {where}{doc['x']} in {_spans(row['bands'])}")
    return lines


def _cmd_studies(args: argparse.Namespace) -> int:
    from service.studies.schema import StudyError, load_study
    from service.studies.shipped import shipped_studies

    rows = []
    for name, path in shipped_studies().items():
        try:
            study = load_study(path)
        except StudyError as exc:  # a shipped file that does not validate: say so, list the rest
            rows.append({"name": name, "points": None, "adaptive": False,
                         "description": f"invalid: {exc}"})  # fmt: skip
            continue
        first = study.description.strip().splitlines()[0] if study.description.strip() else ""
        # An adaptive study's size is the most it may compute (it stops where it has enough).
        rows.append({"name": name, "points": study.size, "adaptive": study.is_adaptive,
                     "description": first})  # fmt: skip
    if args.json:
        print(json.dumps(rows))
        return 0
    width = max((len(r["name"]) for r in rows), default=0)
    for r in rows:
        points = "?" if r["points"] is None else f"{r['points']:,}"
        points = f"up to {points}" if r["adaptive"] else points
        print(f"{r['name']:<{width}}  {points:>7} points  {r['description']}")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``run``, ``show``, ``plot`` and ``studies``."""
    p = sub.add_parser(
        "run",
        help="run (or resume) a parameter study",
        description="Run a study file (or a shipped study) on an embedded dask cluster, or on "
        "a scheduler, without a service, and write its results file DATA/studies/<id>/"
        "results.nc. Points already in the catalogue's point store and chunks of an earlier "
        "run are not computed again. `impactcell plot` draws its figures.",
    )
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

    p = sub.add_parser(
        "show",
        help="summarise a results file",
        description="The study, versions, point counts by outcome, axes and variables of a "
        "results file.",
    )
    p.add_argument("file", help="results file (.nc)")
    p.add_argument("--json", action="store_true", help="summary as one JSON object")
    p.set_defaults(func=_cmd_show)

    p = sub.add_parser(
        "plot",
        help="draw a figure of a results file (PNG or SVG), as the service's /plots",
        description="The figures of the service's /studies/{id}/plots/{kind}.{png,svg}, with "
        "the same options and defaults, from a results file or a study id in the data dir: "
        "no service needed. Without --x, --y or --hue the axes are chosen as the service "
        "chooses them (x the frequency axis, or the swept one for hysteresis; y and hue the "
        "first other varying axis with few values), and every other varying axis is fixed at "
        "its first value and named in the title and on stdout. A map also prints its bands: "
        "the edges in x per value of y.",
    )
    p.add_argument(
        "results", help="results file (.nc), or the id of a finished study in the data dir"
    )
    p.add_argument(
        "--kind",
        choices=PLOT_KINDS,
        default="bandgap",
        help="the figure: impact-effect is the bandgap map of Γ − Γ_lin",
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        default=None,
        help="the file to write, .png or .svg (default: KIND.png)",
    )
    p.add_argument(
        "--sel",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a value of another axis, e.g. --sel theta=0.3; repeat for more "
        "(default: each at its first value)",
    )
    p.add_argument("--x", metavar="AXIS", default=None, help="x axis (default: the frequency axis)")
    p.add_argument(
        "--y",
        metavar="AXIS",
        default=None,
        help="y axis of a map (default: the first other varying axis with few values)",
    )
    p.add_argument(
        "--hue",
        metavar="AXIS",
        default=None,
        help="one transmittance curve per value of this axis (default as --y)",
    )
    p.add_argument(
        "--variable",
        metavar="NAME",
        default=None,
        help="a map's variable: transmittance_db, transmittance_linear_db or "
        "impact_effect_db; any numeric variable for hysteresis (default: "
        "impact_effect_db for impact-effect, else transmittance_db)",
    )
    p.add_argument(
        "--reference",
        choices=("none", "linear"),
        default="none",
        help="linear: map Γ − Γ_lin, as --variable impact_effect_db",
    )
    p.add_argument(
        "--threshold-db",
        metavar="DB",
        type=finite_float,
        default=None,
        help="a map's band threshold (default: 0 dB, −1 dB for impact_effect_db)",
    )
    p.add_argument(
        "--nearest", action="store_true", help="take the closest axis value to each --sel value"
    )
    p.add_argument(
        "--jump-db",
        metavar="DB",
        type=finite_float,
        default=1.0,
        help="hysteresis: a jump is a step between consecutive points over this",
    )
    p.add_argument(
        "--tol-db",
        metavar="DB",
        type=finite_float,
        default=0.05,
        help="hysteresis: branches differ where they spread over this",
    )
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        default=None,
        help="data root of a study id (default $IMPACTCELL_DATA_DIR or ./data)",
    )
    p.set_defaults(func=_cmd_plot)

    p = sub.add_parser(
        "studies",
        help="list the shipped studies (names for `impactcell run NAME`)",
        description="The studies shipped with the package: name, points, one-line description.",
    )
    p.add_argument("--json", action="store_true", help="the list as one JSON array")
    p.set_defaults(func=_cmd_studies)
