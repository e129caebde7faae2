"""API keys with scopes, a site, and rotation

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-02 01:20:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # keys made before scopes existed were admin keys, and stay so
    with op.batch_alter_table("api_keys") as batch:
        batch.add_column(
            sa.Column("scopes", sa.String(length=200), server_default="admin", nullable=False)
        )
        batch.add_column(sa.Column("site_id", sa.String(length=32), nullable=True))
        batch.add_column(sa.Column("rotated_at", sa.DateTime(timezone=True), nullable=True))
        batch.create_foreign_key(
            op.f("fk_api_keys_site_id_sites"), "sites", ["site_id"], ["id"], ondelete="CASCADE"
        )


def downgrade() -> None:
    with op.batch_alter_table("api_keys") as batch:
        batch.drop_constraint(op.f("fk_api_keys_site_id_sites"), type_="foreignkey")
        batch.drop_column("rotated_at")
        batch.drop_column("site_id")
        batch.drop_column("scopes")
