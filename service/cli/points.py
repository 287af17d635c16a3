"""``impactcell points | gc``: the point store of the catalogue database, without a service.

``points`` asks the store what is known across studies (the same filters as ``GET /points``)
and writes JSON lines, CSV or NetCDF; ``gc`` removes the points no study uses any more.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from service.cli.common import finite_float, positive_int
from service.cli.db import _database_flags, _run

__all__ = ["add_commands"]

# The parameters of a query (service.api.points.FLOAT_PARAMS; listed here so that --help does
# not import the service: tests/service/cli check the two agree).
PARAMS = ("theta", "sigma", "gamma_s", "gamma_r", "xi", "xi_b", "g1", "g2", "gap")


def _open(settings: Any) -> tuple[Any, Any]:
    """The catalogue and its point store; ValueError (exit 2) when the default SQLite catalogue
    is not there: these commands only read and prune, so a mistyped --data-dir creates
    nothing."""
    from service.api.catalogue import Catalogue
    from service.api.points import SqlPointStore
    from service.cli.db import _sqlite_file_missing

    url = settings.catalogue_url()
    where = "--database-url" if settings.database_url else "--data-dir"
    if not settings.database_url and not settings.data_dir.is_dir():
        raise ValueError(f"--data-dir {settings.data_dir}: no such folder")
    missing = _sqlite_file_missing(url)
    if missing:
        raise ValueError(
            f"{where}: no catalogue database at {missing}; `impactcell run` and "
            "`impactcell serve` create it"
        )
    cat = Catalogue(url)
    return cat, SqlPointStore(cat.engine)


def _query(args: argparse.Namespace) -> Any:
    from service.api.points import PointQuery
    from worker.simulate import SOLVER_VERSION

    values: dict[str, float] = {}
    ranges: dict[str, tuple[float | None, float | None]] = {}
    for name in PARAMS:
        v = getattr(args, name)
        lo, hi = getattr(args, f"{name}_min"), getattr(args, f"{name}_max")
        flag = "--" + name.replace("_", "-")
        if v is not None and (lo is not None or hi is not None):
            raise ValueError(f"give {flag} or a range ({flag}-min, {flag}-max), not both")
        if lo is not None and hi is not None and lo > hi:
            raise ValueError(f"{flag}-min ({lo}) is above {flag}-max ({hi})")
        if v is not None:
            values[name] = v
        elif lo is not None or hi is not None:
            ranges[name] = (lo, hi)
    return PointQuery(
        values=values, ranges=ranges, modes=args.modes, coupling=args.coupling,
        method=args.method, outcome=args.outcome, cells=args.cells,
        version=args.version or SOLVER_VERSION,
        study=args.study,
        limit=10_000,
    )  # fmt: skip


def _cmd_points(args: argparse.Namespace) -> int:
    q = _query(args)

    def action(settings: Any, shown: str) -> int:
        from service.api.points import points_csv, points_dataset
        from service.studies.dataset import write_netcdf

        cat, store = _open(settings)
        try:
            rows = []
            for row in store.iter_query(q):
                rows.append(row)
                if args.max is not None and len(rows) >= args.max:
                    break
        finally:
            cat.close()
        if args.format == "netcdf":
            if not args.output:
                raise ValueError("--format netcdf needs --output FILE")
            write_netcdf(points_dataset(rows), args.output)
        else:
            text = (
                points_csv(rows)
                if args.format == "csv"
                else "".join(json.dumps(r, allow_nan=False) + "\n" for r in rows)
            )
            if args.output:
                Path(args.output).write_text(text)
            else:
                sys.stdout.write(text)
        if args.output:
            print(f"{len(rows):,} points → {args.output}", file=sys.stderr)
        return 0

    return _run(args, action)


def _cmd_gc(args: argparse.Namespace) -> int:
    def action(settings: Any, shown: str) -> int:
        cat, store = _open(settings)
        try:
            n = store.gc(settings.data_dir, dry_run=args.dry_run)
        finally:
            cat.close()
        verb = "would remove" if args.dry_run else "removed"
        print(
            f"{verb} {n['points']:,} points no study uses and {n['links']:,} links of "
            f"{n['studies']:,} studies that no longer exist ({shown})"
        )
        return 0

    return _run(args, action)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``points`` and ``gc``."""
    p = sub.add_parser(
        "points",
        help="query the point store across studies (values or ranges per parameter)",
        description="Computed points of every study in the catalogue database, by parameter "
        "values (matched within a relative 1e-9) or ranges (ends included). --gap means "
        "g1 = g2 = gap.",
    )
    for name in PARAMS:
        flag = "--" + name.replace("_", "-")
        what = "g1 = g2 = gap" if name == "gap" else name
        p.add_argument(flag, dest=name, type=finite_float, default=None, metavar="V",
                       help=f"{what} equal to V (default: any)")  # fmt: skip
        p.add_argument(f"{flag}-min", dest=f"{name}_min", type=finite_float, default=None,
                       metavar="V", help=f"{what} >= V (default: no bound)")  # fmt: skip
        p.add_argument(f"{flag}-max", dest=f"{name}_max", type=finite_float, default=None,
                       metavar="V", help=f"{what} <= V (default: no bound)")  # fmt: skip
    p.add_argument("--modes", type=int, default=None, help="beam modes (default: any)")
    p.add_argument("--coupling", choices=("paper", "full"), default=None,
                   help="coupling model (default: any)")  # fmt: skip
    p.add_argument("--method", default=None, help="solver method (default: any)")
    p.add_argument("--outcome", default=None,
                   help="linear, periodic, irregular, unsettled or failed "
                   "(default: any)")  # fmt: skip
    p.add_argument("--cells", type=positive_int, default=None, metavar="N",
                   help="chains of N cells only, 1 the unit cell (default: any)")  # fmt: skip
    p.add_argument("--version", default=None,
                   help="solver version, or 'all' (default: this impactcell's)")  # fmt: skip
    p.add_argument("--study", default=None,
                   help="only the points of this study id (default: every study's)")  # fmt: skip
    p.add_argument("--format", choices=("json", "csv", "netcdf"), default="json",
                   help="JSON lines, CSV, or NetCDF (with --output) (default: json)")  # fmt: skip
    p.add_argument("--output", "-o", default=None, help="write to this file (default: stdout)")
    p.add_argument("--max", type=int, default=None,
                   help="at most this many points (default: all)")  # fmt: skip
    _database_flags(p)
    p.set_defaults(func=_cmd_points)

    p = sub.add_parser(
        "gc",
        help="remove stored points that no study uses",
        description="Remove from the point store of the catalogue database the points that no "
        "study in it uses any more, and the links of studies that no longer exist. A data dir "
        "without a catalogue is an error; nothing is created.",
    )
    p.add_argument("--dry-run", action="store_true", help="only count what would go")
    _database_flags(p)
    p.set_defaults(func=_cmd_gc)
