"""Sites, buildings, floors and floor plans.

Deleting a site, a building or a floor removes what belongs to it (the foreign keys'
cascades, listed per route in ``server.api.admin``), and is refused (Conflict) while the
site has active sessions: a session's engine state points into its site's floors by
index, so taking a floor from under it would move it to another one.
"""

from __future__ import annotations

from typing import Any

import anyio
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.plan.geojson_format import PlanError
from server.positioning.plan.geojson_validation import validate_plan
from server.services.errors import Conflict, Invalid, NotFound
from server.services.maps import PENDING, owe_build
from server.services.session_records import active_since
from server.storage.models import Building, Floor, Site
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sessions as session_repo
from server.storage.repositories import sites as site_repo
from server.storage.repositories.pages import Key, Page

NAMED_SESSIONS = 3  # active sessions a refused delete names


async def create_site(s: AsyncSession, name: str) -> Site:
    return await site_repo.create_site(s, name)


async def list_sites(
    s: AsyncSession, after: Key | None, limit: int, site_id: str | None = None
) -> Page[Site]:
    """Sites newest first (only ``site_id``, for a key of one site)."""
    return await site_repo.site_page(s, after, limit, site_id)


async def get_site(s: AsyncSession, site_id: str) -> Site:
    site = await site_repo.get_site(s, site_id)
    if site is None:
        raise NotFound(f"site {site_id} not found", field="site_id")
    return site


async def create_building(s: AsyncSession, site_id: str, **fields: Any) -> Building:
    await get_site(s, site_id)
    return await site_repo.create_building(s, site_id, **fields)


async def list_buildings(
    s: AsyncSession, site_id: str, after: Key | None, limit: int
) -> Page[Building]:
    await get_site(s, site_id)
    return await site_repo.building_page(s, site_id, after, limit)


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


async def list_floors(
    s: AsyncSession, building_id: str, after: Key | None, limit: int
) -> Page[Floor]:
    await get_building(s, building_id)
    return await site_repo.floor_page(s, building_id, after, limit)


async def get_floor(s: AsyncSession, floor_id: str) -> Floor:
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    return floor


async def floor_and_building(s: AsyncSession, floor_id: str) -> tuple[Floor, Building]:
    floor = await get_floor(s, floor_id)
    return floor, await get_building(s, floor.building_id)


def origin_deg(building: Building) -> tuple[float, float] | None:
    """The building's origin (latitude, longitude in degrees), when it has one: what tells
    a plan in degrees from one in metres (``geojson_validation``)."""
    if building.origin_lat is None or building.origin_lon is None:
        return None
    return building.origin_lat, building.origin_lon


async def put_floor_plan(s: AsyncSession, floor_id: str, plan: dict[str, Any]) -> Floor:
    """Store a floor's plan once it passes ``geojson_validation.validate_plan`` (with the
    building's geo-reference, if any, to tell degrees from metres); Invalid naming the
    feature and the property otherwise. IMDF-style features are stored with the kind
    they map to. The building's current radio map version is built again by the worker
    (its floor graphs follow the plan)."""
    floor, building = await floor_and_building(s, floor_id)
    origin = origin_deg(building)
    try:
        # a mall's floor takes ~0.1 s of shapely work: off the event loop
        checked = await anyio.to_thread.run_sync(validate_plan, plan, origin)
    except PlanError as exc:
        raise Invalid(exc.reason, field=exc.field) from None
    floor.plan_geojson = checked
    # the floor graphs of the building's current radio map were built on the old plan
    current = await map_repo.latest_radio_map(s, building.id)
    if current is not None and current.build_status != PENDING:
        owe_build(current)
    await s.flush()
    return floor


async def get_floor_plan(s: AsyncSession, floor_id: str) -> dict[str, Any]:
    floor = await get_floor(s, floor_id)
    if floor.plan_geojson is None:
        raise NotFound(f"floor {floor_id} has no plan", field="floor_id")
    return floor.plan_geojson


async def _refuse_while_active(
    s: AsyncSession, site_id: str, idle_s: float, what: str, field: str
) -> None:
    n, ids = await session_repo.active_sessions(s, site_id, active_since(idle_s), NAMED_SESSIONS)
    if n:
        named = ", ".join(ids) + (f" and {n - len(ids)} more" if n > len(ids) else "")
        raise Conflict(
            f"{what} is in use by {n} active session{'s' if n > 1 else ''} of site "
            f"{site_id} ({named}): they end with DELETE /v1/sessions/{{id}} (their token) "
            f"or expire after {idle_s:.0f} s without a batch",
            field=field,
        )


async def delete_site(s: AsyncSession, site_id: str, idle_s: float) -> None:
    """Delete a site and all it holds (module docstring); ``idle_s``: the session idle
    timeout."""
    await get_site(s, site_id)
    await _refuse_while_active(s, site_id, idle_s, f"site {site_id}", "site_id")
    await site_repo.delete_site(s, site_id)


async def delete_building(s: AsyncSession, building_id: str, idle_s: float) -> None:
    building = await get_building(s, building_id)
    what = f"building {building_id}"
    await _refuse_while_active(s, building.site_id, idle_s, what, "building_id")
    await site_repo.delete_building(s, building_id)


async def delete_floor(s: AsyncSession, floor_id: str, idle_s: float) -> None:
    floor = await get_floor(s, floor_id)
    building = await get_building(s, floor.building_id)
    what = f"floor {floor_id}"
    await _refuse_while_active(s, building.site_id, idle_s, what, "floor_id")
    await site_repo.delete_floor(s, floor_id)


async def site_of(s: AsyncSession, building_id: str | None, floor_id: str | None) -> str | None:
    """The site of a building or of a floor; None when neither is given or found."""
    if floor_id is not None:
        floor = await site_repo.get_floor(s, floor_id)
        building_id = floor.building_id if floor is not None else None
    if building_id is None:
        return None
    building = await site_repo.get_building(s, building_id)
    return building.site_id if building is not None else None
