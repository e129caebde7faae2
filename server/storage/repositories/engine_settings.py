"""Queries over ``engine_settings``: a site's overrides of an engine's defaults. The
caller (a service) owns the transaction and checks the overrides."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import EngineSetting, utcnow


async def get_engine_setting(s: AsyncSession, site_id: str, engine: str) -> EngineSetting | None:
    return await s.get(EngineSetting, (site_id, engine))


async def list_engine_settings(s: AsyncSession, site_id: str) -> Sequence[EngineSetting]:
    rows = await s.scalars(
        select(EngineSetting).where(EngineSetting.site_id == site_id).order_by(EngineSetting.engine)
    )
    return rows.all()


async def put_engine_setting(
    s: AsyncSession, site_id: str, engine: str, params: dict[str, Any]
) -> EngineSetting:
    """Create or replace the site's overrides for ``engine``."""
    row = await get_engine_setting(s, site_id, engine)
    if row is None:
        row = EngineSetting(site_id=site_id, engine=engine, params=params)
        s.add(row)
    else:
        row.params = params
        row.updated_at = utcnow()
    await s.flush()
    return row


async def delete_engine_setting(s: AsyncSession, site_id: str, engine: str) -> bool:
    """Drop the site's overrides for ``engine``; False when it had none."""
    result = await s.execute(
        delete(EngineSetting).where(
            EngineSetting.site_id == site_id, EngineSetting.engine == engine
        )
    )
    return bool(result.rowcount)  # type: ignore[attr-defined]
