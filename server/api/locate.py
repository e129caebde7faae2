"""Stateless locate: one scan in, a position out."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.convert import ble_pairs, wifi_pairs
from server.api.deps import AddressDep, Device, RuntimeDep
from server.api.schemas.locate import LocateIn, LocateOut
from server.services import limits
from server.services import locate as service

router = APIRouter(prefix="/v1", tags=["locate"])


@router.post("/locate")
async def locate(
    body: LocateIn, rt: RuntimeDep, principal: Device, address: AddressDep
) -> LocateOut:
    principal.require("device", body.site_id)
    await limits.check(rt, "locate", address, principal.key_id)
    found = await service.locate(rt, body.site_id, wifi_pairs(body.wifi), ble_pairs(body.ble))
    return LocateOut(
        x_m=found.x_m,
        y_m=found.y_m,
        floor=found.floor,
        building_id=found.building_id,
        floor_id=found.floor_id,
        cov_m2=(found.var_m2, 0.0, 0.0, found.var_m2),
        uncertainty_m=found.var_m2**0.5,
    )
