"""Navigation: a walker's progress along a route, fix by fix, with re-routing and arrival.

Each fix is placed on the route: on the nearest of the leg it is following and the next
``LEG_LOOKAHEAD`` that lie on its floor (a leg on another floor than the last: a
``floor_change`` event), at the nearest point of the leg's polyline. ``off_route_m`` is
the distance to it. The walker is off the route when
that exceeds ``Settings.off_route_m``; it is re-routed (from the fix, a ``rerouted``
event) only once its fixes have said so without a break for ``Settings.reroute_after_s``
and ``Settings.reroute_fixes`` fixes (a hysteresis like the zones' in ``zone_presence``:
one wild fix, or a wobble across the threshold, re-routes nothing). A fix off walkable
space is re-routed from where it snaps to: the new route counts the fix on it as far as
that (``Progress.grace_m``) until the walker comes near it. A search that finds no route
keeps the old one and starts the off-route run again. It arrives (an ``arrived`` event,
and navigation ends) when a fix on the last leg is within ``Settings.arrival_m`` of the
destination in a straight line, or along the route while near it (within
``Settings.off_route_m``).

The next instruction is withheld ("Continue") while the fix's 68 % radius is larger than
the distance to the step it announces: until the filter is sure which side of a turn the
walker is, it says nothing it might have to take back.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.plan.route_steps import Step

FloatArray = NDArray[np.float64]

OFF_ROUTE_M = 5.0
ARRIVAL_M = 3.0
REROUTE_AFTER_S = 4.0
REROUTE_FIXES = 3


@dataclass(frozen=True)
class Settings:
    """What a navigating session asked for."""

    off_route_m: float = OFF_ROUTE_M
    arrival_m: float = ARRIVAL_M
    reroute_after_s: float = REROUTE_AFTER_S
    reroute_fixes: int = REROUTE_FIXES
    accessible: bool = False


@dataclass(frozen=True, eq=False)
class Guide:
    """A route as navigation follows it: each leg's floor and polyline, the seconds of
    each floor change, and the steps."""

    floors: tuple[int, ...]
    legs: tuple[FloatArray, ...]
    change_s: tuple[float, ...]
    steps: tuple[Step, ...]
    walk_speed_m_s: float
    change_kinds: tuple[str, ...] = ()  # per floor change: stairs, elevator ...

    @cached_property
    def leg_lengths(self) -> list[float]:
        return [float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))) for xy in self.legs]

    @cached_property
    def length_m(self) -> float:
        return sum(self.leg_lengths)

    @cached_property
    def leg_starts(self) -> list[float]:
        """How far along the route each leg starts (m)."""
        return [sum(self.leg_lengths[:k]) for k in range(len(self.legs))]

    @cached_property
    def _segments(self) -> list[list[tuple[float, float, float, float, float, float]]]:
        """Per leg, its segments as ``(ax, ay, dx, dy, length², along at a)``."""
        out = []
        for xy in self.legs:
            rows, along = [], 0.0
            for (ax, ay), (bx, by) in zip(xy[:-1].tolist(), xy[1:].tolist(), strict=True):
                dx, dy = bx - ax, by - ay
                rows.append((ax, ay, dx, dy, dx * dx + dy * dy, along))
                along += math.hypot(dx, dy)
            out.append(rows)
        return out

    def place(self, leg: int, x: float, y: float) -> tuple[float, float, tuple[float, float]]:
        """``place`` on leg ``leg``, in plain floating point over its cached segments (a
        fix a batch: numpy's calls on a few points cost more than the arithmetic)."""
        rows = self._segments[leg]
        if not rows:
            px, py = (float(v) for v in self.legs[leg][0])
            return math.hypot(x - px, y - py), 0.0, (px, py)
        best = (math.inf, 0.0, (0.0, 0.0))
        for ax, ay, dx, dy, length2, along in rows:
            t = ((x - ax) * dx + (y - ay) * dy) / length2 if length2 > 0 else 0.0
            t = min(1.0, max(0.0, t))
            px, py = ax + t * dx, ay + t * dy
            gap = math.hypot(x - px, y - py)
            if gap < best[0]:
                best = (gap, along + t * math.sqrt(length2), (px, py))
        return best


@dataclass(frozen=True)
class Progress:
    """Where a walker stands on its route: ``leg`` followed, ``along_m`` walked from the
    route's start, ``step`` the index of the last step passed, the off-route run
    (``off_since_ms`` -1: none) and how many times it was re-routed."""

    leg: int = 0
    along_m: float = 0.0
    step: int = 0
    off_since_ms: int = -1
    off_n: int = 0
    reroutes: int = 0
    arrived: bool = False
    grace_m: float = 0.0  # after a re-route from a fix off the route: as far is on it


@dataclass(frozen=True)
class FixAt:
    t_ms: int
    floor: int
    x_m: float
    y_m: float
    radius_68_m: float | None = None


@dataclass(frozen=True)
class Event:
    kind: str  # "rerouted", "floor_change", "arrived"
    t_ms: int
    detail: dict[str, Any]


@dataclass(frozen=True)
class Report:
    """What one fix says of the navigation (the wire's ``navigation`` object is made of
    it)."""

    progress: Progress
    guide: Guide
    on_route: bool
    off_route_m: float | None
    snapped: tuple[int, float, float]  # floor, x, y on the route
    remaining_m: float
    remaining_s: float
    current: Step
    next: Step | None
    distance_to_next_m: float | None
    withheld: bool
    events: tuple[Event, ...]


def place(xy: FloatArray, point: Sequence[float]) -> tuple[float, float, FloatArray]:
    """The nearest point of a polyline ``xy`` (m, 2) to ``point``: its distance, how far
    along the polyline it lies, and the point."""
    p = np.asarray(point, dtype=np.float64)
    if xy.shape[0] == 1:
        return float(np.linalg.norm(p - xy[0])), 0.0, xy[0].copy()
    a, b = xy[:-1], xy[1:]
    ab = b - a
    length2 = np.sum(ab * ab, axis=1)
    t = np.clip(np.sum((p - a) * ab, axis=1) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    at = a + t[:, None] * ab
    gap = np.linalg.norm(at - p, axis=1)
    k = int(np.argmin(gap))
    seg = np.sqrt(length2)
    along = float(seg[:k].sum() + t[k] * seg[k])
    return float(gap[k]), along, at[k]


def follow(
    guide: Guide,
    progress: Progress,
    fix: FixAt,
    settings: Settings,
    reroute: Callable[[FixAt], Guide | None],
) -> Report:
    """Advance ``progress`` by one fix (module docstring); ``reroute`` makes a new route
    from a fix (None when there is none: the old one is kept, and the off-route run starts
    again, so a failed search is not tried again at every fix)."""
    events: list[Event] = []
    if progress.arrived:  # over: nothing more to say (the service ends it at arrival)
        reroute = _no_reroute
    leg, off, along_leg, at = _leg_of(guide, progress.leg, fix)
    if guide.floors[leg] != guide.floors[progress.leg]:
        detail = {
            "from_floor": guide.floors[progress.leg],
            "to_floor": guide.floors[leg],
            "kind": guide.change_kinds[leg - 1],
        }
        events.append(Event("floor_change", fix.t_ms, detail))
    starts = guide.leg_starts
    if off is None:  # on no leg's floor: where it was
        along_leg = max(0.0, progress.along_m - starts[leg])
    along = float(starts[leg] + along_leg)
    near = off is not None and off <= settings.off_route_m
    on_route = off is not None and off <= max(settings.off_route_m, progress.grace_m)
    off_since, off_n = (-1, 0) if on_route else (
        progress.off_since_ms if progress.off_since_ms >= 0 else fix.t_ms,
        progress.off_n + 1,
    )  # fmt: skip
    grace = 0.0 if near else progress.grace_m
    held = off_since >= 0 and (fix.t_ms - off_since) / 1000.0 >= settings.reroute_after_s
    if held and off_n >= settings.reroute_fixes:
        fresh = reroute(fix)
        if fresh is None:
            off_since, off_n = -1, 0
        else:
            events.append(
                Event(
                    "rerouted",
                    fix.t_ms,
                    {"off_route_m": off, "length_m": fresh.length_m, "off_since": off_since},
                )
            )
            # a fix off walkable space starts the new route where it was snapped to: as
            # far as that, it is on the new route (it is not re-routed again for it)
            gap = fresh.place(0, fix.x_m, fix.y_m)[0] if fix.floor == fresh.floors[0] else 0.0
            restart = Progress(reroutes=progress.reroutes + 1, grace_m=gap + 1.0)
            report = follow(fresh, restart, fix, settings, _no_reroute)
            return replace(report, events=(*events, *report.events))
    last = len(guide.legs) - 1
    remaining = max(0.0, guide.length_m - along)
    arrived = progress.arrived
    if arrived:
        along, remaining = guide.length_m, 0.0
    elif leg == last and off is not None:
        end_x, end_y = guide.legs[last][-1].tolist()
        straight = math.hypot(end_x - fix.x_m, end_y - fix.y_m)
        if straight <= settings.arrival_m or (remaining <= settings.arrival_m and near):
            events.append(Event("arrived", fix.t_ms, {"remaining_m": remaining}))
            arrived, along, remaining = True, guide.length_m, 0.0
    step = _passed(guide.steps, progress.step, leg, along)
    # one Progress made, not replaced field by field (a fix a batch: replace costs more)
    state = Progress(leg, along, step, off_since, off_n, progress.reroutes, arrived, grace)
    nxt = guide.steps[step + 1] if step + 1 < len(guide.steps) and not state.arrived else None
    to_next = max(0.0, nxt.along_m - state.along_m) if nxt is not None else None
    withheld = bool(
        nxt is not None
        and to_next is not None
        and fix.radius_68_m is not None
        and math.isfinite(fix.radius_68_m)
        and fix.radius_68_m > to_next
    )
    changes_left = sum(guide.change_s[leg:]) if not state.arrived else 0.0
    return Report(
        progress=state,
        guide=guide,
        on_route=on_route,
        off_route_m=off,
        snapped=(guide.floors[leg], float(at[0]), float(at[1])),
        remaining_m=remaining,
        remaining_s=remaining / guide.walk_speed_m_s + changes_left,
        current=guide.steps[step],
        next=nxt,
        distance_to_next_m=to_next,
        withheld=withheld,
        events=tuple(events),
    )


LEG_LOOKAHEAD = 2
"""How many legs past the one followed a fix may be placed on (a walker who took two floor
changes between fixes, or a way through on one floor)."""


def _leg_of(
    guide: Guide, leg: int, fix: FixAt
) -> tuple[int, float | None, float, tuple[float, float]]:
    """The leg a fix is on: of the followed one and the next ``LEG_LOOKAHEAD``, the nearest
    on the fix's floor (the earliest of equals); with its distance, how far along it the
    fix lies and its point there. A fix on none of their floors stays on the followed leg
    (distance None)."""
    x0, y0 = guide.legs[leg][0].tolist()
    best: tuple[int, float | None, float, tuple[float, float]] = (leg, None, 0.0, (x0, y0))
    for k in range(leg, min(len(guide.legs), leg + 1 + LEG_LOOKAHEAD)):
        if guide.floors[k] != fix.floor:
            continue
        gap, along, at = guide.place(k, fix.x_m, fix.y_m)
        if best[1] is None or gap < best[1]:
            best = (k, gap, along, at)
    return best


def _no_reroute(_: FixAt) -> Guide | None:
    return None


def _passed(steps: Sequence[Step], passed: int, leg: int, along_m: float) -> int:
    """The last step the walker has passed: on an earlier leg (a floor change is passed
    once the walker is on the next leg), or on its leg at or before where it stands;
    never one before the step it had passed already."""
    found = passed
    for k in range(passed, len(steps)):
        s = steps[k]
        change = s.to_level is not None
        if s.leg < leg or (s.leg == leg and not change and s.along_m <= along_m + 1e-9):
            found = k
        elif s.leg > leg or change:
            break
    return found
