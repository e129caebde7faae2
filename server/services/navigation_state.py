"""A session's navigation as its state keeps it (JSON bytes in the snapshot and in each log
entry), and its advance by a batch's fixes: each fix gets a ``navigation`` object
(``plan.route_following``), re-routes go through the site's routing graph, and the state
after the batch is kept with the batch.

A navigation is a *course* — what stays the same along one route: the destination as the
API said it, its settings, where the destination is on the routing graph it was found on
(to re-route without asking SQL), the route and its steps — and the *progress* along it.
The course is encoded once (and decoded once per process: both are cached by the
course), so a batch encodes only its progress; floors are kept by id, so that a
navigation outlives a change of the site's floors, or ends when its floors are gone. The
wire forms of the course's steps and destination are made once per course and site
floors, so a fix costs its own placing on the route and its snapped point.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property, lru_cache
from typing import Any

import anyio
import numpy as np
import orjson

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
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
_CACHED = 512  # courses encoded, decoded and put on the wire, kept per process


@dataclass(frozen=True, eq=False)
class Course:
    """What stays the same along one route (module docstring)."""

    destination: Mapping[str, Any]  # as the API said it (RouteEnd's fields that were set)
    name: str | None
    settings: Settings
    target_floor: int
    target_vertices: tuple[int, ...]
    target_xy: tuple[float, float] | None
    graph_digest: str
    route: Route
    steps: tuple[Step, ...]
    started_ms: int

    @cached_property
    def guide(self) -> Guide:
        return guide_of(self.route, self.steps)

    def target(self) -> Endpoint:
        xy = np.array(self.target_xy) if self.target_xy is not None else None
        return Endpoint(self.target_floor, np.array(self.target_vertices, dtype=np.int64), xy)

    def rerouted(self, route: Route, steps: Sequence[Step]) -> Course:
        return replace(self, route=route, steps=tuple(steps))


@dataclass(frozen=True)
class Navigation:
    course: Course
    progress: Progress = field(default_factory=Progress)


def guide_of(route: Route, steps: Sequence[Step]) -> Guide:
    return Guide(
        floors=tuple(leg.floor for leg in route.legs),
        legs=tuple(leg.xy for leg in route.legs),
        change_s=tuple(c.seconds for c in route.changes),
        steps=tuple(steps),
        walk_speed_m_s=WALK_SPEED_M_S,
        change_kinds=tuple(c.kind for c in route.changes),
    )


class Unreadable(ValueError):
    """A navigation that cannot go on: written under another layout, or on a floor the
    site no longer has."""


def to_bytes(nav: Navigation | None, floor_ids: Sequence[str]) -> bytes:
    """The navigation as the session keeps it (``floor_ids``: the site's floors by
    index)."""
    if nav is None:
        return b""
    course = _course_json(nav.course, tuple(floor_ids))
    return orjson.dumps({"layout": LAYOUT, "course": course, "progress": vars(nav.progress)})


def from_bytes(data: bytes, floor_ids: Sequence[str]) -> Navigation | None:
    """The navigation the session keeps (None: none); Unreadable for one that cannot go
    on."""
    if not data:
        return None
    try:
        a = orjson.loads(data)
        if a.get("layout") != LAYOUT:
            raise Unreadable(f"a navigation of layout {a.get('layout')}, not {LAYOUT}")
        return Navigation(_course(a["course"], tuple(floor_ids)), Progress(**a["progress"]))
    except KeyError as e:
        raise Unreadable(f"a navigation on a floor the site no longer has, or none: {e}") from None
    except (TypeError, ValueError) as e:  # orjson.JSONDecodeError is a ValueError
        raise Unreadable(f"not a navigation: {e}") from None


@lru_cache(maxsize=_CACHED)
def _course_json(course: Course, floor_ids: tuple[str, ...]) -> str:
    ids = floor_ids
    return orjson.dumps(
        {
            "destination": dict(course.destination),
            "name": course.name,
            "settings": asdict(course.settings),
            "target": {
                "floor": ids[course.target_floor],
                "vertices": list(course.target_vertices),
                "xy": list(course.target_xy) if course.target_xy is not None else None,
                "digest": course.graph_digest,
            },
            "legs": [{"floor": ids[leg.floor], "xy": leg.xy.tolist()} for leg in course.route.legs],
            "changes": [
                asdict(c) | {"from_floor": ids[c.from_floor], "to_floor": ids[c.to_floor]}
                for c in course.route.changes
            ],
            "steps": [asdict(st) | {"floor": ids[st.floor]} for st in course.steps],
            "started_ms": course.started_ms,
        }
    ).decode()


@lru_cache(maxsize=_CACHED)
def _course(text: str, floor_ids: tuple[str, ...]) -> Course:
    """A course from its JSON; KeyError for a floor not in ``floor_ids``."""
    index = {floor_id: i for i, floor_id in enumerate(floor_ids)}
    a = orjson.loads(text)
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
    course = Course(
        destination=a["destination"],
        name=a["name"],
        settings=Settings(**a["settings"]),
        target_floor=index[target["floor"]],
        target_vertices=tuple(target["vertices"]),
        target_xy=tuple(target["xy"]) if target["xy"] is not None else None,
        graph_digest=target["digest"],
        route=route,
        steps=tuple(Step(**(st | {"floor": index[st["floor"]]})) for st in a["steps"]),
        started_ms=a["started_ms"],
    )
    return course


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
        course = current.course
        fresh: list[Course] = []

        def reroute(
            at: FixAt, course: Course = course, fresh: list[Course] = fresh
        ) -> Guide | None:
            route = _route_from(course, graph, at) if graph is not None else None
            if route is None:
                return None
            fresh.append(course.rerouted(route, route_steps_of(maps, route, course.name)))
            return fresh[-1].guide

        report = follow(course.guide, current.progress, fix, course.settings, reroute)
        current = Navigation(fresh[-1] if fresh else course, report.progress)
        out.append(report_to_wire(maps, current, report))
        if report.progress.arrived:
            current = None
    return current, out


def _route_from(course: Course, graph: RoutingGraph, at: FixAt) -> Route | None:
    """A new route from a fix to the course's destination; None when there is none."""
    try:
        origin = point_endpoint(graph, at.floor, (at.x_m, at.y_m), "origin", REROUTE_REACH_M)
        if graph.digest == course.graph_digest:
            target = course.target()
        else:  # the plans changed since: the destination as a point
            end = course.route.legs[-1]
            target = point_endpoint(graph, end.floor, end.xy[-1], "destination", 3.0)
        return find_route(graph, origin, target, course.settings.accessible)
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
        detail |= {
            "destination": nav.course.name,
            "duration_s": (event.t_ms - nav.course.started_ms) / 1000,
        }
    return detail


@lru_cache(maxsize=_CACHED)
def _course_wire(
    course: Course, floors: tuple[FloorRef, ...]
) -> tuple[dict[str, Any], tuple[dict[str, Any], ...]]:
    """The destination and the steps of a course as the wire has them, once per course."""
    last = course.route.legs[-1]
    destination = {**where(floors[last.floor], *map(float, last.xy[-1])), "name": course.name}
    return destination, tuple(step_to_wire(floors, s) for s in course.steps)


def report_to_wire(maps: SiteMaps, nav: Navigation, report: Report) -> dict[str, Any]:
    """A fix's ``navigation`` object."""
    destination, steps = _course_wire(nav.course, maps.floors)
    floor, x, y = report.snapped
    step = report.progress.step
    return {
        "status": "arrived" if report.progress.arrived else "navigating",
        "destination": destination,
        "remaining_m": round(report.remaining_m, 2),
        "remaining_s": round(report.remaining_s, 1),
        "on_route": report.on_route,
        "off_route_m": round(report.off_route_m, 2) if report.off_route_m is not None else None,
        "step_index": step,
        "next_step": steps[step + 1] if report.next is not None else None,
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
    course = nav.course
    return route_to_wire(maps, course.route, course.steps, course.settings.accessible, course.name)


async def navigate(
    maps: SiteMaps, data: bytes, fixes: Sequence[Fix]
) -> tuple[bytes, list[dict[str, Any] | None]]:
    """A batch's part of the navigation: the state after its fixes and each fix's
    ``navigation`` object (None: not navigating). Following a route costs tens of
    microseconds a fix, on the event loop (``bench/performance.md``); a batch that may
    re-route (its walker already off the route, or enough fixes to start and finish a
    run) runs in a worker thread, as a route search takes milliseconds. A navigation that
    cannot go on (a floor the site lost, a layout of another server) or that fails ends,
    logged: it never holds up the session's batches."""
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
        may_reroute = (
            nav.progress.off_since_ms >= 0 or len(places) >= nav.course.settings.reroute_fixes
        )
        if may_reroute:
            after, wires = await anyio.to_thread.run_sync(advance, nav, maps, graph, places)
        else:
            after, wires = advance(nav, maps, graph, places)
        return to_bytes(after, floor_ids), wires
    except Exception:  # a bug here must not stick the session: every retry would fail
        logger.exception("navigation ended by an error")
        return b"", [None] * len(fixes)
