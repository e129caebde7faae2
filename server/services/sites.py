"""Sites, buildings, floors and floor plans."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from server.services.errors import Conflict, NotFound
from server.storage.models import Building, Floor, Site
from server.storage.repositories import sites as site_repo


async def create_site(s: AsyncSession, name: str) -> Site:
    return await site_repo.create_site(s, name)


async def list_sites(s: AsyncSession) -> Sequence[Site]:
    return await site_repo.list_sites(s)


async def get_site(s: AsyncSession, site_id: str) -> Site:
    site = await site_repo.get_site(s, site_id)
    if site is None:
        raise NotFound(f"site {site_id} not found", field="site_id")
    return site


async def create_building(s: AsyncSession, site_id: str, **fields: Any) -> Building:
    await get_site(s, site_id)
    return await site_repo.create_building(s, site_id, **fields)


async def list_buildings(s: AsyncSession, site_id: str) -> Sequence[Building]:
    await get_site(s, site_id)
    return await site_repo.list_buildings(s, site_id)


async def get_building(s: AsyncSession, building_id: str) -> Building:
    building = await site_repo.get_building(s, building_id)
    if building is None:
        raise NotFound(f"building {building_id} not found", field="building_id")
    return building


async def create_floor(s: AsyncSession, building_id: str, level: int, name: str | None) -> Floor:
    await get_building(s, building_id)
    if await site_repo.find_floor(s, building_id, level) is not None:
        raise Conflict(f"building {building_id} already has level {level}", field="level")
    return await site_repo.create_floor(s, building_id, level, name)


async def list_floors(s: AsyncSession, building_id: str) -> Sequence[Floor]:
    await get_building(s, building_id)
    return await site_repo.list_floors(s, building_id)


async def get_floor(s: AsyncSession, floor_id: str) -> Floor:
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    return floor


async def put_floor_plan(s: AsyncSession, floor_id: str, plan: dict[str, Any]) -> Floor:
    floor = await get_floor(s, floor_id)
    floor.plan_geojson = plan
    await s.flush()
    return floor


async def get_floor_plan(s: AsyncSession, floor_id: str) -> dict[str, Any]:
    floor = await get_floor(s, floor_id)
    if floor.plan_geojson is None:
        raise NotFound(f"floor {floor_id} has no plan", field="floor_id")
    return floor.plan_geojson


async def site_of(s: AsyncSession, building_id: str | None, floor_id: str | None) -> str | None:
    """The site of a building or of a floor; None when neither is given or found."""
    if floor_id is not None:
        floor = await site_repo.get_floor(s, floor_id)
        building_id = floor.building_id if floor is not None else None
    if building_id is None:
        return None
    building = await site_repo.get_building(s, building_id)
    return building.site_id if building is not None else None
