"""Fencing tokens: the leases' generation.

Adds ``leases.generation``: one more at every acquisition of a lease that is not its live
holder renewing it, so a study's writes can be checked against the token of the process that
runs it (service.studies.fence).

Revision ID: 0003
Revises: 0002
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0003"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Add the leases' generation (0 for the leases there are)."""
    with op.batch_alter_table("leases") as batch:
        batch.add_column(
            sa.Column("generation", sa.Integer(), server_default=sa.text("0"), nullable=False)
        )


def downgrade() -> None:
    """Drop the leases' generation."""
    with op.batch_alter_table("leases") as batch:
        batch.drop_column("generation")
