"""magnetic map versions record their sample count, known cells and source

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23 16:10:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("magnetic_maps", schema=None) as batch_op:
        batch_op.add_column(sa.Column("n_samples", sa.Integer(), nullable=False, server_default="0"))
        batch_op.add_column(
            sa.Column("known_cells", sa.Integer(), nullable=False, server_default="0")
        )
        batch_op.add_column(
            sa.Column("source", sa.String(length=32), nullable=False, server_default="survey")
        )


def downgrade() -> None:
    with op.batch_alter_table("magnetic_maps", schema=None) as batch_op:
        batch_op.drop_column("source")
        batch_op.drop_column("known_cells")
        batch_op.drop_column("n_samples")
