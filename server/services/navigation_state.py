"""A session's navigation as its state keeps it (JSON bytes in the snapshot and in each log
entry), and its advance by a batch's fixes: each fix gets a ``navigation`` object
(``plan.route_following``), re-routes go through the site's routing graph, and the state
after the batch is kept with the batch.

The state holds what the navigation asked for (the destination as the API said it and its
settings), where the destination is on the routing graph it was found on (to re-route
without asking SQL), the route being followed (legs, floor changes, steps) and the
progress along it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from typing import Any

import anyio
import numpy as np
import orjson

from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model.events import Fix
from server.positioning.plan.route_following import (
    Event,
    FixAt,
    Guide,
    Progress,
    Report,
    Settings,
    follow,
)
from server.positioning.plan.route_steps import Step
from server.positioning.plan.routes import (
    Endpoint,
    FloorChange,
    Leg,
    NoRoute,
    Route,
    find_route,
    point_endpoint,
)
from server.positioning.plan.routing_graph import WALK_SPEED_M_S, RoutingGraph
from server.services.routes import (
    route_steps_of,
    route_to_wire,
    routing,
    step_to_wire,
    where,
)

logger = logging.getLogger("indoorpos.navigation")

LAYOUT = 1
REROUTE_REACH_M = 15.0  # how far from walkable space a fix may be and still be routed from


@dataclass(frozen=True)
class Navigation:
    """What a navigating session keeps (module docstring)."""

    destination: Mapping[str, Any]  # as the API said it (RouteEnd's fields that were set)
    name: str | None
    settings: Settings
    target_floor: int
    target_vertices: tuple[int, ...]
    target_xy: tuple[float, float] | None
    graph_digest: str
    route: Route
    steps: tuple[Step, ...]
    progress: Progress
    started_ms: int

    @cached_property
    def guide(self) -> Guide:
        return guide_of(self.route, self.steps)

    def target(self) -> Endpoint:
        xy = np.array(self.target_xy) if self.target_xy is not None else None
        return Endpoint(self.target_floor, np.array(self.target_vertices, dtype=np.int64), xy)


def guide_of(route: Route, steps: Sequence[Step]) -> Guide:
    return Guide(
        floors=tuple(leg.floor for leg in route.legs),
        legs=tuple(leg.xy for leg in route.legs),
        change_s=tuple(c.seconds for c in route.changes),
        steps=tuple(steps),
        walk_speed_m_s=WALK_SPEED_M_S,
        change_kinds=tuple(c.kind for c in route.changes),
    )


def to_bytes(nav: Navigation | None, floor_ids: Sequence[str]) -> bytes:
    """The navigation as the session keeps it; floors by id (``floor_ids``: the site's
    floors by index), so that it outlives a change of the site's floors."""
    if nav is None:
        return b""
    ids = list(floor_ids)
    return orjson.dumps(
        {
            "layout": LAYOUT,
            "destination": dict(nav.destination),
            "name": nav.name,
            "settings": asdict(nav.settings),
            "target": {
                "floor": ids[nav.target_floor],
                "vertices": list(nav.target_vertices),
                "xy": list(nav.target_xy) if nav.target_xy is not None else None,
                "digest": nav.graph_digest,
            },
            "legs": [{"floor": ids[leg.floor], "xy": leg.xy.tolist()} for leg in nav.route.legs],
            "changes": [
                asdict(c) | {"from_floor": ids[c.from_floor], "to_floor": ids[c.to_floor]}
                for c in nav.route.changes
            ],
            "steps": [asdict(st) | {"floor": ids[st.floor]} for st in nav.steps],
            "progress": asdict(nav.progress),
            "started_ms": nav.started_ms,
        }
    )


class Unreadable(ValueError):
    """A navigation that cannot go on: written under another layout, or on a floor the
    site no longer has."""


def from_bytes(data: bytes, floor_ids: Sequence[str]) -> Navigation | None:
    """The navigation the session keeps (None: none); Unreadable for one that cannot go
    on."""
    if not data:
        return None
    index = {floor_id: i for i, floor_id in enumerate(floor_ids)}
    try:
        a = orjson.loads(data)
        if a.get("layout") != LAYOUT:
            raise Unreadable(f"a navigation of layout {a.get('layout')}, not {LAYOUT}")
        target = a["target"]
        route = Route(
            legs=tuple(
                Leg(index[leg["floor"]], np.array(leg["xy"], dtype=np.float64)) for leg in a["legs"]
            ),
            changes=tuple(
                FloorChange(
                    **(c | {"from_floor": index[c["from_floor"]], "to_floor": index[c["to_floor"]]})
                )
                for c in a["changes"]
            ),
        )
        return Navigation(
            destination=a["destination"],
            name=a["name"],
            settings=Settings(**a["settings"]),
            target_floor=index[target["floor"]],
            target_vertices=tuple(target["vertices"]),
            target_xy=tuple(target["xy"]) if target["xy"] is not None else None,
            graph_digest=target["digest"],
            route=route,
            steps=tuple(Step(**(st | {"floor": index[st["floor"]]})) for st in a["steps"]),
            progress=Progress(**a["progress"]),
            started_ms=a["started_ms"],
        )
    except KeyError as e:
        raise Unreadable(
            f"a navigation on a floor the site no longer has, or not one: {e}"
        ) from None
    except (TypeError, ValueError, orjson.JSONDecodeError) as e:
        raise Unreadable(f"not a navigation: {e}") from None


def fix_at(fix: Fix) -> FixAt:
    return FixAt(fix.t_ms, fix.floor, fix.x_m, fix.y_m, fix.accuracy_68_m)


def advance(
    nav: Navigation, maps: SiteMaps, graph: RoutingGraph | None, fixes: Sequence[FixAt]
) -> tuple[Navigation | None, list[dict[str, Any] | None]]:
    """The navigation after ``fixes`` (None once arrived), and each fix's ``navigation``
    object (wire form); re-routed through ``graph`` (None: never re-routed)."""
    out: list[dict[str, Any] | None] = []
    current: Navigation | None = nav
    for fix in fixes:
        if current is None:
            out.append(None)
            continue
        now = current
        fresh: dict[str, Route] = {}

        def reroute(
            at: FixAt, now: Navigation = now, fresh: dict[str, Route] = fresh
        ) -> Guide | None:
            route = _route_from(now, graph, at) if graph is not None else None
            if route is None:
                return None
            fresh["route"] = route
            return guide_of(route, route_steps_of(maps, route, now.name))

        report = follow(now.guide, now.progress, fix, now.settings, reroute)
        current = replace(
            now, route=fresh.get("route", now.route), steps=report.guide.steps,
            progress=report.progress,
        )  # fmt: skip
        out.append(report_to_wire(maps, current, report))
        if report.progress.arrived:
            current = None
    return current, out


def _route_from(nav: Navigation, graph: RoutingGraph, at: FixAt) -> Route | None:
    """A new route from a fix to the navigation's destination; None when there is none."""
    try:
        origin = point_endpoint(graph, at.floor, (at.x_m, at.y_m), "origin", REROUTE_REACH_M)
        if graph.digest == nav.graph_digest:
            target = nav.target()
        else:  # the plans changed since: the destination as a point
            end = nav.route.legs[-1]
            target = point_endpoint(graph, end.floor, end.xy[-1], "destination", 3.0)
        return find_route(graph, origin, target, nav.settings.accessible)
    except NoRoute:
        return None


def instruction(report: Report) -> str:
    """The next instruction in words: "In 12 m, turn left"; "Continue" while withheld."""
    nxt = report.next
    if nxt is None:
        return "You have arrived" if report.progress.arrived else "Continue"
    if report.withheld:
        return "Continue"
    text = nxt.text[0].lower() + nxt.text[1:]
    distance = report.distance_to_next_m or 0.0
    return f"In {distance:.0f} m, {text}" if distance >= 1.0 else nxt.text


def event_to_wire(maps: SiteMaps, nav: Navigation, event: Event) -> dict[str, Any]:
    """A navigation event as fixes, the socket and webhooks carry it."""
    detail: dict[str, Any] = {
        "type": event.kind,
        "t": event.t_ms,
        "route_version": nav.progress.reroutes,
    }
    if event.kind == "floor_change":
        detail |= {
            "kind": event.detail["kind"],
            "from_level": maps.floors[event.detail["from_floor"]].level,
            "to_level": maps.floors[event.detail["to_floor"]].level,
        }
    elif event.kind == "rerouted":
        detail |= {"off_route_m": event.detail["off_route_m"], "length_m": event.detail["length_m"]}
    elif event.kind == "arrived":
        detail |= {"destination": nav.name, "duration_s": (event.t_ms - nav.started_ms) / 1000}
    return detail


def report_to_wire(maps: SiteMaps, nav: Navigation, report: Report) -> dict[str, Any]:
    floor, x, y = report.snapped
    last = nav.route.legs[-1]
    return {
        "status": "arrived" if report.progress.arrived else "navigating",
        "destination": {
            **where(maps.floors[last.floor], *map(float, last.xy[-1])),
            "name": nav.name,
        },
        "remaining_m": round(report.remaining_m, 2),
        "remaining_s": round(report.remaining_s, 1),
        "on_route": report.on_route,
        "off_route_m": round(report.off_route_m, 2) if report.off_route_m is not None else None,
        "step_index": report.progress.step,
        "current_step": step_to_wire(maps, report.current),
        "next_step": step_to_wire(maps, report.next) if report.next is not None else None,
        "distance_to_next_m": (
            round(report.distance_to_next_m, 2) if report.distance_to_next_m is not None else None
        ),
        "instruction": instruction(report),
        "withheld": report.withheld,
        "snapped": where(maps.floors[floor], x, y),
        "route_version": report.progress.reroutes,
        "events": [event_to_wire(maps, nav, e) for e in report.events],
    }


def route_wire(maps: SiteMaps, nav: Navigation) -> dict[str, Any]:
    """The route being followed, as ``POST /routes`` answers one."""
    return route_to_wire(maps, nav.route, nav.steps, nav.settings.accessible, nav.name)


async def navigate(
    maps: SiteMaps, data: bytes, fixes: Sequence[Fix]
) -> tuple[bytes, list[dict[str, Any] | None]]:
    """A batch's part of the navigation: the state after its fixes and each fix's
    ``navigation`` object (None: not navigating). Following a route costs about a hundred
    microseconds a fix, on the event loop; a batch that may re-route (its walker already
    off the route, or enough fixes to start and finish a run) runs in a worker thread, as
    a route search takes milliseconds. A navigation that cannot go on (a floor the site
    lost, a layout of another server) or that fails ends, logged: it never holds up the
    session's batches."""
    floor_ids = [f.floor_id for f in maps.floors]
    try:
        nav = from_bytes(data, floor_ids)
    except Unreadable as e:
        logger.warning("navigation ended: %s", e)
        return b"", [None] * len(fixes)
    if nav is None or not fixes:
        return data, [None] * len(fixes)
    places = [fix_at(f) for f in fixes]
    try:
        graph = await routing(maps)
        may_reroute = nav.progress.off_since_ms >= 0 or len(places) >= nav.settings.reroute_fixes
        if may_reroute:
            after, wires = await anyio.to_thread.run_sync(advance, nav, maps, graph, places)
        else:
            after, wires = advance(nav, maps, graph, places)
        return to_bytes(after, floor_ids), wires
    except Exception:  # a bug here must not stick the session: every retry would fail
        logger.exception("navigation ended by an error")
        return b"", [None] * len(fixes)
