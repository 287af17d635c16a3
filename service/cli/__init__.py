"""The ``impactcell`` command line: one module per command group, each adding its subcommands.

Errors end a command with one line on stderr (``impactcell: error: ...``) and exit status 2
for bad usage or 1 for a failure (:mod:`service.cli.common`); ``--traceback`` shows the
traceback of an unexpected error instead.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from service.cli import db, nightly, points, service, simulate, study
from service.cli.common import Parser, error_exit_status

__all__ = ["build_parser", "main"]

# In the order ``impactcell --help`` lists them.
_GROUPS = (simulate, study, service, nightly, points, db)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = Parser(
        prog="impactcell", description="Impacting beam-in-mass metamaterial cell studies."
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
