"""uploads carry the floor hint and device model; survey points remember their upload

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23 16:30:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("uploads", schema=None) as batch_op:
        batch_op.add_column(sa.Column("floor_level", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("device_model", sa.String(length=128), nullable=True))
    with op.batch_alter_table("survey_points", schema=None) as batch_op:
        batch_op.add_column(sa.Column("upload_id", sa.String(length=32), nullable=True))
        batch_op.create_index(batch_op.f("ix_survey_points_upload_id"), ["upload_id"])
        batch_op.create_foreign_key(
            batch_op.f("fk_survey_points_upload_id_uploads"),
            "uploads",
            ["upload_id"],
            ["id"],
            ondelete="CASCADE",
        )


def downgrade() -> None:
    with op.batch_alter_table("survey_points", schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f("fk_survey_points_upload_id_uploads"), type_="foreignkey")
        batch_op.drop_index(batch_op.f("ix_survey_points_upload_id"))
        batch_op.drop_column("upload_id")
    with op.batch_alter_table("uploads", schema=None) as batch_op:
        batch_op.drop_column("device_model")
        batch_op.drop_column("floor_level")
