"""The point store: computed points keyed by content, their solver settings, study links.

Adds ``points``, ``solvers`` and ``study_points`` (service.api.points), and the studies'
``points_computed`` / ``points_reused`` counts of their last run.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22 23:50:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0002"
down_revision: str | Sequence[str] | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Create the point store's tables and add the studies' reuse counts."""
    op.create_table(
        "solvers",
        sa.Column("key", sa.String(length=32), nullable=False),
        sa.Column("settings", sa.Text(), nullable=False),
        sa.PrimaryKeyConstraint("key"),
    )
    op.create_table(
        "points",
        sa.Column("key", sa.String(length=32), nullable=False),
        sa.Column("version", sa.String(length=16), nullable=False),
        sa.Column("method", sa.String(length=16), nullable=False),
        sa.Column("solver", sa.String(length=32), nullable=False),
        sa.Column("start", sa.String(length=40), nullable=False),
        sa.Column("coupling", sa.String(length=16), nullable=False),
        sa.Column("modes", sa.Integer(), nullable=False),
        sa.Column("theta", sa.Float(), nullable=False),
        sa.Column("sigma", sa.Float(), nullable=False),
        sa.Column("gamma_s", sa.Float(), nullable=False),
        sa.Column("gamma_r", sa.Float(), nullable=False),
        sa.Column("xi", sa.Float(), nullable=False),
        sa.Column("xi_b", sa.Float(), nullable=True),
        sa.Column("g1", sa.Float(), nullable=False),
        sa.Column("g2", sa.Float(), nullable=False),
        sa.Column("outcome", sa.String(length=16), nullable=False),
        sa.Column("transmittance_db", sa.Float(), nullable=True),
        sa.Column("record", sa.Text(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["solver"], ["solvers.key"]),
        sa.PrimaryKeyConstraint("key"),
    )
    op.create_index(
        "ix_points_version_theta_g1_gamma_r", "points", ["version", "theta", "g1", "gamma_r"]
    )
    op.create_index("ix_points_sigma", "points", ["sigma"])
    op.create_index("ix_points_gamma_r", "points", ["gamma_r"])
    op.create_table(
        "study_points",
        sa.Column("study_id", sa.String(length=64), nullable=False),
        sa.Column("idx", sa.Integer(), nullable=False),
        sa.Column("key", sa.String(length=32), nullable=False),
        sa.PrimaryKeyConstraint("study_id", "idx"),
    )
    op.create_index("ix_study_points_key", "study_points", ["key"])
    with op.batch_alter_table("studies") as batch:
        batch.add_column(
            sa.Column("points_computed", sa.Integer(), server_default=sa.text("0"), nullable=False)
        )
        batch.add_column(
            sa.Column("points_reused", sa.Integer(), server_default=sa.text("0"), nullable=False)
        )


def downgrade() -> None:
    """Drop the point store (and every stored point) and the reuse counts."""
    with op.batch_alter_table("studies") as batch:
        batch.drop_column("points_reused")
        batch.drop_column("points_computed")
    op.drop_index("ix_study_points_key", table_name="study_points")
    op.drop_table("study_points")
    op.drop_index("ix_points_gamma_r", table_name="points")
    op.drop_index("ix_points_sigma", table_name="points")
    op.drop_index("ix_points_version_theta_g1_gamma_r", table_name="points")
    op.drop_table("points")
    op.drop_table("solvers")
