"""Turn-by-turn steps of a route (``routes``): where to turn, which way, and where to take
the stairs, a lift or an escalator.

Each leg's polyline is simplified (Douglas-Peucker, ``SIMPLIFY_M``) so that the few
centimetres a straightened route bends at a door do not read as a turn. At every
remaining corner the change of bearing ``Δ`` (degrees, clockwise positive, in
``(-180, 180]``) gives the instruction:

============  ====================  =============================
``|Δ|``       kind                  text
============  ====================  =============================
< 20          (none: straight on)
20 - 60       ``slight_left/right``  "Bear left"
60 - 120      ``left`` / ``right``   "Turn left"
120 - 165     ``sharp_left/right``   "Turn sharp left"
>= 165        ``uturn``              "Make a U-turn"
============  ====================  =============================

A route starts with ``start`` ("Head north-east"), ends with ``arrive``, and at each floor
change says ``stairs_up`` / ``lift_down`` / ``escalator_up`` ... ("Take the lift up to
level 3"), then ``straight`` for the direction on the new floor. A step's ``distance_m``
is what is walked from the previous step to it; ``along_m`` from the start of the route
(floor changes add no metres); ``bearing_rad`` the direction walked after it, clockwise
from the building's y axis (``None`` at the end).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from server.positioning.plan.routes import Route
from server.positioning.plan.routing_graph import ELEVATOR, ESCALATOR, RAMP, STAIRS

SIMPLIFY_M = 0.5
"""Douglas-Peucker tolerance of a leg before its corners are read (m)."""

MERGE_M = 3.0
"""Bends of a leg closer together than this are one turn (m)."""

STRAIGHT_DEG, SLIGHT_DEG, TURN_DEG, SHARP_DEG = 20.0, 60.0, 120.0, 165.0

_CHANGE_NAMES = {STAIRS: "stairs", ELEVATOR: "lift", ESCALATOR: "escalator", RAMP: "ramp"}
_COMPASS = (
    "north", "north-east", "east", "south-east", "south", "south-west", "west", "north-west",
)  # fmt: skip

TURN_KINDS = (
    "slight_left", "slight_right", "left", "right", "sharp_left", "sharp_right", "uturn",
)  # fmt: skip
CHANGE_KINDS = tuple(
    f"{name}_{way}" for name in ("stairs", "lift", "escalator", "ramp", "traversal")
    for way in ("up", "down")
)  # fmt: skip
KINDS = ("start", "straight", *TURN_KINDS, *CHANGE_KINDS, "arrive")
"""Every instruction kind, as the wire carries it."""


@dataclass(frozen=True)
class Step:
    """One instruction: at ``(x_m, y_m)`` of floor index ``floor``."""

    kind: str
    text: str
    leg: int  # the leg it is on (a floor change: the leg it ends)
    floor: int
    x_m: float
    y_m: float
    distance_m: float  # walked from the previous step
    along_m: float  # walked from the start of the route
    bearing_rad: float | None  # the direction after the step, from the building's y axis
    to_level: int | None = None  # a floor change: the level it ends on


def bearing_rad(dx: float, dy: float) -> float:
    """A direction clockwise from the y axis (north in an unturned building), in [0, 2π)."""
    return math.atan2(dx, dy) % (2 * math.pi)


def compass(bearing_from_north_deg: float) -> str:
    """One of eight winds for a bearing in degrees from north."""
    return _COMPASS[round(bearing_from_north_deg / 45.0) % 8]


def turn_kind(delta_deg: float) -> str | None:
    """The instruction of a change of bearing (module docstring); None: straight on."""
    size = abs(delta_deg)
    side = "right" if delta_deg > 0 else "left"
    if size < STRAIGHT_DEG:
        return None
    if size >= SHARP_DEG:
        return "uturn"
    if size < SLIGHT_DEG:
        return f"slight_{side}"
    if size < TURN_DEG:
        return side
    return f"sharp_{side}"


def _turn_text(kind: str) -> str:
    if kind == "uturn":
        return "Make a U-turn"
    if kind.startswith("slight_"):
        return f"Bear {kind.removeprefix('slight_')}"
    if kind.startswith("sharp_"):
        return f"Turn sharp {kind.removeprefix('sharp_')}"
    return f"Turn {kind}"


def route_steps(
    route: Route,
    levels: Sequence[int],
    rotation_rad: Sequence[float] | float = 0.0,
    destination_name: str | None = None,
) -> list[Step]:
    """The steps of ``route`` (module docstring); ``levels[i]`` is floor index ``i``'s
    level and ``rotation_rad`` its building's bearing (one per floor index, or one for
    all), for the compass words of the text."""
    rotations = (
        [float(rotation_rad)] * len(levels)
        if isinstance(rotation_rad, int | float)
        else [float(r) for r in rotation_rad]
    )
    steps: list[Step] = []
    along = 0.0
    last_along = 0.0
    for k, leg in enumerate(route.legs):
        corners = _corners(leg.xy)
        lengths = np.linalg.norm(np.diff(corners, axis=0), axis=1)
        headings = [bearing_rad(*d) for d in np.diff(corners, axis=0)]
        if not headings and k == 0:  # the route leaves the floor where it starts
            steps.append(
                Step(
                    "start",
                    "Start here",
                    0,
                    leg.floor,
                    float(corners[0, 0]),
                    float(corners[0, 1]),
                    0.0,
                    0.0,
                    None,
                )
            )
        if headings:
            if k == 0:
                first_kind, head_text = "start", "Head"
            else:
                first_kind, head_text = "straight", "Go"
            words = compass(math.degrees(headings[0] + rotations[leg.floor]) % 360.0)
            steps.append(
                Step(
                    first_kind,
                    f"{head_text} {words}",
                    k,
                    leg.floor,
                    float(corners[0, 0]),
                    float(corners[0, 1]),
                    along - last_along,
                    along,
                    headings[0],
                )
            )
            last_along = along
        c = 1
        while c < len(corners) - 1:
            # bends closer together than MERGE_M read as one turn (a corner that a
            # straightened route takes in two)
            e = c
            while e + 1 < len(corners) - 1 and lengths[e] < MERGE_M:
                e += 1
            first, c = c, e + 1
            along_here = along + float(lengths[:first].sum())
            turn = headings[e] - headings[first - 1]
            delta = math.degrees((turn + math.pi) % (2 * math.pi) - math.pi)
            kind = turn_kind(delta)
            if kind is None:
                continue
            steps.append(
                Step(
                    kind,
                    _turn_text(kind),
                    k,
                    leg.floor,
                    float(corners[first, 0]),
                    float(corners[first, 1]),
                    along_here - last_along,
                    along_here,
                    headings[e],
                )
            )
            last_along = along_here
        along += leg.length_m
        end = leg.xy[-1]
        if k < len(route.changes):
            change = route.changes[k]
            to_level = levels[change.to_floor]
            up = to_level > levels[change.from_floor]
            name = _CHANGE_NAMES.get(change.kind, "traversal")
            way = "up" if up else "down"
            the = f"the {change.name}" if change.name else f"the {name}"
            if to_level == levels[change.from_floor]:
                text = f"Go through {the}"
            else:
                text = f"Take {the} {way} to level {to_level}"
            steps.append(
                Step(
                    f"{name}_{way}",
                    text,
                    k,
                    leg.floor,
                    float(end[0]),
                    float(end[1]),
                    along - last_along,
                    along,
                    None,
                    to_level,
                )
            )
            last_along = along
    last = route.legs[-1]
    where = f"Arrive at {destination_name}" if destination_name else "Arrive at your destination"
    steps.append(
        Step(
            "arrive",
            where,
            len(route.legs) - 1,
            last.floor,
            float(last.xy[-1, 0]),
            float(last.xy[-1, 1]),
            along - last_along,
            along,
            None,
        )
    )
    return steps


def _corners(xy: np.ndarray) -> np.ndarray:
    """The leg simplified (module docstring), shape (k, 2); a point for a leg of none."""
    if xy.shape[0] < 3:
        return xy
    line = shapely.LineString(xy).simplify(SIMPLIFY_M, preserve_topology=False)
    return np.asarray(line.coords, dtype=np.float64)
