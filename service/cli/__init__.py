"""The ``impactcell`` command line: one module per command group, each adding its subcommands.

Errors end a command with one line on stderr (``impactcell: error: ...``) and exit status 2
for bad usage or 1 for a failure (:mod:`service.cli.common`); ``--traceback`` shows the
traceback of an unexpected error instead.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import os
import sys
import threading
from collections.abc import Sequence
from typing import Any, NoReturn

from service.cli import db, nightly, points, service, simulate, study
from service.cli.common import Parser, error_exit_status

__all__ = ["build_parser", "entry", "main"]

# In the order ``impactcell --help`` lists them.
_GROUPS = (simulate, study, service, nightly, points, db)


class _Version(argparse.Action):
    """``--version``: the package's version and the solver's (the one in every study id)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        kwargs.update(nargs=0, default=argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, *args: Any) -> NoReturn:
        from service.studies.provenance import package_version
        from worker.solvers.settings import SOLVER_VERSION

        print(f"impactcell {package_version()} (solver version {SOLVER_VERSION})")
        parser.exit(0)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = Parser(
        prog="impactcell", description="Impacting beam-in-mass metamaterial cell studies."
    )
    parser.add_argument(
        "--version",
        action=_Version,
        help="print impactcell's version and the solver version, then exit",
    )
    parser.add_argument(
        "--traceback",
        action="store_true",
        help="on an unexpected error, show the Python traceback instead of one line",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for group in _GROUPS:
        group.add_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, run, turn errors into one line and an exit status (1 or 2)."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("impactcell: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.traceback:
            raise
        code, message = error_exit_status(exc)
        # One error per line; an error that lists several problems indents the rest under it.
        print(f"impactcell: error: {message}".replace("\n", "\n  "), file=sys.stderr)
        return code


def entry() -> NoReturn:
    """The ``impactcell`` command (and ``python -m service.cli``): :func:`main`, then a quick
    exit.

    Tearing the interpreter down after a command (freeing numba, xarray, pandas, SQLAlchemy
    and the rest module by module) costs 1–1.5 s after every command. Everything a
    command writes is closed by the time :func:`main` returns, so this does the parts of a
    normal exit that matter -- wait for other non-daemon threads, run the ``atexit`` handlers
    (logging, multiprocessing, temporary files), flush stdout and stderr -- and skips the
    rest. An exception out of :func:`main` (``--traceback``) exits the normal way, and so does
    a command run under a profiler, tracer or debugger (``python -m cProfile``, coverage), which
    write their results after the command returns.
    """
    code = main()
    if sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(code)
    threading._shutdown()  # type: ignore[attr-defined]  # what a normal exit does first
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe (``| head``)
            stream.flush()
    os._exit(code)
