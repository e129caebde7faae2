"""Stateless locate: one scan in, a position out."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.convert import ble_pairs, wifi_pairs
from server.api.deps import AddressDep, Device, RuntimeDep
from server.api.gated_route import GatedRoute
from server.api.schemas.locate import LocateIn, LocateOut
from server.services import limits
from server.services import locate as service

router = APIRouter(prefix="/v1", tags=["locate"], route_class=GatedRoute)


@router.post("/locate")
async def locate(
    body: LocateIn, rt: RuntimeDep, principal: Device, address: AddressDep
) -> LocateOut:
    principal.require("device", body.site_id)
    await limits.check(rt, "locate", address, principal.key_id)
    found = await service.locate(rt, body.site_id, wifi_pairs(body.wifi), ble_pairs(body.ble))
    fix = found.fix
    return LocateOut(
        x_m=fix.x_m,
        y_m=fix.y_m,
        floor=found.level,
        building_id=found.building_id,
        floor_id=found.floor_id,
        cov_m2=fix.cov,
        uncertainty_m=fix.uncertainty_m,
        accuracy_68_m=fix.accuracy_68_m,
        accuracy_95_m=fix.accuracy_95_m,
        floor_prob=fix.floor_prob,
        **found.world,
    )
