"""Engine routes: the registered engines with their defaults, and a site's settings."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Response, status

from server.api.deps import IdPath, MapsWriteDep, PrincipalDep, SqlDep, ViewerDep
from server.api.gated_route import GatedRoute
from server.api.schemas.engines import (
    EngineList,
    EngineRead,
    EngineSettingsIn,
    EngineSettingsList,
    EngineSettingsRead,
)
from server.positioning.engines.registry import ENGINES
from server.services import engine_settings
from server.services.engine_settings import EngineSettings

EnginePath = Annotated[
    str, Path(min_length=1, max_length=64, pattern=r"^[a-z0-9_]+$", description="engine name")
]

router = APIRouter(prefix="/v1", tags=["engines"], route_class=GatedRoute)


def _read(settings: EngineSettings) -> EngineSettingsRead:
    return EngineSettingsRead(
        site_id=settings.site_id,
        engine=settings.engine,
        params=settings.overrides,
        effective=settings.effective,
        problem=settings.problem,
    )


@router.get("/engines")
async def list_engines(principal: PrincipalDep) -> EngineList:
    """Every engine a session can run, the event kinds it reads and its defaults (any
    valid key)."""
    del principal
    items = [
        EngineRead(name=name, uses=sorted(spec.uses), params=engine_settings.defaults(name))
        for name, spec in sorted(ENGINES.items())
    ]
    return EngineList(items=items, count=len(items))


@router.get("/sites/{site_id}/engines", dependencies=[ViewerDep])
async def list_site_engines(site_id: IdPath, s: SqlDep) -> EngineSettingsList:
    items = [_read(x) for x in await engine_settings.list_settings(s, site_id)]
    return EngineSettingsList(items=items, count=len(items))


@router.get("/sites/{site_id}/engines/{name}", dependencies=[ViewerDep])
async def get_site_engine(site_id: IdPath, name: EnginePath, s: SqlDep) -> EngineSettingsRead:
    return _read(await engine_settings.get_settings(s, site_id, name))


@router.put("/sites/{site_id}/engines/{name}", dependencies=[MapsWriteDep])
async def put_site_engine(
    site_id: IdPath, name: EnginePath, body: EngineSettingsIn, s: SqlDep
) -> EngineSettingsRead:
    """Set the parameters new sessions of the site with this engine start from (they
    replace what the site had set; running sessions keep theirs)."""
    return _read(await engine_settings.put_settings(s, site_id, name, body.params))


@router.delete(
    "/sites/{site_id}/engines/{name}",
    status_code=status.HTTP_204_NO_CONTENT,
    dependencies=[MapsWriteDep],
)
async def delete_site_engine(site_id: IdPath, name: EnginePath, s: SqlDep) -> Response:
    """New sessions of the site with this engine start from the engine's defaults again."""
    await engine_settings.delete_settings(s, site_id, name)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
