"""Zones of floors."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import Building, Floor, Zone


async def floor_zones(s: AsyncSession, floor_id: str) -> Sequence[Zone]:
    stmt = select(Zone).where(Zone.floor_id == floor_id).order_by(Zone.id)
    return (await s.scalars(stmt)).all()


def _of_site(site_id: str) -> Any:
    return (
        select(Zone)
        .join(Floor, Zone.floor_id == Floor.id)
        .join(Building, Floor.building_id == Building.id)
        .where(Building.site_id == site_id)
    )


async def site_zones(s: AsyncSession, site_id: str) -> Sequence[Zone]:
    """Every zone of a site's floors, by floor and id."""
    return (await s.scalars(_of_site(site_id).order_by(Zone.floor_id, Zone.id))).all()


async def site_zones_version(s: AsyncSession, site_id: str) -> str:
    """A word that changes whenever the site's zones do (every write replaces a floor's
    zones with rows made then): a digest of which zones there are and when each was
    written (not their geometry: cheap to ask every few seconds)."""
    stmt = _of_site(site_id).with_only_columns(Zone.floor_id, Zone.id, Zone.created_at)
    rows = (await s.execute(stmt.order_by(Zone.floor_id, Zone.id))).all()
    digest = hashlib.sha256()
    for floor_id, zone_id, created_at in rows:
        digest.update(f"{floor_id}/{zone_id}@{created_at.isoformat()};".encode())
    return digest.hexdigest()[:16]


async def replace_floor_zones(s: AsyncSession, floor_id: str, zones: Sequence[Zone]) -> None:
    await s.execute(delete(Zone).where(Zone.floor_id == floor_id))
    s.add_all(zones)
    await s.flush()
