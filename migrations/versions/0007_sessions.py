"""sessions kept in SQL too, to rebuild them after the session store lost its data

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-02 01:45:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "sessions",
        sa.Column("id", sa.String(length=32), nullable=False),
        sa.Column("site_id", sa.String(length=32), nullable=False),
        sa.Column("engine", sa.String(length=64), nullable=False),
        sa.Column("token_digest", sa.String(length=64), nullable=False),
        sa.Column("entropy", sa.String(length=32), nullable=False),
        sa.Column("contribute", sa.Boolean(), nullable=False),
        sa.Column("device_model", sa.String(length=128), nullable=False),
        sa.Column("epoch", sa.String(length=64), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("last_active_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("ended_at", sa.DateTime(timezone=True), nullable=True),
        sa.ForeignKeyConstraint(
            ["site_id"], ["sites.id"], name=op.f("fk_sessions_site_id_sites"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_sessions")),
    )
    op.create_index(op.f("ix_sessions_site_id"), "sessions", ["site_id"], unique=False)
    op.create_index(
        op.f("ix_sessions_last_active_at"), "sessions", ["last_active_at"], unique=False
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_sessions_last_active_at"), table_name="sessions")
    op.drop_index(op.f("ix_sessions_site_id"), table_name="sessions")
    op.drop_table("sessions")
