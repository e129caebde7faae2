"""sessions' history: the fixes of every applied batch

Revision ID: 0011
Revises: 0010
Create Date: 2026-12-05 18:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0011"
down_revision: str | None = "0010"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "session_fixes",
        sa.Column("session_id", sa.String(length=32), nullable=False),
        sa.Column("seq", sa.BigInteger(), nullable=False),
        sa.Column("site_id", sa.String(length=32), nullable=False),
        sa.Column("t_first_ms", sa.BigInteger(), nullable=False),
        sa.Column("t_last_ms", sa.BigInteger(), nullable=False),
        sa.Column("n_fixes", sa.Integer(), nullable=False),
        sa.Column("fixes", sa.LargeBinary(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("session_id", "seq", name=op.f("pk_session_fixes")),
    )
    op.create_index(op.f("ix_session_fixes_site_id"), "session_fixes", ["site_id"])
    op.create_index(op.f("ix_session_fixes_created_at"), "session_fixes", ["created_at"])


def downgrade() -> None:
    op.drop_index(op.f("ix_session_fixes_created_at"), table_name="session_fixes")
    op.drop_index(op.f("ix_session_fixes_site_id"), table_name="session_fixes")
    op.drop_table("session_fixes")
