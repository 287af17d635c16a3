"""``impactcell db upgrade | current | history | downgrade | revision``: catalogue migrations.

``impactcell serve`` upgrades the catalogue when it starts, so these are for doing it ahead of a
deployment, looking at where a database stands, going back before running older code, and (in
a checkout) writing a new revision after a model change.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from service.cli.common import settings_from_flags

__all__ = ["add_commands"]


def _settings(args: argparse.Namespace) -> Any:
    return settings_from_flags(data_dir=args.data_dir, database_url=args.database_url)


def _run(args: argparse.Namespace, action: Any) -> int:
    """``action(settings, shown_url)``, with the catalogue's errors as one line and exit 1."""
    from sqlalchemy.exc import SQLAlchemyError

    from service.api.migrate import CatalogueError
    from service.cli.common import catalogue_error
    from service.cli.service import _without_password

    settings = _settings(args)
    shown = _without_password(settings.catalogue_url())
    try:
        return int(action(settings, shown) or 0)
    except (CatalogueError, SQLAlchemyError) as exc:
        print(f"impactcell: error: {catalogue_error(exc, shown)}", file=sys.stderr)
        return 1


def _sqlite_file_missing(url: str) -> str | None:
    """The path of a SQLite catalogue that does not exist yet (reading it would create it)."""
    from pathlib import Path

    from sqlalchemy import make_url

    u = make_url(url)
    if u.get_backend_name() == "sqlite" and u.database and not Path(u.database).exists():
        return u.database
    return None


def _cmd_upgrade(args: argparse.Namespace) -> int:
    from service.api import migrate

    def action(settings: Any, shown: str) -> int:
        if not settings.database_url:  # the default SQLite file: its folder, as serve makes it
            settings.data_dir.mkdir(parents=True, exist_ok=True)
        before, after = migrate.upgrade(settings.catalogue_url(), args.revision)
        if before == after:
            print(f"catalogue {shown}: at revision {after}, nothing to do")
        else:
            print(f"catalogue {shown}: upgraded from {before or 'nothing'} to {after}")
        return 0

    return _run(args, action)


def _cmd_downgrade(args: argparse.Namespace) -> int:
    from service.api import migrate

    if args.revision == "base" and not args.yes:
        raise ValueError("downgrading to base drops every catalogue table and row; add --yes")

    def action(settings: Any, shown: str) -> int:
        missing = _sqlite_file_missing(settings.catalogue_url())
        if missing:
            print(f"impactcell: error: no catalogue database at {missing}", file=sys.stderr)
            return 1
        before, after = migrate.downgrade(settings.catalogue_url(), args.revision)
        print(f"catalogue {shown}: downgraded from {before or 'nothing'} to {after or 'base'}")
        return 0

    return _run(args, action)


def _cmd_current(args: argparse.Namespace) -> int:
    from service.api import migrate

    def action(settings: Any, shown: str) -> int:
        missing = _sqlite_file_missing(settings.catalogue_url())
        if missing:
            print(f"catalogue {shown}: no database yet (serve or db upgrade creates it)")
            return 0
        rev = migrate.current_revision(settings.catalogue_url())
        head = migrate.head_revision()
        known = {r for r, _ in migrate.history()}
        if rev is None:
            note = "no revision: an empty database, or a catalogue from before migrations"
        elif rev == head:
            note = "head"
        elif rev in known:
            note = f"behind head {head}: impactcell db upgrade"
        else:
            note = f"unknown to this impactcell, whose newest is {head}"
        print(f"catalogue {shown}: {rev or '-'} ({note})")
        return 0

    return _run(args, action)


def _cmd_history(args: argparse.Namespace) -> int:
    from service.api import migrate

    head = migrate.head_revision()
    for rev, doc in migrate.history():
        print(f"{rev}  {doc}{'  (head)' if rev == head else ''}")
    return 0


def _cmd_revision(args: argparse.Namespace) -> int:
    from service.api import migrate

    path = migrate.new_revision(args.message, autogenerate=not args.empty)
    print(path)
    print(
        "review it (autogenerate misses renames and data moves), then run "
        "tests/service/api/test_migrations.py: it checks head against the models",
        file=sys.stderr,
    )
    return 0


def _database_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data-dir", default=None, help="data folder (default ./data)")
    p.add_argument(
        "--database-url",
        default=None,
        help="catalogue SQLAlchemy URL (default $IMPACTCELL_DATABASE_URL, else SQLite in the "
        "data dir)",
    )


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``db`` and its subcommands."""
    db = sub.add_parser(
        "db",
        help="catalogue schema migrations (serve upgrades on start)",
        description="Migrations of the catalogue database's schema (Alembic): upgrade ahead of "
        "a deployment, see where a database stands, go back before running older code.",
    )
    dsub = db.add_subparsers(dest="db_command", required=True)

    p = dsub.add_parser(
        "upgrade",
        help="upgrade the catalogue database (default: to head)",
        description="Upgrade the catalogue database to a revision (default: head, the one "
        "this impactcell needs), creating it when there is none.",
    )
    p.add_argument("revision", nargs="?", default="head", help="target revision (default head)")
    _database_flags(p)
    p.set_defaults(func=_cmd_upgrade)

    p = dsub.add_parser(
        "current",
        help="the catalogue database's revision",
        description="The catalogue database's revision, and whether it is this impactcell's "
        "head, behind it, or unknown to it.",
    )
    _database_flags(p)
    p.set_defaults(func=_cmd_current)

    p = dsub.add_parser(
        "downgrade",
        help="downgrade the catalogue database (before older code)",
        description="Downgrade the catalogue database to an older revision, before running "
        "older code on it; 'base' drops every table and row and needs --yes.",
    )
    p.add_argument("revision", help="target revision, or 'base' (drops every table and row)")
    p.add_argument("--yes", action="store_true", help="confirm a downgrade to base")
    _database_flags(p)
    p.set_defaults(func=_cmd_downgrade)

    p = dsub.add_parser(
        "history",
        help="the revisions this impactcell knows, oldest first",
        description="The catalogue revisions this impactcell knows, oldest first, with what "
        "each changes; head is marked.",
    )
    p.set_defaults(func=_cmd_history)

    p = dsub.add_parser(
        "revision",
        help="developers: write the next revision, autogenerated from the models (a checkout)",
        description="Developers, in a source checkout: write the next migration revision, "
        "autogenerated from the models' difference to head (review it before committing).",
    )
    p.add_argument("-m", "--message", required=True, help="what it changes, e.g. 'add owner'")
    p.add_argument("--empty", action="store_true", help="no autogenerate: empty functions")
    p.set_defaults(func=_cmd_revision)
