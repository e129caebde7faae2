"""A seeded synthetic building: floor plans as GeoJSON and a walkable graph per floor.

Every floor is a ``width_m`` x ``depth_m`` rectangle in the building's local metric frame
(x east, y north, metres; origin at the south-west corner) laid out as

- a band of rooms ``room_depth_m`` deep along each outside wall;
- a corridor loop ``corridor_width_m`` wide just inside that band;
- ``side_corridors`` north-south corridors across the block the loop encloses;
- two rows of rooms in each part of that block between side corridors.

Rooms and corridors tile the floor exactly (their areas add up to the floor's), every room
has one door ``door_width_m`` wide onto a straight stretch of corridor, and walls are the
room outlines with a gap at each door plus the building's outline. Room widths and door
positions are drawn from the generator, so each floor of each seed differs.

A staircase and a lift join the floors: the same square on every floor, inside the
corridor loop (the stairs at the south end of the west corridor, the lift at the north end
of the east one), 2 m on a side (``_SHAFT_M``; the corridor's width if that is less). They
lie in corridor area, so they change neither the walkable area nor the walls; the plan
marks them as ``"stairs"`` and ``"elevator"`` features with an ``id`` and a ``name`` shared
by all floors. The walkable graph stays on each floor.

The walkable graph has nodes on the corridor centre-lines (loop corners, junctions with
side corridors, the foot of each door), at each door, one metre inside each door, and at
each room's centre; edges run along centre-lines and from a corridor through its door to
the room's centre, so a walk along edges never crosses a wall.

Only numpy; randomness through an ``rng: numpy.random.Generator`` argument.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

Use = Literal["room", "corridor"]

_DOOR_MARGIN_M = 0.3  # between a door's jamb and the corner of its room
_MIN_FACING_M = 3.0  # the least stretch of wall a room shares with its corridor
_INSIDE_M = 1.0  # the graph node just inside a door
_SHAFT_M = 2.0  # side of the stairs' and the lift's squares
_DECIMALS = 3  # coordinates on the wire: millimetres


@dataclass(frozen=True, slots=True)
class Rect:
    """An axis-aligned walkable rectangle ``[x0, x1] x [y0, y1]`` in metres."""

    x0: float
    y0: float
    x1: float
    y1: float
    use: Use

    @property
    def area_m2(self) -> float:
        return (self.x1 - self.x0) * (self.y1 - self.y0)

    @property
    def centre(self) -> tuple[float, float]:
        return ((self.x0 + self.x1) / 2.0, (self.y0 + self.y1) / 2.0)

    def ring(self) -> list[list[float]]:
        """The outline as a closed GeoJSON linear ring, counter-clockwise."""
        corners = [
            (self.x0, self.y0),
            (self.x1, self.y0),
            (self.x1, self.y1),
            (self.x0, self.y1),
            (self.x0, self.y0),
        ]
        return [[round(x, _DECIMALS), round(y, _DECIMALS)] for x, y in corners]


@dataclass(frozen=True, slots=True)
class Shaft:
    """A way between floors, the same square on every floor: the stairs or the lift."""

    id: str
    kind: Literal["stairs", "elevator"]
    name: str
    rect: Rect  # inside a corridor


@dataclass(frozen=True, eq=False)
class Floor:
    """One floor: walkable rectangles, walls, doors and the walkable graph.

    Attributes
    ----------
    level : int
        Floor level as on the wire.
    walkable : tuple of Rect
        Rooms and corridors; they tile the floor rectangle.
    walls : ndarray, shape (n_walls, 2, 2)
        Wall segments ``[[x0, y0], [x1, y1]]``; the first four are the outline's sides.
    outline : ndarray, shape (5, 2)
        The floor's outside wall as a closed ring.
    doors : ndarray, shape (n_doors, 2)
        Door centres, each on a wall line in the middle of a gap ``door_width_m`` wide.
    nodes : ndarray, shape (n_nodes, 2)
        Walkable graph nodes.
    edges : ndarray, shape (n_edges, 2)
        Node index pairs, each edge once.
    shafts : tuple of Shaft
        The stairs and the lift, at the same place on every floor.
    """

    level: int
    walkable: tuple[Rect, ...]
    walls: FloatArray
    outline: FloatArray
    doors: FloatArray
    door_width_m: float
    nodes: FloatArray
    edges: IntArray
    shafts: tuple[Shaft, ...] = ()

    @property
    def edge_lengths_m(self) -> FloatArray:
        """Length of each edge, shape (n_edges,)."""
        d = self.nodes[self.edges[:, 1]] - self.nodes[self.edges[:, 0]]
        lengths: FloatArray = np.hypot(d[:, 0], d[:, 1])
        return lengths

    def neighbours(self) -> list[list[int]]:
        """Adjacency lists of the walkable graph."""
        adjacency: list[list[int]] = [[] for _ in range(len(self.nodes))]
        for a, b in self.edges.tolist():
            adjacency[a].append(b)
            adjacency[b].append(a)
        return adjacency

    def contains(self, points: FloatArray, tol_m: float = 1e-9) -> NDArray[np.bool_]:
        """Whether each point, shape (n, 2), lies on a walkable rectangle."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        box = np.array([[r.x0, r.y0, r.x1, r.y1] for r in self.walkable])
        inside = (
            (p[:, None, 0] >= box[None, :, 0] - tol_m)
            & (p[:, None, 0] <= box[None, :, 2] + tol_m)
            & (p[:, None, 1] >= box[None, :, 1] - tol_m)
            & (p[:, None, 1] <= box[None, :, 3] + tol_m)
        )
        result: NDArray[np.bool_] = np.asarray(np.any(inside, axis=1), dtype=np.bool_)
        return result

    def wall_distance_m(self, points: FloatArray) -> FloatArray:
        """Distance from each point, shape (n, 2), to the nearest wall, shape (n,)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        a, ab = self.walls[:, 0, :], self.walls[:, 1, :] - self.walls[:, 0, :]
        ab2 = np.maximum(np.einsum("wd,wd->w", ab, ab), 1e-12)
        px = p[:, 0:1] - a[None, :, 0]  # (n, n_walls)
        py = p[:, 1:2] - a[None, :, 1]
        dot = px * ab[None, :, 0] + py * ab[None, :, 1]
        u = np.clip(dot / ab2, 0.0, 1.0)
        dx = px - u * ab[None, :, 0]
        dy = py - u * ab[None, :, 1]
        d: FloatArray = np.sqrt((dx * dx + dy * dy).min(axis=1))
        return d

    def walkable_grid(self, spacing_m: float, wall_clearance_m: float = 0.25) -> FloatArray:
        """Points on a square grid, ``spacing_m`` apart, on walkable ground at least
        ``wall_clearance_m`` from any wall, shape (n, 2)."""
        x0, y0 = self.outline.min(axis=0)
        x1, y1 = self.outline.max(axis=0)
        xs = np.arange(x0 + spacing_m / 2.0, x1, spacing_m)
        ys = np.arange(y0 + spacing_m / 2.0, y1, spacing_m)
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        grid = np.column_stack([gx.ravel(), gy.ravel()])
        keep = self.contains(grid) & (self.wall_distance_m(grid) >= wall_clearance_m)
        points: FloatArray = grid[keep]
        return points

    def door_openings(self) -> FloatArray:
        """Each door's gap as a segment along its wall line, shape (n_doors, 2, 2): the
        walls end half a door width either side of the centre, along x or along y."""
        ends = self.walls.reshape(-1, 2)
        half = self.door_width_m / 2.0
        out = np.empty((len(self.doors), 2, 2), dtype=np.float64)
        for i, centre in enumerate(self.doors):
            for axis in (np.array([half, 0.0]), np.array([0.0, half])):
                if np.min(np.hypot(*(ends - (centre + axis)).T)) < 1e-6:
                    out[i] = (centre - axis, centre + axis)
                    break
            else:
                raise ValueError(f"door at {centre.tolist()} has no wall ending beside it")
        return out

    def plan_geojson(self) -> dict[str, Any]:
        """The floor plan as a GeoJSON FeatureCollection in the local metric frame.

        Features carry ``properties.kind``: ``"walkable"`` Polygons (with ``use`` room or
        corridor), ``"wall"`` LineStrings (the outline as one closed ring), ``"door"``
        LineStrings: each door's opening, ``door_width_m`` long, lying on its wall line
        across the gap the walls leave for it (with ``width_m``), and a ``"stairs"`` and
        an ``"elevator"`` Polygon (with ``id`` and ``name``, the same on every floor).
        """
        features: list[dict[str, Any]] = []
        for i, rect in enumerate(self.walkable):
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "Polygon", "coordinates": [rect.ring()]},
                    "properties": {"kind": "walkable", "use": rect.use, "name": f"{rect.use}-{i}"},
                }
            )
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": _coords(self.outline)},
                "properties": {"kind": "wall", "name": "outline"},
            }
        )
        for segment in self.walls[4:]:
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "LineString", "coordinates": _coords(segment)},
                    "properties": {"kind": "wall"},
                }
            )
        for opening in self.door_openings():
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "LineString", "coordinates": _coords(opening)},
                    "properties": {"kind": "door", "width_m": self.door_width_m},
                }
            )
        for shaft in self.shafts:
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "Polygon", "coordinates": [shaft.rect.ring()]},
                    "properties": {"kind": shaft.kind, "name": shaft.name, "id": shaft.id},
                }
            )
        return {
            "type": "FeatureCollection",
            "properties": {"level": self.level, "frame": "local", "units": "m"},
            "features": features,
        }


@dataclass(frozen=True, eq=False)
class SyntheticBuilding:
    """Floors of one synthetic building, lowest level first."""

    width_m: float
    depth_m: float
    floors: tuple[Floor, ...]

    @property
    def levels(self) -> tuple[int, ...]:
        return tuple(f.level for f in self.floors)

    def floor(self, level: int) -> Floor:
        for f in self.floors:
            if f.level == level:
                return f
        raise KeyError(f"no floor at level {level}")


def synthesize_building(
    rng: np.random.Generator,
    *,
    width_m: float = 60.0,
    depth_m: float = 30.0,
    levels: tuple[int, ...] = (0, 1),
    room_depth_m: float = 6.0,
    corridor_width_m: float = 2.0,
    side_corridors: int = 2,
    room_width_m: float = 7.0,
    door_width_m: float = 1.0,
) -> SyntheticBuilding:
    """Draw a building with the layout of the module docstring, one plan per level."""
    d, cw = room_depth_m, corridor_width_m
    inner_w, inner_h = width_m - 2 * (d + cw), depth_m - 2 * (d + cw)
    if min(d, cw, door_width_m) <= 0 or len(levels) == 0 or len(set(levels)) != len(levels):
        raise ValueError("sizes must be positive and levels distinct and non-empty")
    if door_width_m + 2 * _DOOR_MARGIN_M > _MIN_FACING_M * 0.6 or d < 2 * _INSIDE_M:
        raise ValueError("doors too wide or rooms too shallow")
    if inner_h < 2 * _MIN_FACING_M or inner_w < (side_corridors + 1) * (cw + _MIN_FACING_M):
        raise ValueError(
            f"a {width_m} x {depth_m} m floor leaves no room for {side_corridors} side "
            "corridors and two rows of rooms inside the corridor loop"
        )
    floors = tuple(
        _floor(rng, level, width_m, depth_m, d, cw, side_corridors, room_width_m, door_width_m)
        for level in sorted(levels)
    )
    return SyntheticBuilding(width_m=width_m, depth_m=depth_m, floors=floors)


# ---------------------------------------------------------------- layout


@dataclass(frozen=True)
class _Room:
    rect: Rect
    door: tuple[float, float]
    inward: tuple[float, float]  # unit normal from the door into the room
    foot: tuple[float, float]  # where the door's axis meets the corridor centre-line


def _floor(
    rng: np.random.Generator,
    level: int,
    W: float,
    H: float,
    d: float,
    cw: float,
    n_side: int,
    room_w: float,
    door_w: float,
) -> Floor:
    c_lo, c_hi = d + cw / 2.0, H - d - cw / 2.0  # loop centre-lines, south and north
    c_west, c_east = d + cw / 2.0, W - d - cw / 2.0
    rooms: list[_Room] = []

    half = door_w / 2.0 + _DOOR_MARGIN_M

    def band(
        lo: float, hi: float, face_lo: float, face_hi: float, make: Callable[..., _Room]
    ) -> None:
        bounds = _split(rng, lo, hi, face_lo, face_hi, room_w)
        for a, b in itertools.pairwise(bounds):
            f0, f1 = max(a, face_lo), min(b, face_hi)
            rooms.append(make(a, b, float(rng.uniform(f0 + half, f1 - half))))

    # outer bands: south and north span the whole width, west and east fill in between
    def south(a: float, b: float, x: float) -> _Room:
        return _Room(Rect(a, 0.0, b, d, "room"), (x, d), (0.0, -1.0), (x, c_lo))

    def north(a: float, b: float, x: float) -> _Room:
        return _Room(Rect(a, H - d, b, H, "room"), (x, H - d), (0.0, 1.0), (x, c_hi))

    def west(a: float, b: float, y: float) -> _Room:
        return _Room(Rect(0.0, a, d, b, "room"), (d, y), (-1.0, 0.0), (c_west, y))

    def east(a: float, b: float, y: float) -> _Room:
        return _Room(Rect(W - d, a, W, b, "room"), (W - d, y), (1.0, 0.0), (c_east, y))

    band(0.0, W, d + cw, W - d - cw, south)
    band(0.0, W, d + cw, W - d - cw, north)
    band(d, H - d, d + cw, H - d - cw, west)
    band(d, H - d, d + cw, H - d - cw, east)

    # side corridors, evenly spread with jitter, and the blocks of rooms between them
    x_lo, x_hi = d + cw, W - d - cw
    y_lo, y_hi = d + cw, H - d - cw
    y_mid = (y_lo + y_hi) / 2.0
    pitch = (x_hi - x_lo) / (n_side + 1)
    jitter = max(0.0, (pitch - cw - _MIN_FACING_M) / 2.0) * 0.5
    side_x = [x_lo + (i + 1) * pitch + float(rng.uniform(-jitter, jitter)) for i in range(n_side)]
    corridors = [
        Rect(d, d, W - d, d + cw, "corridor"),
        Rect(d, H - d - cw, W - d, H - d, "corridor"),
        Rect(d, d + cw, d + cw, H - d - cw, "corridor"),
        Rect(W - d - cw, d + cw, W - d, H - d - cw, "corridor"),
        *(Rect(s - cw / 2.0, y_lo, s + cw / 2.0, y_hi, "corridor") for s in side_x),
    ]
    edges_x = [x_lo, *(v for s in side_x for v in (s - cw / 2.0, s + cw / 2.0)), x_hi]
    for a_blk, b_blk in zip(edges_x[0::2], edges_x[1::2], strict=True):
        bounds = _split(rng, a_blk, b_blk, a_blk, b_blk, room_w)
        for a, b in itertools.pairwise(bounds):
            xs = rng.uniform(a + half, b - half, size=2)
            x_s, x_n = float(xs[0]), float(xs[1])
            rooms.append(
                _Room(Rect(a, y_lo, b, y_mid, "room"), (x_s, y_lo), (0.0, 1.0), (x_s, c_lo))
            )
            rooms.append(
                _Room(Rect(a, y_mid, b, y_hi, "room"), (x_n, y_hi), (0.0, -1.0), (x_n, c_hi))
            )

    outline = np.array([[0.0, 0.0], [W, 0.0], [W, H], [0.0, H], [0.0, 0.0]])
    walls = _walls(outline, rooms, door_w)
    nodes, edges = _graph(rooms, side_x, c_lo, c_hi, c_west, c_east)
    s = min(_SHAFT_M, cw)  # squares across the corridor, at the ends of its straight stretch
    shafts = (
        Shaft(
            "stairs-1",
            "stairs",
            "Stairs",
            Rect(c_west - s / 2, y_lo, c_west + s / 2, y_lo + s, "corridor"),
        ),
        Shaft(
            "lift-1",
            "elevator",
            "Lift",
            Rect(c_east - s / 2, y_hi - s, c_east + s / 2, y_hi, "corridor"),
        ),
    )
    return Floor(
        level=level,
        walkable=(*corridors, *(r.rect for r in rooms)),
        walls=walls,
        outline=outline,
        doors=np.array([r.door for r in rooms], dtype=np.float64),
        door_width_m=door_w,
        nodes=nodes,
        edges=edges,
        shafts=shafts,
    )


def _split(
    rng: np.random.Generator,
    lo: float,
    hi: float,
    face_lo: float,
    face_hi: float,
    room_w: float,
) -> list[float]:
    """Boundaries ``lo < b1 < ... < hi`` of rooms about ``room_w`` wide, each sharing at
    least ``0.6 * _MIN_FACING_M`` of its side with ``[face_lo, face_hi]``."""
    f0, f1 = max(lo, face_lo), min(hi, face_hi)
    k = int(np.clip(round((hi - lo) / room_w), 1, max(1, int((f1 - f0) // _MIN_FACING_M))))
    pitch = (f1 - f0) / k
    inner = f0 + pitch * np.arange(1, k) + rng.uniform(-0.2, 0.2, size=k - 1) * pitch
    return [lo, *(float(b) for b in inner), hi]


def _walls(outline: FloatArray, rooms: list[_Room], door_w: float) -> FloatArray:
    """The outline's four sides, then every room side not on the outline, with a gap at
    the door; shared sides once."""
    W, H = outline.max(axis=0)
    segments: list[tuple[float, float, float, float]] = [
        (float(a[0]), float(a[1]), float(b[0]), float(b[1])) for a, b in itertools.pairwise(outline)
    ]
    seen: set[tuple[float, float, float, float]] = set()

    def add(x0: float, y0: float, x1: float, y1: float) -> None:
        if (x0 == x1 and x0 in (0.0, W)) or (y0 == y1 and y0 in (0.0, H)):
            return  # on the outline
        ends = sorted([(round(x0, 9), round(y0, 9)), (round(x1, 9), round(y1, 9))])
        key = (*ends[0], *ends[1])
        if key not in seen:
            seen.add(key)
            segments.append((x0, y0, x1, y1))

    for room in rooms:
        r = room.rect
        dx, dy = room.door
        half = door_w / 2.0
        for x0, y0, x1, y1 in (
            (r.x0, r.y0, r.x1, r.y0),
            (r.x1, r.y0, r.x1, r.y1),
            (r.x0, r.y1, r.x1, r.y1),
            (r.x0, r.y0, r.x0, r.y1),
        ):
            if y0 == y1 == dy and x0 < dx < x1:
                add(x0, y0, dx - half, y0)
                add(dx + half, y0, x1, y0)
            elif x0 == x1 == dx and y0 < dy < y1:
                add(x0, y0, x0, dy - half)
                add(x0, dy + half, x0, y1)
            else:
                add(x0, y0, x1, y1)
    return np.array(segments, dtype=np.float64).reshape(-1, 2, 2)


def _graph(
    rooms: list[_Room],
    side_x: list[float],
    c_lo: float,
    c_hi: float,
    c_west: float,
    c_east: float,
) -> tuple[FloatArray, IntArray]:
    nodes: list[tuple[float, float]] = []
    index: dict[tuple[float, float], int] = {}
    edges: set[tuple[int, int]] = set()

    def node(p: tuple[float, float]) -> int:
        key = (round(p[0], 9), round(p[1], 9))
        if key not in index:
            index[key] = len(nodes)
            nodes.append(key)
        return index[key]

    def edge(a: int, b: int) -> None:
        if a != b:
            edges.add((min(a, b), max(a, b)))

    corners = [(c_west, c_lo), (c_east, c_lo), (c_east, c_hi), (c_west, c_hi)]
    # centre-lines as (start, end); every node on one is chained along it in order
    lines = [
        (corners[0], corners[1]),
        (corners[3], corners[2]),
        (corners[0], corners[3]),
        (corners[1], corners[2]),
        *(((s, c_lo), (s, c_hi)) for s in side_x),
    ]
    on_line: list[list[int]] = [[node(a), node(b)] for a, b in lines]
    for s in side_x:  # junctions of side corridors with the loop
        on_line[0].append(node((s, c_lo)))
        on_line[1].append(node((s, c_hi)))
    for room in rooms:
        foot = node(room.foot)
        for i, (a, b) in enumerate(lines):
            if _on_segment(room.foot, a, b):
                on_line[i].append(foot)
                break
        else:  # pragma: no cover - the layout puts every door foot on a centre-line
            raise AssertionError(f"door foot {room.foot} is on no corridor")
        door = node(room.door)
        inside = node(
            (room.door[0] + _INSIDE_M * room.inward[0], room.door[1] + _INSIDE_M * room.inward[1])
        )
        centre = node(room.rect.centre)
        edge(foot, door)
        edge(door, inside)
        edge(inside, centre)
    xy = np.array(nodes, dtype=np.float64)
    for (a, b), members in zip(lines, on_line, strict=True):
        direction = np.subtract(b, a)
        order = sorted(set(members), key=lambda n: float(np.dot(xy[n] - a, direction)))
        for p, q in itertools.pairwise(order):
            edge(p, q)
    return xy, np.array(sorted(edges), dtype=np.int64).reshape(-1, 2)


def _on_segment(
    p: tuple[float, float], a: tuple[float, float], b: tuple[float, float], tol: float = 1e-9
) -> bool:
    ab = np.subtract(b, a)
    ap = np.subtract(p, a)
    cross = ab[0] * ap[1] - ab[1] * ap[0]
    u = float(np.dot(ap, ab) / np.dot(ab, ab))
    return abs(cross) <= tol * float(np.dot(ab, ab)) and -tol <= u <= 1.0 + tol


def _coords(a: FloatArray) -> Any:
    return np.round(np.asarray(a, dtype=np.float64), _DECIMALS).tolist()


def count_crossings(p0: FloatArray, p1: FloatArray, walls: FloatArray) -> IntArray:
    """How many walls each segment ``p0 -> p1`` crosses properly (touching does not count).

    Parameters
    ----------
    p0, p1 : ndarray, shape (..., 2)
        Segment ends; the leading shapes broadcast against each other.
    walls : ndarray, shape (n_walls, 2, 2)

    Returns
    -------
    ndarray of int, shape of the broadcast leading dimensions
    """
    p = np.asarray(p0, dtype=np.float64)[..., None, :]
    q = np.asarray(p1, dtype=np.float64)[..., None, :]
    a, b = walls[:, 0, :], walls[:, 1, :]

    def cross(u: FloatArray, v: FloatArray) -> FloatArray:
        out: FloatArray = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
        return out

    pq = q - p
    ab = b - a
    o1 = cross(pq, a - p)
    o2 = cross(pq, b - p)
    o3 = cross(ab, p - a)
    o4 = cross(ab, q - a)
    hits = (o1 * o2 < 0) & (o3 * o4 < 0)
    counts: IntArray = hits.sum(axis=-1).astype(np.int64)
    return counts
