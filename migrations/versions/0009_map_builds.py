"""map builds: survey points keep their walk, route and first map version; radio map
versions keep their parent and what the worker built of them

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-04 23:30:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("survey_points") as batch:
        batch.add_column(sa.Column("walk", sa.String(length=64), nullable=True))
        batch.add_column(sa.Column("route", sa.String(length=64), nullable=True))
        batch.add_column(sa.Column("radio_map_id", sa.String(length=32), nullable=True))
        batch.create_index(batch.f("ix_survey_points_radio_map_id"), ["radio_map_id"])
    with op.batch_alter_table("radio_maps") as batch:
        batch.add_column(sa.Column("parent_id", sa.String(length=32), nullable=True))
        batch.add_column(
            sa.Column("build_status", sa.String(length=16), server_default="pending", nullable=False)
        )
        batch.add_column(
            sa.Column("build_attempts", sa.Integer(), server_default="0", nullable=False)
        )
        batch.add_column(
            sa.Column("build_leased_until", sa.DateTime(timezone=True), nullable=True)
        )
        batch.add_column(sa.Column("build_error", sa.Text(), nullable=True))
        batch.add_column(sa.Column("build_seconds", sa.Float(), nullable=True))
        batch.add_column(sa.Column("fix_error", sa.JSON(), nullable=True))
        batch.add_column(sa.Column("artefacts", sa.LargeBinary(), nullable=True))
    # only each building's current version is owed a build; an older one is built if it
    # is activated again
    op.execute(
        "UPDATE radio_maps SET build_status = 'superseded' WHERE EXISTS ("
        " SELECT 1 FROM radio_maps AS newer WHERE newer.building_id = radio_maps.building_id"
        " AND (newer.activated_at > radio_maps.activated_at"
        " OR (newer.activated_at = radio_maps.activated_at AND newer.version > radio_maps.version)))"
    )
    # an upload is one walk (as the service now stores it)
    op.execute("UPDATE survey_points SET walk = upload_id WHERE upload_id IS NOT NULL")


def downgrade() -> None:
    with op.batch_alter_table("radio_maps") as batch:
        for name in (
            "artefacts",
            "fix_error",
            "build_seconds",
            "build_error",
            "build_leased_until",
            "build_attempts",
            "build_status",
            "parent_id",
        ):
            batch.drop_column(name)
    with op.batch_alter_table("survey_points") as batch:
        batch.drop_index(batch.f("ix_survey_points_radio_map_id"))
        batch.drop_column("radio_map_id")
        batch.drop_column("route")
        batch.drop_column("walk")
