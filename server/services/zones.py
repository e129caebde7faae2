"""Zones of a floor: replaced whole from GeoJSON (``plan.zones`` says what counts as one)
and read back as GeoJSON. ``services.maps`` indexes a site's zones with its maps, for the
batch path."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.plan.geojson_format import PlanError
from server.positioning.plan.geojson_validation import check_frame
from server.positioning.plan.zones import ZoneFeature, as_feature, zones_from_geojson
from server.services.errors import Invalid
from server.services.sites import floor_and_building, origin_deg
from server.storage import models
from server.storage.repositories import zones as repo


@dataclass(frozen=True)
class FloorZones:
    floor_id: str
    site_id: str
    zones: tuple[ZoneFeature, ...]
    skipped: int = 0  # features sent that are not zones

    def geojson(self) -> dict[str, Any]:
        return {
            "type": "FeatureCollection",
            "floor_id": self.floor_id,
            "features": [as_feature(z) for z in self.zones],
        }


def _feature(row: models.Zone) -> ZoneFeature:
    return ZoneFeature(row.id, row.name, row.geometry, row.properties or {})


async def put_floor_zones(
    s: AsyncSession, floor_id: str, collection: Mapping[str, Any]
) -> FloorZones:
    """Replace the floor's zones with those of ``collection`` (floor metres; with the
    building's geo-reference, coordinates that look like degrees are refused); Invalid
    naming the field at fault."""
    _, building = await floor_and_building(s, floor_id)
    try:
        read = zones_from_geojson(collection)
        check_frame([as_feature(z) for z in read.zones], origin_deg(building))
    except PlanError as exc:
        raise Invalid(exc.reason, field=exc.field) from None
    rows = [
        models.Zone(
            floor_id=floor_id, id=z.id, name=z.name, geometry=z.geometry, properties=z.properties
        )
        for z in read.zones
    ]
    await repo.replace_floor_zones(s, floor_id, rows)
    return FloorZones(floor_id, building.site_id, read.zones, read.skipped)


async def get_floor_zones(s: AsyncSession, floor_id: str) -> FloorZones:
    _, building = await floor_and_building(s, floor_id)  # NotFound for a floor not there
    rows = await repo.floor_zones(s, floor_id)
    return FloorZones(floor_id, building.site_id, tuple(_feature(r) for r in rows))
