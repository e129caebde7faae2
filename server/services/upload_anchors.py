"""What an upload's building offers to anchor a walk (``papers/003_*`` IV-B, IV-E2, IV-E3).

The BLE beacons its floor plans mark (entrances, elevators), the floor's own WiFi APs that
qualify as anchors in its current radio map (``mapping.wifi_anchors``; located again at
most every ``WIFI_ANCHOR_REFRESH_S`` per building, as locating them reads the whole radio
map), its geo-reference for satellite fixes, and each floor plan's extent.
"""

from __future__ import annotations

import time
from collections import OrderedDict

import anyio
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.mapping.walk_contribution import AnchorContext, Beacon
from server.positioning.mapping.wifi_anchors import anchor_nodes
from server.positioning.plan.anchors import anchors_from_plan
from server.positioning.plan.geojson_plan import plan_extent
from server.positioning.radio.fingerprints import MISSING_DBM
from server.services.maps import geo_reference, stored_radio_map
from server.storage.models import Upload
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo


async def upload_building_id(s: AsyncSession, upload: Upload) -> str | None:
    """The building an upload goes to: the one it names, else the site's only one (None
    when the site has several, or none)."""
    if upload.building_id is not None:
        return upload.building_id
    buildings = await site_repo.list_buildings(s, upload.site_id)
    return buildings[0].id if len(buildings) == 1 else None


async def anchor_context(s: AsyncSession, upload: Upload) -> AnchorContext:
    """The beacons the floor plans of the upload's building mark, the WiFi APs that
    qualify as anchors in its current radio map (``mapping.wifi_anchors``) and its
    geo-reference; nothing when the site has several buildings and the upload names
    none."""
    building_id = await upload_building_id(s, upload)
    building = await site_repo.get_building(s, building_id) if building_id else None
    if building is None:
        return AnchorContext()
    extents = {
        f.level: extent
        for f in await site_repo.list_floors(s, building.id)
        if (extent := plan_extent(f.plan_geojson)) is not None
    }
    return AnchorContext(await _beacons(s, building.id), geo_reference(building), extents)


async def _beacons(s: AsyncSession, building_id: str) -> list[Beacon]:
    floors = await site_repo.list_floors(s, building_id)
    found = []
    for floor in floors:
        for a in anchors_from_plan(floor.plan_geojson, 0):
            found.append(Beacon(a.emitter.split(":", 1)[1], (a.x_m, a.y_m), floor.level))
    current = await map_repo.latest_radio_map(s, building_id)
    if current is not None:
        found += await _wifi_anchors(s, building_id, current.id, {f.id: f.level for f in floors})
    return found


# per building: when located, from which map version, the anchor APs
_WIFI_ANCHORS: OrderedDict[str, tuple[float, str, list[Beacon]]] = OrderedDict()
# anchor APs change slowly with the map, and locating them reads the whole radio map:
# a worker locates them again at most this often per building
WIFI_ANCHOR_REFRESH_S = 300.0


async def _wifi_anchors(
    s: AsyncSession, building_id: str, map_id: str, levels: dict[str, int]
) -> list[Beacon]:
    cached = _WIFI_ANCHORS.get(building_id)
    if cached is not None and (
        cached[1] == map_id or time.monotonic() - cached[0] < WIFI_ANCHOR_REFRESH_S
    ):
        return cached[2]
    stored = await map_repo.load_radio_map(s, map_id, MISSING_DBM)
    order = sorted(levels)
    radio = stored_radio_map(stored, {f: i for i, f in enumerate(order)})
    nodes = await anyio.to_thread.run_sync(anchor_nodes, radio)
    beacons = [
        Beacon(
            n.emitter.split(":", 1)[1],
            (float(n.fit.xy[0]), float(n.fit.xy[1])),
            levels[order[n.floor]],
            kind="wifi",
            threshold_dbm=n.fit.p0_dbm,
        )
        for n in nodes
    ]
    _WIFI_ANCHORS[building_id] = (time.monotonic(), map_id, beacons)
    _WIFI_ANCHORS.move_to_end(building_id)
    while len(_WIFI_ANCHORS) > 16:
        _WIFI_ANCHORS.popitem(last=False)
    return beacons
