"""Stateless positioning: one WiFi/BLE scan in, a position with floor and uncertainty out."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from server.positioning.engines.step_ekf import StepEkfParams
from server.positioning.events import RadioReading
from server.positioning.fingerprint import scan_vector, wknn
from server.services.errors import Invalid, NotFound
from server.services.maps import site_maps
from server.services.runtime import Runtime

MIN_VAR_M2 = StepEkfParams().min_fix_var_m2  # the same floor as the step_ekf engine


@dataclass(frozen=True)
class Located:
    x_m: float
    y_m: float
    floor: int
    building_id: str
    floor_id: str
    var_m2: float


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
    if maps.radio is None:
        raise NotFound(f"site {site_id} has no radio map yet", field="site_id")
    for kind, readings in (("wifi", wifi), ("ble", ble)):
        if not readings:
            continue
        scan = scan_vector(maps.radio, [RadioReading(e, r) for e, r in readings], kind)
        fix = wknn(maps.radio, scan)
        if fix is not None:
            ref = maps.floors[fix.floor]
            return Located(
                fix.x_m,
                fix.y_m,
                ref.level,
                ref.building_id,
                ref.floor_id,
                max(fix.var_m2, MIN_VAR_M2),
            )
    raise Invalid("no emitter in the scan is known to the site's radio map", field="wifi")
