"""The ``impactcell`` command line: one module per command group, each adding its subcommands."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from service.cli import db, nightly, service, simulate, study

__all__ = ["build_parser", "main"]

# In the order ``impactcell --help`` lists them.
_GROUPS = (simulate, study, service, nightly, db)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="impactcell", description="Impacting beam-in-mass metamaterial cell studies."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for group in _GROUPS:
        group.add_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, run, map bad input to exit status 2."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"impactcell: error: {exc}", file=sys.stderr)
        return 2
