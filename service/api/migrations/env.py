"""Alembic's environment for the catalogue.

Run by Alembic when :mod:`service.api.migrate` (the service's start, ``impactcell db ...``) calls
it, with ``config.attributes["connection"]`` already inside the locked transaction that the
whole migration runs in; this script never connects on its own, so every migration goes
through that lock and the checks around it.
"""

from alembic import context

from service.api.catalogue import metadata

connection = context.config.attributes.get("connection")
if connection is None:
    raise RuntimeError(
        "the catalogue's migrations run through impactcell (impactcell db upgrade, or the "
        "service's start), which passes them a locked connection; not through the alembic "
        "command"
    )
context.configure(
    connection=connection,
    target_metadata=metadata,
    # SQLite alters most things only by copying the table: batch mode does that (elsewhere it
    # emits plain ALTERs).
    render_as_batch=True,
    compare_type=True,
    compare_server_default=True,
)
# The caller's transaction is already open, so this one is Alembic's no-op: all revisions and
# the version stamp commit (or roll back) together with it.
with context.begin_transaction():
    context.run_migrations()
