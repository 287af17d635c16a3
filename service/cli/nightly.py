"""``impactcell nightly``: the regression suite against its baselines (``service.regression``)."""

from __future__ import annotations

import argparse
import json
import sys

from service.cli.common import check_service_url, positive_int, settings_from_flags

__all__ = ["add_commands"]


def _cmd_nightly(args: argparse.Namespace) -> int:
    if args.url is not None and args.serial:
        raise ValueError("--serial runs embedded; it cannot be combined with --url")
    if args.url is not None:
        check_service_url(args.url)  # reachability: run_suite, before any work
    elif not args.serial:
        from service.studies import forkserver

        forkserver.start()  # as ``run``: the workers' forkserver loads while this imports

    from service.regression.run import run_suite

    # --data-dir and --token over IMPACTCELL_DATA_DIR and _API_TOKEN; IMPACTCELL_MAX_POINTS.
    settings = settings_from_flags(
        {"api_token": "--token"}, data_dir=args.data_dir, api_token=args.token
    )

    def log(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    report = run_suite(
        directory=args.suite,
        baselines=args.baselines,
        url=args.url,
        token=settings.api_token,
        data_dir=settings.data_dir,
        update_baseline=args.update_baseline,
        report_dir=args.report,
        workers=args.workers,
        serial=args.serial,
        max_points=settings.max_points,
        log=None if args.quiet else log,
    )
    if args.json:
        extra = {"catalogued": report.catalogued} if report.catalogued else {}
        print(json.dumps({**report.to_json(), **extra}))
    else:
        for s in report.studies:
            extra = f" ({len(s.regressions)} changed points)" if s.regressions else ""
            failed = [f"{d.variable} {d.check}" for d in s.failed_checks]
            if failed:
                extra += f" (distribution: {', '.join(failed)})"
            if s.error:
                extra += f": {s.error}"
            print(f"{s.study:<28} {s.points:>6} points  {s.status}{extra}")
        verdict = "ok" if report.ok else "REGRESSION"
        if args.update_baseline:
            verdict = "updated" if report.ok else "NOT all baselines written"
        print(f"{verdict}: {report.summary()}")
        print(f"{report.wall_s:.1f} s; report in {report.report_dir}")
        if report.catalogued:
            print(f"catalogued as {report.catalogued}")
    if report.catalogue_error:
        print(
            f"impactcell: warning: the report is not in the service's catalogue: "
            f"{report.catalogue_error}",
            file=sys.stderr,
        )
    return 0 if report.ok else 1


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``nightly``."""
    p = sub.add_parser(
        "nightly",
        help="run the regression suite and compare with the baselines",
        description="Run every study in the suite folder and compare it with its baseline. "
        "Exit status 0: no regression; 1: a regression or a run that failed; 2: bad input "
        "(a bad suite, missing baselines, a service that cannot be reached), found before "
        "anything runs.",
    )
    p.add_argument(
        "--url",
        default=None,
        help="run on an impactcell service at this URL (each study tagged with this run, so "
        "the service computes it afresh; the report is catalogued there, GET /regressions) "
        "(default: embedded, no service)",
    )
    p.add_argument(
        "--token",
        default=None,
        help="bearer token of the service (default $IMPACTCELL_API_TOKEN)",
    )
    p.add_argument(
        "--suite", default=None, help="suite folder (default: the shipped suite, studies/nightly)"
    )
    p.add_argument(
        "--baselines",
        default=None,
        help="baseline folder (default: 'baselines' beside --suite; for the shipped suite the "
        "shipped baselines, studies/baselines, which --update-baseline writes only in a source "
        "checkout)",
    )
    p.add_argument(
        "--data-dir", default=None, help="data root (default $IMPACTCELL_DATA_DIR or ./data)"
    )
    p.add_argument(
        "--update-baseline",
        action="store_true",
        help="write the new results as baselines (the report says what changed)",
    )
    p.add_argument(
        "--report", default=None, help="report folder (default <data-dir>/nightly/<timestamp>)"
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="worker processes of the embedded cluster (default: one per core)",
    )
    p.add_argument("--serial", action="store_true", help="run embedded without dask")
    p.add_argument("--quiet", action="store_true", help="no per-study progress on stderr")
    p.add_argument("--json", action="store_true", help="the report as one JSON object")
    p.set_defaults(func=_cmd_nightly)
