"""Sites, their buildings and floors."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import (
    Building,
    Floor,
    SessionContribution,
    SessionFixes,
    SessionRecord,
    Site,
)
from server.storage.repositories.pages import Key, Page, keyset_page


async def create_site(s: AsyncSession, name: str) -> Site:
    site = Site(name=name)
    s.add(site)
    await s.flush()
    return site


async def list_sites(s: AsyncSession) -> Sequence[Site]:
    return (await s.scalars(select(Site).order_by(Site.created_at, Site.id))).all()


async def site_page(
    s: AsyncSession, after: Key | None, limit: int, site_id: str | None = None
) -> Page[Site]:
    """Sites newest first (only ``site_id``, when given)."""
    stmt = select(Site)
    if site_id is not None:
        stmt = stmt.where(Site.id == site_id)
    return await keyset_page(s, stmt, (Site.created_at, Site.id), after, limit, descending=True)


async def get_site(s: AsyncSession, site_id: str) -> Site | None:
    return await s.get(Site, site_id)


async def delete_site(s: AsyncSession, site_id: str) -> None:
    """Delete the site; the database's cascades take everything that belongs to it. The
    batches its contributing sessions kept and its sessions' history (no foreign keys:
    they outlive a session's row until it ends) go first."""
    of_site = select(SessionRecord.id).where(SessionRecord.site_id == site_id)
    await s.execute(delete(SessionContribution).where(SessionContribution.session_id.in_(of_site)))
    await s.execute(delete(SessionFixes).where(SessionFixes.site_id == site_id))
    await s.execute(delete(Site).where(Site.id == site_id))


async def delete_building(s: AsyncSession, building_id: str) -> None:
    await s.execute(delete(Building).where(Building.id == building_id))


async def delete_floor(s: AsyncSession, floor_id: str) -> None:
    await s.execute(delete(Floor).where(Floor.id == floor_id))


async def create_building(s: AsyncSession, site_id: str, **fields: Any) -> Building:
    building = Building(site_id=site_id, **fields)
    s.add(building)
    await s.flush()
    return building


async def list_buildings(s: AsyncSession, site_id: str) -> Sequence[Building]:
    stmt = select(Building).where(Building.site_id == site_id).order_by(Building.created_at)
    return (await s.scalars(stmt)).all()


async def building_page(
    s: AsyncSession, site_id: str, after: Key | None, limit: int
) -> Page[Building]:
    """The site's buildings, oldest first."""
    stmt = select(Building).where(Building.site_id == site_id)
    return await keyset_page(s, stmt, (Building.created_at, Building.id), after, limit)


async def get_building(s: AsyncSession, building_id: str) -> Building | None:
    return await s.get(Building, building_id)


async def lock_building(s: AsyncSession, building_id: str) -> Building | None:
    """The building row, locked until the transaction ends (map rebuilds take turns)."""
    stmt = select(Building).where(Building.id == building_id).with_for_update()
    return (await s.scalars(stmt)).one_or_none()


async def create_floor(s: AsyncSession, building_id: str, level: int, name: str | None) -> Floor:
    floor = Floor(building_id=building_id, level=level, name=name)
    s.add(floor)
    await s.flush()
    return floor


async def find_floor(s: AsyncSession, building_id: str, level: int) -> Floor | None:
    stmt = select(Floor).where(Floor.building_id == building_id, Floor.level == level)
    return (await s.scalars(stmt)).one_or_none()


async def list_floors(s: AsyncSession, building_id: str) -> Sequence[Floor]:
    stmt = select(Floor).where(Floor.building_id == building_id).order_by(Floor.level)
    return (await s.scalars(stmt)).all()


async def floor_page(
    s: AsyncSession, building_id: str, after: Key | None, limit: int
) -> Page[Floor]:
    """The building's floors by level, lowest first."""
    stmt = select(Floor).where(Floor.building_id == building_id)
    return await keyset_page(s, stmt, (Floor.level, Floor.id), after, limit)


async def get_floor(s: AsyncSession, floor_id: str) -> Floor | None:
    return await s.get(Floor, floor_id)


async def list_site_floors(s: AsyncSession, site_id: str) -> Sequence[tuple[Floor, Building]]:
    """All floors of a site with their building, in (building creation, level) order."""
    stmt = (
        select(Floor, Building)
        .join(Building, Floor.building_id == Building.id)
        .where(Building.site_id == site_id)
        .order_by(Building.created_at, Building.id, Floor.level)
    )
    return [(f, b) for f, b in (await s.execute(stmt)).all()]
