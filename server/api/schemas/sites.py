"""Sites, buildings, floors and floor plans."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from server.api.schemas.common import FiniteFloat, Name, Strict, StrictIn
from server.api.schemas.pages import NextCursor, PageCount


class SiteCreate(StrictIn):
    name: Name


class SiteRead(Strict):
    id: str
    name: str
    created_at: datetime


class SiteList(Strict):
    items: list[SiteRead]
    count: PageCount
    next_cursor: NextCursor


class BuildingCreate(StrictIn):
    name: Name
    origin_lat: Annotated[float | None, Field(gt=-90, lt=90, allow_inf_nan=False)] = None
    origin_lon: Annotated[float | None, Field(ge=-180, le=180, allow_inf_nan=False)] = None
    rotation_rad: FiniteFloat = Field(
        0.0, description="angle from geographic north to the local y axis, clockwise"
    )


class BuildingRead(Strict):
    id: str
    site_id: str
    name: str
    origin_lat: float | None
    origin_lon: float | None
    rotation_rad: float
    created_at: datetime


class BuildingList(Strict):
    items: list[BuildingRead]
    count: PageCount
    next_cursor: NextCursor


class FloorCreate(StrictIn):
    level: Annotated[int, Field(ge=-20, le=200)]
    name: Name | None = None


class FloorRead(Strict):
    id: str
    building_id: str
    level: int
    name: str | None
    has_plan: bool
    created_at: datetime


class FloorList(Strict):
    items: list[FloorRead]
    count: PageCount
    next_cursor: NextCursor


class FloorPlan(BaseModel):
    """A GeoJSON FeatureCollection in the building's local metric frame."""

    model_config = ConfigDict(extra="allow")
    type: Literal["FeatureCollection"]
    features: Annotated[list[dict[str, Any]], Field(max_length=100_000)]
