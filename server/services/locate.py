"""Stateless positioning: one WiFi/BLE scan in, a position with floor and uncertainty out.

The scan is located as a ``wknn`` session's first scan would be (``engines.wknn``: at
least three matched map emitters, the floor from the scan's likelihood of each floor,
the fix's variance learned from the map's training data, the site's ``wknn`` settings),
so its uncertainty is the same calibrated one (``accuracy``): 68 % and 95 % radii and
the floor's probability. WiFi is tried first; BLE when the WiFi scan gives no fix.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from server.positioning.engines import wknn
from server.positioning.model.events import BleEvent, Fix, RadioReading, WifiEvent
from server.services import engine_settings
from server.services.errors import Invalid, NotFound
from server.services.maps import site_maps
from server.services.runtime import Runtime
from server.services.session_records import world_fields


@dataclass(frozen=True)
class Located:
    fix: Fix
    level: int
    building_id: str
    floor_id: str
    # lat, lon, level, accuracy_m, heading_deg (session_records) and the zones it is in
    world: dict[str, Any]


async def locate(
    rt: Runtime,
    site_id: str,
    wifi: Sequence[tuple[str, float]],
    ble: Sequence[tuple[str, float]],
) -> Located:
    if not wifi and not ble:
        raise Invalid("send at least one WiFi or BLE reading", field="wifi")
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, site_id)
        overrides = await engine_settings.site_overrides(s, site_id, wknn.SPEC.name)
    if maps.radio is None:
        raise NotFound(f"site {site_id} has no radio map yet", field="site_id")
    engine = wknn.SPEC
    params = engine.params(overrides)  # the site's wknn settings, as its sessions
    scans = (
        WifiEvent(0, tuple(RadioReading(e, r) for e, r in wifi)),
        BleEvent(0, tuple(RadioReading(e, r) for e, r in ble)),
    )
    for scan in scans:
        if not scan.readings:
            continue
        rng = np.random.default_rng(0)  # the engine draws none
        _, fixes = engine.step(engine.start(params), [scan], maps, params, rng)
        if fixes:
            fix = fixes[0]
            ref = maps.floors[fix.floor]
            world = world_fields(fix.x_m, fix.y_m, fix.heading_rad, fix.accuracy_68_m, ref)
            # one scan has no dwell: the zones its position lies in
            zones = [z.id for z in maps.zones.at(fix.floor, fix.x_m, fix.y_m)]
            return Located(fix, ref.level, ref.building_id, ref.floor_id, {**world, "zones": zones})
    raise Invalid(
        "the scan matches too few emitters of the site's radio map to place it (at least "
        f"{params.min_matched} of one kind)",
        field="wifi",
    )
