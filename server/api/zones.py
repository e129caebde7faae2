"""Zone routes: a floor's zones, replaced whole from GeoJSON and read back."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.deps import IdPath, MapsWriteDep, RuntimeDep, SqlDep, ViewerDep
from server.api.gated_route import GatedRoute
from server.api.schemas.zones import ZonesIn, ZonesRead
from server.services import zones

router = APIRouter(prefix="/v1", tags=["zones"], route_class=GatedRoute)


@router.put("/floors/{floor_id}/zones", dependencies=[MapsWriteDep])
async def put_floor_zones(floor_id: IdPath, body: ZonesIn, rt: RuntimeDep) -> ZonesRead:
    """Replace the floor's zones (what counts as a zone: see the body's schema). Sessions
    on the site see the new zones at once on this replica, within seconds on the others;
    a zone sent again with the same id (or, without one, the same name and geometry)
    keeps the sessions inside it inside."""
    async with rt.transaction() as s:
        stored = await zones.put_floor_zones(s, floor_id, body.model_dump(mode="json"))
    rt.maps.expire(stored.site_id)  # committed: this replica's sessions see them now
    return ZonesRead.model_validate({**stored.geojson(), "skipped": stored.skipped})


@router.get("/floors/{floor_id}/zones", dependencies=[ViewerDep])
async def get_floor_zones(floor_id: IdPath, s: SqlDep) -> ZonesRead:
    """The floor's zones as GeoJSON (floor metres)."""
    return ZonesRead.model_validate((await zones.get_floor_zones(s, floor_id)).geojson())
