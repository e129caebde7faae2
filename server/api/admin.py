"""Admin routes: sites, buildings, floors, floor plans, surveys, radio and magnetic maps."""

from __future__ import annotations

import math
from typing import Annotated, Any

from fastapi import APIRouter, Path, Response, status

from server.api.convert import ble_pairs, wifi_pairs
from server.api.deps import (
    AdminDep,
    GlobalAdminDep,
    IdPath,
    MapsWriteDep,
    PageQuery,
    RuntimeDep,
    SqlDep,
    Viewer,
    ViewerDep,
    page_query,
)
from server.api.gated_route import GatedRoute
from server.api.schemas.maps import (
    DeviceOffsetList,
    DeviceOffsetRead,
    MagneticMapList,
    MagneticMapRead,
    MagneticSurveyIn,
    RadioMapList,
    RadioMapRead,
    SurveyIn,
)
from server.api.schemas.pages import CREATED, LEVEL, encode_cursor
from server.api.schemas.sites import (
    BuildingCreate,
    BuildingList,
    BuildingRead,
    FloorCreate,
    FloorList,
    FloorPlan,
    FloorRead,
    SiteCreate,
    SiteList,
    SiteRead,
)
from server.positioning.mapping.survey_points import SurveyPointData
from server.services import device_offsets, magnetic_maps, maps, sites

VersionPath = Annotated[int, Path(ge=1, le=2**31 - 1, description="map version number")]

router = APIRouter(prefix="/v1", tags=["admin"], route_class=GatedRoute)
SitePage = Annotated[PageQuery, page_query("sites", CREATED)]
BuildingPage = Annotated[PageQuery, page_query("buildings", CREATED)]
FloorPage = Annotated[PageQuery, page_query("floors", LEVEL)]
NO_CONTENT = status.HTTP_204_NO_CONTENT


def _floor(f: Any) -> FloorRead:
    return FloorRead(
        id=f.id,
        building_id=f.building_id,
        level=f.level,
        name=f.name,
        has_plan=f.plan_geojson is not None,
        created_at=f.created_at,
    )


def _radio_map(m: Any) -> RadioMapRead:
    return RadioMapRead.model_validate(m, from_attributes=True)


@router.post("/sites", status_code=status.HTTP_201_CREATED, dependencies=[GlobalAdminDep])
async def create_site(body: SiteCreate, s: SqlDep) -> SiteRead:
    return SiteRead.model_validate(await sites.create_site(s, body.name), from_attributes=True)


def _next(name: str, key: tuple[Any, ...] | None) -> str | None:
    return encode_cursor(name, key) if key is not None else None


@router.get("/sites")
async def list_sites(s: SqlDep, principal: Viewer, page: SitePage) -> SiteList:
    """Sites newest first (a key of one site sees that one)."""
    found = await sites.list_sites(s, page.after, page.limit, principal.site_id)
    items = [SiteRead.model_validate(x, from_attributes=True) for x in found.rows]
    return SiteList(items=items, count=len(items), next_cursor=_next("sites", found.next_key))


@router.get("/sites/{site_id}", dependencies=[ViewerDep])
async def get_site(site_id: IdPath, s: SqlDep) -> SiteRead:
    return SiteRead.model_validate(await sites.get_site(s, site_id), from_attributes=True)


@router.delete("/sites/{site_id}", status_code=NO_CONTENT, dependencies=[GlobalAdminDep])
async def delete_site(site_id: IdPath, s: SqlDep, rt: RuntimeDep) -> Response:
    """Delete the site with everything in it: its buildings (each as DELETE
    /v1/buildings/{id} removes it), its uploads, its sessions' records (and the batches
    contributing sessions kept), its engine settings, and the API keys of this site
    alone, which stop working. Refused with 409, naming them, while the site has active
    sessions (not ended, a batch within the last 1.5 idle timeouts: GET
    /v1/sessions?active=true): they end by DELETE /v1/sessions/{id} with their token, or
    expire."""
    await sites.delete_site(s, site_id, rt.settings.session_idle_s)
    return Response(status_code=NO_CONTENT)


@router.post(
    "/sites/{site_id}/buildings", status_code=status.HTTP_201_CREATED, dependencies=[AdminDep]
)
async def create_building(site_id: IdPath, body: BuildingCreate, s: SqlDep) -> BuildingRead:
    building = await sites.create_building(s, site_id, **body.model_dump())
    return BuildingRead.model_validate(building, from_attributes=True)


@router.get("/sites/{site_id}/buildings", dependencies=[ViewerDep])
async def list_buildings(site_id: IdPath, s: SqlDep, page: BuildingPage) -> BuildingList:
    """The site's buildings, oldest first."""
    found = await sites.list_buildings(s, site_id, page.after, page.limit)
    items = [BuildingRead.model_validate(b, from_attributes=True) for b in found.rows]
    cursor = _next("buildings", found.next_key)
    return BuildingList(items=items, count=len(items), next_cursor=cursor)


@router.get("/buildings/{building_id}", dependencies=[ViewerDep])
async def get_building(building_id: IdPath, s: SqlDep) -> BuildingRead:
    building = await sites.get_building(s, building_id)
    return BuildingRead.model_validate(building, from_attributes=True)


@router.delete("/buildings/{building_id}", status_code=NO_CONTENT, dependencies=[AdminDep])
async def delete_building(building_id: IdPath, s: SqlDep, rt: RuntimeDep) -> Response:
    """Delete the building: its floors (each as DELETE /v1/floors/{id} removes it), its
    emitters, every radio map version, and the uploads that named it with the survey
    points they gave (uploads of the site that named no building stay). Device offsets
    are computed from its survey points, so its own go too. Refused with 409, naming
    them, while the site has active sessions (their engines hold the site's floors)."""
    await sites.delete_building(s, building_id, rt.settings.session_idle_s)
    return Response(status_code=NO_CONTENT)


@router.post(
    "/buildings/{building_id}/floors", status_code=status.HTTP_201_CREATED, dependencies=[AdminDep]
)
async def create_floor(building_id: IdPath, body: FloorCreate, s: SqlDep) -> FloorRead:
    return _floor(await sites.create_floor(s, building_id, body.level, body.name))


@router.get("/buildings/{building_id}/floors", dependencies=[ViewerDep])
async def list_floors(building_id: IdPath, s: SqlDep, page: FloorPage) -> FloorList:
    """The building's floors by level, lowest first."""
    found = await sites.list_floors(s, building_id, page.after, page.limit)
    items = [_floor(f) for f in found.rows]
    return FloorList(items=items, count=len(items), next_cursor=_next("floors", found.next_key))


@router.get("/floors/{floor_id}", dependencies=[ViewerDep])
async def get_floor(floor_id: IdPath, s: SqlDep) -> FloorRead:
    return _floor(await sites.get_floor(s, floor_id))


@router.delete("/floors/{floor_id}", status_code=NO_CONTENT, dependencies=[AdminDep])
async def delete_floor(floor_id: IdPath, s: SqlDep, rt: RuntimeDep) -> Response:
    """Delete the floor: its plan, its magnetic map versions and the survey points taken
    on it. Its reference points drop out of every version of the building's radio map
    (the versions stay, over the other floors); emitters placed on it stay, unplaced.
    Uploads hinting its level stay (the worker rejects one it then cannot place).
    Refused with 409, naming them, while the site has active sessions (their engines
    hold the site's floors by index)."""
    await sites.delete_floor(s, floor_id, rt.settings.session_idle_s)
    return Response(status_code=NO_CONTENT)


@router.put("/floors/{floor_id}/plan", dependencies=[MapsWriteDep])
async def put_floor_plan(floor_id: IdPath, body: FloorPlan, s: SqlDep) -> FloorRead:
    return _floor(await sites.put_floor_plan(s, floor_id, body.model_dump(mode="json")))


@router.get("/floors/{floor_id}/plan", dependencies=[ViewerDep])
async def get_floor_plan(floor_id: IdPath, s: SqlDep) -> FloorPlan:
    return FloorPlan.model_validate(await sites.get_floor_plan(s, floor_id))


@router.post(
    "/buildings/{building_id}/survey",
    status_code=status.HTTP_201_CREATED,
    dependencies=[MapsWriteDep],
)
async def post_survey(building_id: IdPath, body: SurveyIn, s: SqlDep) -> RadioMapRead:
    points = [
        SurveyPointData(
            x_m=p.x_m,
            y_m=p.y_m,
            floor_level=p.floor,
            t_ms=p.t,
            wifi=wifi_pairs(p.wifi),
            ble=ble_pairs(p.ble),
            wifi_age_ms=[r.age_ms for r in p.wifi],
            ble_age_ms=[r.age_ms for r in p.ble],
            mag_ut=p.mag_ut,
            walk=p.walk,
            route=p.route,
        )
        for p in body.points
    ]
    return _radio_map(await maps.add_survey(s, building_id, points))


@router.get("/buildings/{building_id}/radio-maps", dependencies=[ViewerDep])
async def list_radio_maps(building_id: IdPath, s: SqlDep) -> RadioMapList:
    items = [_radio_map(m) for m in await maps.list_radio_maps(s, building_id)]
    return RadioMapList(items=items, count=len(items))


@router.post(
    "/floors/{floor_id}/magnetic-survey",
    status_code=status.HTTP_201_CREATED,
    dependencies=[MapsWriteDep],
)
async def post_magnetic_survey(
    floor_id: IdPath, body: MagneticSurveyIn, s: SqlDep
) -> MagneticMapRead:
    """Fold survey points and walked lines into the floor's magnetic map (a new version)."""
    points = [
        magnetic_maps.MagneticPointData(
            x_m=p.x_m,
            y_m=p.y_m,
            magnitude_ut=p.magnitude_ut
            if p.magnitude_ut is not None
            else math.hypot(*(p.field_ut or ())),
            horizontal_ut=p.horizontal_ut,
            vertical_ut=p.vertical_ut,
        )
        for p in body.points
    ]
    lines = [
        magnetic_maps.MagneticLineData(
            start_xy=line.start,
            end_xy=line.end,
            t_start_ms=line.t_start,
            t_end_ms=line.t_end,
            samples=line.samples,
        )
        for line in body.lines
    ]
    row = await magnetic_maps.add_magnetic_survey(s, floor_id, points, lines)
    return MagneticMapRead.model_validate(row, from_attributes=True)


@router.get("/floors/{floor_id}/magnetic-maps", dependencies=[ViewerDep])
async def list_magnetic_maps(floor_id: IdPath, s: SqlDep) -> MagneticMapList:
    rows = await magnetic_maps.list_magnetic_maps(s, floor_id)
    items = [MagneticMapRead.model_validate(m, from_attributes=True) for m in rows]
    return MagneticMapList(items=items, count=len(items))


@router.post("/buildings/{building_id}/radio-maps/{version}:activate", dependencies=[MapsWriteDep])
async def activate_radio_map(building_id: IdPath, version: VersionPath, s: SqlDep) -> RadioMapRead:
    """Roll back (or forward) to a version: it becomes the building's current radio map."""
    return _radio_map(await maps.activate_radio_map(s, building_id, version))


@router.post("/floors/{floor_id}/magnetic-maps/{version}:activate", dependencies=[MapsWriteDep])
async def activate_magnetic_map(
    floor_id: IdPath, version: VersionPath, s: SqlDep
) -> MagneticMapRead:
    """Roll back (or forward) to a version: it becomes the floor's current magnetic map."""
    row = await magnetic_maps.activate_magnetic_map(s, floor_id, version)
    return MagneticMapRead.model_validate(row, from_attributes=True)


@router.get("/buildings/{building_id}/device-offsets", dependencies=[ViewerDep])
async def list_device_offsets(building_id: IdPath, s: SqlDep) -> DeviceOffsetList:
    """Per device model, the RSSI offset estimated from co-located contributions; a
    session that names its device model has it taken off its scans."""
    await sites.get_building(s, building_id)
    found = await device_offsets.building_offsets(s, building_id)
    items = [
        DeviceOffsetRead(
            device_model=model, offset_db=o.offset_db, n_pairs=o.n_pairs, std_db=o.std_db
        )
        for model, o in sorted(found.items())
    ]
    return DeviceOffsetList(items=items, count=len(items))
