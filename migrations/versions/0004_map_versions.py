"""radio map versions as one compressed blob; the current map version is the one
activated last (rollback)

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-23 16:45:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("radio_maps", schema=None) as batch_op:
        batch_op.add_column(sa.Column("arrays", sa.LargeBinary(), nullable=True))
        batch_op.add_column(sa.Column("activated_at", sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table("magnetic_maps", schema=None) as batch_op:
        batch_op.add_column(sa.Column("activated_at", sa.DateTime(timezone=True), nullable=True))
    # versions written before: activated when they were written
    op.execute("UPDATE radio_maps SET activated_at = created_at")
    op.execute("UPDATE magnetic_maps SET activated_at = created_at")
    with op.batch_alter_table("radio_maps", schema=None) as batch_op:
        batch_op.alter_column("activated_at", nullable=False)
    with op.batch_alter_table("magnetic_maps", schema=None) as batch_op:
        batch_op.alter_column("activated_at", nullable=False)


def downgrade() -> None:
    with op.batch_alter_table("magnetic_maps", schema=None) as batch_op:
        batch_op.drop_column("activated_at")
    with op.batch_alter_table("radio_maps", schema=None) as batch_op:
        batch_op.drop_column("activated_at")
        batch_op.drop_column("arrays")
