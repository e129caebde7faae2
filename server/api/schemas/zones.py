"""Zones of a floor."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from server.api.schemas.common import Strict

MAX_ZONES = 10_000


class ZonesIn(BaseModel):
    """A GeoJSON FeatureCollection in metres of the floor frame (the plan's frame). Its
    zones: Polygon or MultiPolygon features that are IMDF ``geofence``, ``unit`` or
    ``section`` features, have ``properties.kind`` ``"zone"``, or have neither a
    ``feature_type`` nor a ``kind``; other features (a whole plan may be sent) are skipped.
    A zone's id is the feature's ``id``; its name ``properties.name`` (a string or IMDF
    labels)."""

    model_config = ConfigDict(extra="allow")
    type: Literal["FeatureCollection"]
    features: Annotated[list[dict[str, Any]], Field(max_length=MAX_ZONES)]


class ZoneFeatureOut(Strict):
    type: Literal["Feature"]
    id: str
    name: str = Field(description="the zone's name, read from its properties (or its id)")
    geometry: dict[str, Any] = Field(description="Polygon or MultiPolygon, floor metres")
    properties: dict[str, Any] = Field(description="as sent")


class ZonesRead(Strict):
    type: Literal["FeatureCollection"]
    floor_id: str
    features: list[ZoneFeatureOut]
    skipped: int = Field(0, description="features sent that are not zones (PUT only)")
