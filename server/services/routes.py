"""Routes between places of a site: where a route starts and ends (a point, a session's
latest fix, a zone, a named place of the plan), the site's routing graph (built once per
plan version, in a worker thread, and kept per process), and a route as the wire carries
it. The search and the instructions are the core's (``plan.routing_graph``,
``plan.routes``, ``plan.route_steps``)."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import anyio
import orjson
import shapely

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.model.geo import heading_from_north_deg, to_local, to_world
from server.positioning.plan.route_steps import Step, route_steps
from server.positioning.plan.routes import (
    Endpoint,
    NoRoute,
    Route,
    area_endpoint,
    find_route,
    point_endpoint,
)
from server.positioning.plan.routing_graph import LAYOUT as GRAPH_LAYOUT
from server.positioning.plan.routing_graph import (
    FloorInput,
    Place,
    RoutingGraph,
    routing_graph,
)
from server.services.errors import Invalid, NotFound
from server.services.maps import site_maps
from server.services.runtime import Runtime
from server.services.sessions import load_state
from server.storage.repositories import zones as zone_repo

GRAPH_CACHE_SIZE = 8  # sites' routing graphs kept per process
_GRAPHS: OrderedDict[tuple[str, ...], RoutingGraph] = OrderedDict()
_LOCKS: dict[tuple[str, ...], anyio.Lock] = {}
# the graph of the map sets asked for lately, by the map set itself (which a process keeps
# while it is fresh): a navigating batch finds its graph without making the key again
_BY_MAPS: OrderedDict[int, tuple[SiteMaps, RoutingGraph]] = OrderedDict()


@dataclass(frozen=True)
class RouteEnd:
    """One end of a route as the API says it: exactly one of a point (``floor_id`` with
    ``x_m``/``y_m``, or ``lat``/``lon`` with ``level`` and, in a site of several
    buildings, ``building_id``), a session (its latest fix), a zone or a place."""

    floor_id: str | None = None
    x_m: float | None = None
    y_m: float | None = None
    lat: float | None = None
    lon: float | None = None
    level: int | None = None
    building_id: str | None = None
    session_id: str | None = None
    zone_id: str | None = None
    place: str | None = None


@dataclass(frozen=True)
class Placed:
    """A resolved end: where the search starts or stops, and its name (a zone's, a
    place's)."""

    endpoint: Endpoint
    name: str | None = None


def _key(maps: SiteMaps) -> tuple[str, ...]:
    return _graph_key(maps.plan_digest, maps.floors)


@lru_cache(maxsize=64)
def _graph_key(plan_digest: str, floors: tuple[FloorRef, ...]) -> tuple[str, ...]:
    """What a routing graph is built from: the plans, and the floors' buildings and levels
    (cached: a navigating batch asks for it)."""
    return (plan_digest, *(f"{f.building_id}/{f.floor_id}@{f.level}" for f in floors))


def cached_graph(maps: SiteMaps) -> RoutingGraph | None:
    """The site's routing graph when this process has built it for these plans."""
    seen = _BY_MAPS.get(id(maps))
    if seen is not None and seen[0] is maps:  # the same map set as a batch ago: no key
        return seen[1]
    key = _key(maps)
    found = _GRAPHS.get(key)
    if found is not None:
        _GRAPHS.move_to_end(key)
        _BY_MAPS[id(maps)] = (maps, found)
        while len(_BY_MAPS) > GRAPH_CACHE_SIZE:
            _BY_MAPS.popitem(last=False)
    return found


async def routing(maps: SiteMaps) -> RoutingGraph:
    """The site's routing graph, built once per plan version (a new radio map or zone
    leaves it as it is), off the event loop."""
    found = cached_graph(maps)
    if found is not None:
        return found
    key = _key(maps)
    async with _LOCKS.setdefault(key, anyio.Lock()):
        found = cached_graph(maps)
        if found is None:
            floors = [
                FloorInput(
                    f.building_id,
                    f.level,
                    maps.plans[i] if i < len(maps.plans) else None,
                    maps.plan_geojson[i] if i < len(maps.plan_geojson) else None,
                )
                for i, f in enumerate(maps.floors)
            ]
            digest = f"{maps.plan_digest}/{GRAPH_LAYOUT}"
            found = await anyio.to_thread.run_sync(lambda: routing_graph(floors, digest))
            _GRAPHS[key] = found
            while len(_GRAPHS) > GRAPH_CACHE_SIZE:
                dropped, _ = _GRAPHS.popitem(last=False)
                _LOCKS.pop(dropped, None)
    return found


def _floor_index(maps: SiteMaps, floor_id: str, field: str) -> int:
    for i, f in enumerate(maps.floors):
        if f.floor_id == floor_id:
            return i
    raise Invalid(f"floor {floor_id} is not a floor of this site", field=f"{field}.floor_id")


def _world_floor(maps: SiteMaps, end: RouteEnd, field: str) -> int:
    """The floor a lat/lon/level end is on: of its building, or of the one building of the
    site that is geo-referenced and has that level."""
    found = [
        i
        for i, f in enumerate(maps.floors)
        if f.level == end.level
        and f.geo is not None
        and (end.building_id is None or f.building_id == end.building_id)
    ]
    if not found:
        raise Invalid(
            f"no geo-referenced building of this site has level {end.level}", field=f"{field}.level"
        )
    if len({maps.floors[i].building_id for i in found}) > 1:
        raise Invalid(
            "several buildings have this level: say which with building_id",
            field=f"{field}.building_id",
        )
    return found[0]


async def resolve(
    rt: Runtime,
    site_id: str,
    maps: SiteMaps,
    graph: RoutingGraph,
    end: RouteEnd,
    field: str,
    near_floor: int | None = None,
) -> Placed:
    """Where a route starts or stops (``RouteEnd``); Invalid or NotFound naming the
    field. ``near_floor``: a place found on several floors is taken on this one first."""
    try:
        if end.session_id is not None:
            return Placed(await _session_end(rt, site_id, maps, graph, end.session_id, field))
        if end.zone_id is not None:
            return await _zone_end(rt, maps, graph, end, field)
        if end.place is not None:
            return _place_end(graph, end.place, field, near_floor)
        if end.floor_id is not None and end.x_m is not None and end.y_m is not None:
            floor = _floor_index(maps, end.floor_id, field)
            return Placed(point_endpoint(graph, floor, (end.x_m, end.y_m), field))
        if end.lat is not None and end.lon is not None and end.level is not None:
            floor = _world_floor(maps, end, field)
            geo = maps.floors[floor].geo
            assert geo is not None  # _world_floor finds geo-referenced floors only
            return Placed(point_endpoint(graph, floor, to_local(end.lat, end.lon, geo), field))
    except NoRoute as e:
        raise NotFound(e.reason, field=e.field) from None
    raise Invalid(
        "say where: floor_id with x_m and y_m, lat and lon with level, session_id, zone_id "
        "or place",
        field=field,
    )


async def _session_end(
    rt: Runtime, site_id: str, maps: SiteMaps, graph: RoutingGraph, session_id: str, field: str
) -> Endpoint:
    """A session's latest fix (the caller may view the site); snapped to the walkable
    grid within its 95 % radius."""
    _, meta, state = await load_state(rt, session_id, None)
    if meta.site_id != site_id:
        raise NotFound(f"session {session_id} is not a session of this site", field=field)
    fix = orjson.loads(state.last_fix) if state.last_fix else None
    return fix_endpoint(maps, graph, fix, f"{field}.session_id")


def fix_endpoint(
    maps: SiteMaps, graph: RoutingGraph, fix: Mapping[str, Any] | None, field: str
) -> Endpoint:
    """A fix (wire form) as a route's start, snapped within its 95 % radius (at most
    15 m) to walkable space."""
    if not fix or fix.get("floor_id") is None:
        raise NotFound("the session's latest fix is on no floor of the site", field=field)
    floor = next((i for i, f in enumerate(maps.floors) if f.floor_id == fix["floor_id"]), None)
    if floor is None:
        raise NotFound("the session's latest fix is on a floor the site no longer has", field=field)
    reach = min(15.0, float(fix.get("accuracy_95_m") or 5.0))
    try:
        return point_endpoint(graph, floor, (fix["x_m"], fix["y_m"]), field, reach_m=reach)
    except NoRoute as e:
        raise NotFound(e.reason, field=e.field) from None


async def _zone_end(
    rt: Runtime, maps: SiteMaps, graph: RoutingGraph, end: RouteEnd, field: str
) -> Placed:
    found = [
        z
        for z in maps.zones.zones
        if z.id == end.zone_id and (end.floor_id is None or z.floor_id == end.floor_id)
    ]
    if not found:
        raise NotFound(f"zone {end.zone_id} not found in this site", field=f"{field}.zone_id")
    if len(found) > 1:
        raise Invalid(
            f"zone {end.zone_id} is on several floors: say which with floor_id",
            field=f"{field}.floor_id",
        )
    zone = found[0]
    async with rt.read() as s:
        rows = await zone_repo.floor_zones(s, zone.floor_id)
        properties = next((dict(r.properties or {}) for r in rows if r.id == zone.id), {})
    endpoint = area_endpoint(graph, zone.floor, zone.shape, field, _entrances(properties))
    return Placed(endpoint, zone.name)


def _entrances(properties: Mapping[str, Any]) -> list[tuple[float, float]]:
    """A zone's declared entrances: ``properties.entrances`` (a list of ``[x, y]``) or
    ``properties.entrance`` (one), floor metres; what is not a point is skipped."""
    raw = properties.get("entrances", [properties["entrance"]] if "entrance" in properties else [])
    points = []
    for p in raw if isinstance(raw, list) else []:
        if (
            isinstance(p, list)
            and len(p) >= 2
            and all(isinstance(v, int | float) and math.isfinite(v) for v in p[:2])
        ):
            points.append((float(p[0]), float(p[1])))
    return points


def _place_end(graph: RoutingGraph, wanted: str, field: str, near_floor: int | None) -> Placed:
    key = wanted.strip().casefold()
    found = [p for p in graph.places if p.id == wanted or p.name.casefold() == key]
    if not found:
        raise NotFound(
            f"no place of the plan has the id or name {wanted!r}", field=f"{field}.place"
        )
    found.sort(key=lambda p: p.floor != near_floor)
    place: Place = found[0]
    if place.shape.geom_type == "Point":
        xy = tuple(shapely.get_coordinates(place.shape)[0])
        return Placed(point_endpoint(graph, place.floor, xy, field, reach_m=3.0), place.name)
    return Placed(area_endpoint(graph, place.floor, place.shape, field), place.name)


async def plan_route(
    rt: Runtime,
    site_id: str,
    origin: RouteEnd,
    destination: RouteEnd,
    accessible: bool,
) -> dict[str, Any]:
    """A route between two ends of the site, as the wire carries it (``route_to_wire``);
    NotFound naming why when there is none."""
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, site_id)
    graph = await routing(maps)
    start = await resolve(rt, site_id, maps, graph, origin, "origin")
    stop = await resolve(rt, site_id, maps, graph, destination, "destination", start.endpoint.floor)
    route = await anyio.to_thread.run_sync(lambda: search(graph, start, stop, accessible))
    return route_to_wire(maps, route, route_steps_of(maps, route, stop.name), accessible, stop.name)


def search(graph: RoutingGraph, start: Placed, stop: Placed, accessible: bool) -> Route:
    try:
        return find_route(graph, start.endpoint, stop.endpoint, accessible)
    except NoRoute as e:
        raise NotFound(e.reason, field=e.field) from None


def route_steps_of(maps: SiteMaps, route: Route, name: str | None) -> list[Step]:
    levels = [f.level for f in maps.floors]
    return route_steps(route, levels, [f.rotation_rad for f in maps.floors], name)


def where(ref: FloorRef, x_m: float, y_m: float) -> dict[str, Any]:
    """A point of a floor as the wire gives it: floor metres, and WGS84 where the building
    is geo-referenced."""
    lat, lon = to_world(x_m, y_m, ref.geo) if ref.geo is not None else (None, None)
    return {
        "floor_id": ref.floor_id,
        "building_id": ref.building_id,
        "level": ref.level,
        "x_m": x_m,
        "y_m": y_m,
        "lat": lat,
        "lon": lon,
    }


def step_to_wire(floors: Sequence[FloorRef], step: Step) -> dict[str, Any]:
    ref = floors[step.floor]
    bearing = (
        heading_from_north_deg(step.bearing_rad, ref.rotation_rad)
        if step.bearing_rad is not None
        else None
    )
    return {
        "kind": step.kind,
        "text": step.text,
        "distance_m": round(step.distance_m, 2),
        "along_m": round(step.along_m, 2),
        "bearing_deg": bearing,
        "to_level": step.to_level,
        **where(ref, step.x_m, step.y_m),
    }


def route_to_wire(
    maps: SiteMaps,
    route: Route,
    steps: Sequence[Step],
    accessible: bool,
    destination_name: str | None = None,
) -> dict[str, Any]:
    legs = []
    for leg in route.legs:
        ref = maps.floors[leg.floor]
        coordinates = [[float(x), float(y)] for x, y in leg.xy]
        wgs84 = None
        if ref.geo is not None:
            geo = ref.geo
            wgs84 = {
                "type": "LineString",
                "coordinates": [list(reversed(to_world(x, y, geo))) for x, y in coordinates],
            }
        legs.append(
            {
                "floor_id": ref.floor_id,
                "building_id": ref.building_id,
                "level": ref.level,
                "length_m": round(leg.length_m, 2),
                "geometry": {"type": "LineString", "coordinates": coordinates},
                "geometry_wgs84": wgs84,
            }
        )
    changes = [
        {
            "kind": c.kind,
            "name": c.name,
            "from_floor_id": maps.floors[c.from_floor].floor_id,
            "to_floor_id": maps.floors[c.to_floor].floor_id,
            "from_level": maps.floors[c.from_floor].level,
            "to_level": maps.floors[c.to_floor].level,
            "duration_s": round(c.seconds, 1),
        }
        for c in route.changes
    ]
    first, last = route.legs[0], route.legs[-1]
    return {
        "length_m": round(route.length_m, 2),
        "duration_s": round(route.duration_s, 1),
        "accessible": accessible,
        "origin": where(maps.floors[first.floor], *map(float, first.xy[0])),
        "destination": {
            **where(maps.floors[last.floor], *map(float, last.xy[-1])),
            "name": destination_name,
        },
        "legs": legs,
        "floor_changes": changes,
        "steps": [step_to_wire(maps.floors, s) for s in steps],
    }
