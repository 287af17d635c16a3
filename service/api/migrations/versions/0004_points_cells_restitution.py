"""Chains of N cells and coefficients of restitution in the point store.

Adds ``points.cells``: N of a chain point (docs/chains.md), NULL for the unit cell (every
point stored before, and every N = 1 point after: a unit cell's key and row are unchanged);
and ``points.e1``, ``points.e2``: the stops' coefficients of restitution (docs/model.md §5),
NULL for the points stored before (plastic impacts, e = 0).

Revision ID: 0004
Revises: 0003
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0004"
down_revision: str | Sequence[str] | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Add the chain length (NULL: the unit cell) and the restitution (NULL: 0)."""
    with op.batch_alter_table("points") as batch:
        batch.add_column(sa.Column("cells", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("e1", sa.Float(), nullable=True))
        batch.add_column(sa.Column("e2", sa.Float(), nullable=True))


def downgrade() -> None:
    """Drop the chain length and the restitution."""
    with op.batch_alter_table("points") as batch:
        batch.drop_column("e2")
        batch.drop_column("e1")
        batch.drop_column("cells")
