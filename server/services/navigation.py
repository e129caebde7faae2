"""Navigation of a session: started towards a destination from the session's latest fix,
read back, stopped. The navigation lives in the session's state (``navigation_state``):
starting or stopping it writes a snapshot of the session (after the engine steps its
log still owes, as a batch would take them), so that any replica's next batch follows it.

Who may: the session's token, or an ``admin`` key of the session's site (a console
guiding a visitor); reading: also a ``viewer`` key of the site.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import asdict, replace
from typing import Any

import anyio
import orjson

from server.positioning.engines.registry import NEEDS_GRAPHS, get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.plan.route_following import FixAt, Settings
from server.services import engine_settings
from server.services.batches import caught_up
from server.services.errors import Forbidden, NotFound
from server.services.maps import site_maps, with_graphs
from server.services.navigation_state import (
    Course,
    Navigation,
    Unreadable,
    advance,
    from_bytes,
    route_wire,
    to_bytes,
)
from server.services.routes import (
    Placed,
    RouteEnd,
    fix_endpoint,
    resolve,
    route_steps_of,
    routing,
    search,
)
from server.services.runtime import Runtime
from server.services.session_records import SessionMeta, SessionState
from server.services.sessions import authorize_reader, load_state, site_key

Change = Callable[[SessionMeta, SessionState, SiteMaps], Awaitable[Navigation | None]]


async def authorize_driver(rt: Runtime, session_id: str, secret: str) -> str | None:
    """The token to read the session with: ``secret`` when it is the session's token, None
    for an admin key of the session's site; Forbidden (NotFound) otherwise."""
    try:
        await load_state(rt, session_id, secret)
    except Forbidden:
        await site_key(rt, session_id, secret, "admin")
        return None
    return secret


async def _write(
    rt: Runtime, session_id: str, secret: str, change: Change
) -> tuple[SiteMaps, Navigation | None]:
    """Set the session's navigation to what ``change`` makes of it, as one snapshot
    written by compare-and-set (read again when another writer got there first)."""
    token = await authorize_driver(rt, session_id, secret)
    while True:
        version, meta, state = await load_state(rt, session_id, token)
        async with rt.transaction() as s:
            maps = await site_maps(s, rt.maps, meta.site_id)
        nav = await change(meta, state, maps)
        engine_maps = await with_graphs(maps) if meta.engine in NEEDS_GRAPHS else maps
        params = engine_settings.session_params(meta.engine, meta.params)
        engine_state = await anyio.to_thread.run_sync(caught_up, state, meta, engine_maps, params)
        new_state = replace(
            state,
            engine_state=engine_state,
            pending=(),
            navigation=to_bytes(nav, [f.floor_id for f in maps.floors]),
        )
        spec = get_engine(meta.engine)
        written = await rt.store.compare_and_set(
            session_id, version, new_state.to_bytes(spec), rt.settings.session_idle_s
        )
        if written:
            rt.states.put(session_id, version + 1, meta, new_state, written=True)
            return maps, nav
        rt.states.drop(session_id)


def _fix_at(maps: SiteMaps, fix: dict[str, Any]) -> FixAt:
    """A fix of the wire as the navigation reads one (floor -1: a floor the site lost)."""
    floor = next((i for i, f in enumerate(maps.floors) if f.floor_id == fix["floor_id"]), -1)
    return FixAt(
        int(fix["t"]), floor, float(fix["x_m"]), float(fix["y_m"]), fix.get("accuracy_68_m")
    )


def _answer(maps: SiteMaps, nav: Navigation, last_fix: dict[str, Any] | None) -> dict[str, Any]:
    """The route and the navigation as the latest fix stands on it."""
    progress = None
    if last_fix and last_fix.get("floor_id") is not None:
        _, wires = advance(nav, maps, None, [_fix_at(maps, last_fix)])  # read: no re-route
        progress = wires[0]
    return {"route": route_wire(maps, nav), "navigation": progress}


async def start(
    rt: Runtime, session_id: str, secret: str, destination: RouteEnd, settings: Settings
) -> dict[str, Any]:
    """Navigate the session from its latest fix to ``destination`` (replacing any
    navigation it had); NotFound naming why when there is no route."""
    found: dict[str, Any] = {}

    async def begin(meta: SessionMeta, state: SessionState, maps: SiteMaps) -> Navigation:
        """The navigation of a new course from the session's latest fix."""
        graph = await routing(maps)
        fix = orjson.loads(state.last_fix) if state.last_fix else None
        origin = fix_endpoint(maps, graph, fix, "session")
        stop = await resolve(
            rt, meta.site_id, maps, graph, destination, "destination", origin.floor
        )
        route = await anyio.to_thread.run_sync(
            lambda: search(graph, Placed(origin), stop, settings.accessible)
        )
        found["fix"] = fix
        target = stop.endpoint
        course = Course(
            destination={k: v for k, v in asdict(destination).items() if v is not None},
            name=stop.name,
            settings=settings,
            target_floor=target.floor,
            target_vertices=tuple(int(v) for v in target.vertices.tolist()),
            target_xy=(float(target.xy[0]), float(target.xy[1])) if target.xy is not None else None,
            graph_digest=graph.digest,
            route=route,
            steps=tuple(route_steps_of(maps, route, stop.name)),
            started_ms=int(fix["t"]) if fix else 0,
        )
        return Navigation(course)

    maps, nav = await _write(rt, session_id, secret, begin)
    assert nav is not None
    return _answer(maps, nav, found.get("fix"))


async def stop(rt: Runtime, session_id: str, secret: str) -> None:
    """Stop the session's navigation (nothing to stop is no error)."""

    async def end(_meta: SessionMeta, _state: SessionState, _maps: SiteMaps) -> None:
        return None

    await _write(rt, session_id, secret, end)


async def read(rt: Runtime, session_id: str, secret: str) -> dict[str, Any]:
    """The session's navigation: its route and where the latest fix stands on it;
    NotFound when it is not navigating."""
    owner = await authorize_reader(rt, session_id, secret)
    _, meta, state = await load_state(rt, session_id, secret if owner else None)
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, meta.site_id)
    try:
        nav = from_bytes(state.navigation, [f.floor_id for f in maps.floors])
    except Unreadable:
        nav = None  # its next batch ends it
    if nav is None:
        raise NotFound("the session is not navigating", field="session_id")
    return _answer(maps, nav, orjson.loads(state.last_fix) if state.last_fix else None)
