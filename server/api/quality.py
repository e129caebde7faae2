"""Admin route: how good a floor's current maps are (coverage, sampling, freshness, emitters)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from server.api.deps import IdPath, SqlDep, ViewerDep
from server.api.schemas.map_quality import MapQualityRead
from server.services import map_quality

router = APIRouter(prefix="/v1", tags=["admin"], dependencies=[ViewerDep])


@router.get("/floors/{floor_id}/maps/quality")
async def get_map_quality(
    floor_id: IdPath,
    s: SqlDep,
    max_emitters: Annotated[
        int, Query(ge=0, le=500, description="emitters to locate, the most-read first")
    ] = 50,
    retired_after_days: Annotated[
        int,
        Query(
            ge=1,
            le=3650,
            description="an emitter of the radio map no survey point heard in this many days "
            "before the floor's newest point counts as retired",
        ),
    ] = 30,
) -> MapQualityRead:
    """Coverage, cell sampling, freshness and emitters of the floor's current radio and
    magnetic maps. A floor without maps answers with nulls and zeros."""
    params = map_quality.QualityParams(
        max_emitters=max_emitters, retired_after_days=retired_after_days
    )
    quality = await map_quality.floor_map_quality(s, floor_id, params)
    return MapQualityRead.model_validate(quality, from_attributes=True)
