"""Survey points: the readings placed on a floor, by an operator or an upload."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import func, insert, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import SurveyPoint, Upload

INSERT_CHUNK = 5000


async def add_survey_points(s: AsyncSession, rows: Sequence[dict[str, Any]]) -> None:
    for start in range(0, len(rows), INSERT_CHUNK):
        await s.execute(insert(SurveyPoint), list(rows[start : start + INSERT_CHUNK]))


async def list_survey_points(s: AsyncSession, building_id: str) -> Sequence[SurveyPoint]:
    stmt = select(SurveyPoint).where(SurveyPoint.building_id == building_id)
    return (await s.scalars(stmt.order_by(SurveyPoint.id))).all()


async def survey_point_places(
    s: AsyncSession, floor_id: str
) -> list[tuple[float, float, datetime]]:
    """Where and when each survey point of a floor was made (x, y, creation time),
    without its readings."""
    stmt = select(SurveyPoint.x_m, SurveyPoint.y_m, SurveyPoint.created_at).where(
        SurveyPoint.floor_id == floor_id
    )
    return [(x, y, created) for x, y, created in (await s.execute(stmt)).all()]


async def survey_readings_with_devices(
    s: AsyncSession, building_id: str
) -> list[tuple[float, float, str, dict[str, Any], str | None, str | None]]:
    """Per survey point of the building: x, y, floor id, readings, the upload it came from
    (None for points surveyed through the admin API) and that upload's device model."""
    stmt = (
        select(
            SurveyPoint.x_m,
            SurveyPoint.y_m,
            SurveyPoint.floor_id,
            SurveyPoint.readings,
            SurveyPoint.upload_id,
            Upload.device_model,
        )
        .outerjoin(Upload, SurveyPoint.upload_id == Upload.id)
        .where(SurveyPoint.building_id == building_id)
        .order_by(SurveyPoint.id)
    )
    return [(r[0], r[1], r[2], r[3], r[4], r[5]) for r in (await s.execute(stmt)).all()]


async def count_survey_points(s: AsyncSession, upload_id: str) -> int:
    stmt = select(func.count()).select_from(SurveyPoint).where(SurveyPoint.upload_id == upload_id)
    return int(await s.scalar(stmt) or 0)
