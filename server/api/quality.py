"""Admin routes: how good a floor's current maps are (coverage, sampling, freshness,
emitters), cell by cell, and where to survey it next."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from server.api.deps import IdPath, SqlDep, ViewerDep
from server.api.gated_route import GatedRoute
from server.api.schemas.map_quality import CoverageGridRead, MapQualityRead, SurveyPlanRead
from server.positioning.mapping.map_quality import QualityParams
from server.services import map_quality, survey_plans

router = APIRouter(prefix="/v1", tags=["admin"], dependencies=[ViewerDep], route_class=GatedRoute)


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
    params = QualityParams(max_emitters=max_emitters, retired_after_days=retired_after_days)
    quality = await map_quality.floor_map_quality(s, floor_id, params)
    return MapQualityRead.model_validate(quality, from_attributes=True)


@router.get("/floors/{floor_id}/maps/coverage")
async def get_map_coverage(
    floor_id: IdPath,
    s: SqlDep,
    cell_m: Annotated[
        float,
        Query(
            ge=0.5,
            le=50,
            description="side of a grid cell (m); a floor may have at most 40,000 cells",
        ),
    ] = 2.0,
) -> CoverageGridRead:
    """Where the floor's radio map is thin, cell by cell: over a grid on the floor's
    walkable area (without a plan, the box of its reference points and survey points),
    each cell's readings, survey points, emitters heard, RSS variance, the age of its
    newest survey point, and the error a radio fix there can be expected to have: from
    the map's fix-error table for the emitters heard at the nearest reference point and
    the distance to it, so that a cell far from every reference point looks worse. Cells
    without data are listed too; a floor without maps answers an empty grid or one
    without data. A ``cell_m`` too small for the floor's size answers 422."""
    found = await map_quality.floor_coverage(s, floor_id, cell_m)
    return CoverageGridRead.model_validate(found.document())


@router.get("/floors/{floor_id}/maps/placement")
async def get_survey_plan(
    floor_id: IdPath,
    s: SqlDep,
    noise_distance_m: Annotated[
        float | None,
        Query(
            gt=0,
            le=100,
            description="a constant noise distance (m) instead of the one the radio map's "
            "variance and the access points' path loss give",
        ),
    ] = None,
) -> SurveyPlanRead:
    """Where to put reference points on the floor (GeoJSON points, floor frame), after the
    reference-point placement theory of Wang et al.: along grid lines through each located
    access point, one a noise distance from the last, then wherever a walkable point is
    farther than that from every planned one; each point says whether the current radio
    map already has it, and the summary gives the accuracy a nearest-point fix would reach.
    A floor with neither a plan nor reference points answers 422."""
    found = await survey_plans.floor_survey_plan(s, floor_id, noise_distance_m)
    return SurveyPlanRead.model_validate(found.geojson())
