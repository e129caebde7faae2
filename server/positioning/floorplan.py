"""Floor plans: a walkable raster and an exact wall-crossing test for particle moves.

The map constraint of the particle filter (``papers/001_*`` section III-B and III-D:
"particles outside reachable areas are removed according to the floor plan", "users have
no possibility to walk through a wall"): a particle moved from ``a`` to ``b`` survives
when ``b`` is reachable and the segment ``a -> b`` meets no wall.

Plan format. A floor plan is a GeoJSON FeatureCollection in metres of the floor frame
(x east, y north). Each feature's ``properties.kind`` says what it is:

==========================  ==================================================================
``"walkable"``              Polygon / MultiPolygon of floor area people may stand on
``"outline"``               the same (ILC: the floor outline, see below)
``"wall"``                  LineString / MultiLineString: a thin wall; Polygon /
                            MultiPolygon: a solid block (thick wall, pillar, closed room)
``"unit"``, ``"obstacle"``  the same as ``"wall"`` (ILC: a shop or room)
``"door"``                  Polygon: an opening area; LineString: an opening lying on a wall
                            (grown by ``DOOR_SNAP_M`` across it, flat ends)
==========================  ==================================================================

Features of any other kind (anchors, entrances, beacons ...) or without a kind are
ignored. With ``D`` the union of the door areas, the walkable area is::

    W = union(walkable) - (union(solid blocks) - D)

and the wall segments are the edges of the boundary of ``W`` together with the thin walls
minus ``D``. Adjacent walkable polygons merge into one area: rooms are kept apart by walls
drawn between them, with doors cutting gaps in those walls.

ILC plans (``server.datasets.ilc.plan_to_metres``) carry one ``"outline"`` feature (the
floor) and ``"unit"`` features (shops, rooms): the walkable area is the outline minus the
units, i.e. the corridors and halls of the mall. People are followed in the corridors
only: on site2 of the ILC 2.0 sample, all 3,054 waypoints of all 417 traces lie inside
that area and in walkable raster cells (0.25 m), though 15 of them are less than 0.25 m
from a wall (the closest 0.012 m).

Raster. ``walkable[iy, ix]`` covers the square ``[x0 + ix c, x0 + (ix + 1) c) x
[y0 + iy c, y0 + (iy + 1) c)`` with ``(x0, y0) = origin_m`` and ``c = cell_m``; a cell is
walkable when its centre lies inside ``W`` (boundary excluded). The origin is a multiple
of ``cell_m``, so the rasters of floors that share a frame share their cells.

Moves. A move ``a -> b`` (a closed segment) crosses a wall when it has any point in common
with a wall segment: crossing, touching at an end, running along it. A move is valid when
``b`` is in a walkable cell and the move crosses no wall. The crossing test is exact (up
to the rounding of the orientation tests, about 1e-12 m), so a particle that starts
inside ``W`` and makes valid moves only stays inside ``W`` forever: to leave it, a move
would have to meet the boundary of ``W``, whose edges are wall segments. The raster is a
further check on ``b`` that can only refuse moves, up to half a cell diagonal from the
boundary.

Wall index. Testing every move against every wall is ``n x m`` work (3,000 particles
against 1,617 segments on site2/B1). The walls are bucketed once per plan in a
uniform grid of ``WALL_BUCKET_M`` squares; bucket ``(i, j)`` lists the walls that may meet
the square grown by ``WALL_REACH_M`` to the right and up. A move whose extent is at most
``WALL_REACH_M`` along x and along y is then tested only against the walls listed for the
bucket holding its lower-left bounding-box corner; a longer move is cut into such pieces
first. Of a piece's candidate walls, only those whose bounding box meets the piece's go
through the segment intersection test, the orientation (cross-product) test vectorised
over the remaining (piece, wall) pairs.

Clearance raster. Most moves are far from every wall; a raster computed once per plan
spares them the index. Every cell a wall may touch is marked (walls cut into pieces at
most half a cell long, each marking the 2 x 2 cells its bounding box can reach), and so is
a ring of cells around the raster, standing for everything beyond it. Grown by one cell
all round, the marked set's Euclidean distance transform (``scipy.ndimage``, in cells)
at a cell's centre is the gap between that cell's square and the nearest marked square,
so no point of the cell is nearer to a wall. It is stored per cell in ``1 /
CLEARANCE_STEPS`` of a cell, rounded down (uint8), and ``CLEARANCE_MARGIN_M`` is taken
off when it is used. A move shorter than the clearance of its start's cell cannot meet
a wall and is not tested further. Both filters skip only pairs that provably share no
point, so a move gets the orientation test's answer against all the walls. On site2/B1
(1,386 x 1,217 cells) the raster takes 1.7 MB and ~0.13 s to build (the plan ~0.6 s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage
from shapely.geometry.base import BaseGeometry

FloatArray = NDArray[np.float64]

CELL_M = 0.25
"""Default raster cell side (m)."""

DOOR_SNAP_M = 0.05
"""Half-thickness given to a door LineString so that it cuts the wall it lies on (m)."""

WALL_BUCKET_M = 0.5
"""Side of the wall-index buckets (m)."""

WALL_REACH_M = 1.0
"""Largest x and y extent of a move tested in one index lookup (m); longer moves are
cut into pieces. Steps of a walker are shorter, so one lookup serves almost every move."""

CLEARANCE_STEPS = 8
"""Clearances are stored in whole ``1 / CLEARANCE_STEPS`` of a cell, rounded down (uint8)."""

CLEARANCE_MARGIN_M = 1e-6
"""Taken off every clearance: far more than the rounding of any coordinate, cell index or
squared length involved, far less than any step."""

_WALKABLE_KINDS = frozenset({"walkable", "outline"})
_BARRIER_KINDS = frozenset({"wall", "unit", "obstacle"})
_DOOR_KINDS = frozenset({"door"})
_RANDOM_POINT_ROUNDS = 64  # redraws in random_walkable_points before the fallback


@dataclass(frozen=True, eq=False)
class _WallIndex:
    """Walls bucketed in a uniform grid (CSR lists; see the module docstring).

    ``origin_m`` is the lower-left corner of bucket ``(0, 0)``; bucket ``(iy, ix)`` is
    number ``iy * nx + ix`` and its walls are ``walls[start[k]:start[k + 1]]``.
    """

    origin_m: tuple[float, float]
    bucket_m: float
    reach_m: float
    nx: int
    ny: int
    start: NDArray[np.intp]  # (nx * ny + 1,)
    walls: NDArray[np.intp]  # (n_entries,) rows of FloorPlan.walls
    # per entry: the wall [x1, y1, x2, y2] and its bounding box [x_min, y_min, x_max, y_max]
    segments: FloatArray  # (n_entries, 8)


@dataclass(frozen=True, eq=False)
class FloorPlan:
    """A floor's walkable raster and wall segments, in metres of the floor frame.

    Attributes
    ----------
    origin_m : tuple of float
        ``(x, y)`` of the lower-left corner of cell ``(0, 0)``.
    cell_m : float
        Side of a raster cell.
    walkable : ndarray, shape (ny, nx), bool
        Raster of the walkable area; row ``iy`` is the ``iy``-th cell along y.
    walls : ndarray, shape (m, 4), float64
        Wall segments ``[x1, y1, x2, y2]``: the boundary of the walkable area and the thin
        walls (door gaps cut out).

    The four fields are the whole plan (a plan is rebuilt from them); the wall index and
    the clearance raster used by ``crosses_wall`` are derived from them on construction.
    """

    origin_m: tuple[float, float]
    cell_m: float
    walkable: NDArray[np.bool_]
    walls: FloatArray
    _index: _WallIndex = field(init=False, repr=False)
    _clearance: NDArray[np.uint8] = field(init=False, repr=False)  # (ny * nx,)
    _clear_below: FloatArray = field(init=False, repr=False)  # (256,) squared lengths (m^2)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cell_m) and self.cell_m > 0):
            raise ValueError(f"cell_m must be positive, not {self.cell_m}")
        if self.walkable.ndim != 2 or self.walkable.dtype != np.bool_:
            raise ValueError(f"walkable must be a 2-D bool array, not {self.walkable.dtype}")
        if self.walls.ndim != 2 or self.walls.shape[1] != 4:
            raise ValueError(f"walls must have shape (m, 4), not {self.walls.shape}")
        # a derived cache on a frozen instance: the documented idiom for __post_init__
        object.__setattr__(self, "_index", _build_index(self.walls, WALL_BUCKET_M, WALL_REACH_M))
        object.__setattr__(self, "_clearance", _clearance(self).ravel())
        steps = np.arange(256) * (self.cell_m / CLEARANCE_STEPS) - CLEARANCE_MARGIN_M
        object.__setattr__(self, "_clear_below", np.maximum(steps, 0.0) ** 2)


def plan_from_geojson(geojson: Mapping[str, Any], cell_m: float = CELL_M) -> FloorPlan:
    """Build a floor plan from a GeoJSON FeatureCollection in metres.

    Parameters
    ----------
    geojson : mapping
        FeatureCollection whose features carry ``properties.kind`` (module docstring).
    cell_m : float
        Raster cell side (m).

    Returns
    -------
    FloorPlan

    Raises
    ------
    ValueError
        No walkable polygon, a feature whose geometry does not fit its kind (the message
        gives the feature's index), an empty walkable area or a bad ``cell_m``.
    """
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be positive, not {cell_m}")
    walkable: list[BaseGeometry] = []
    solids: list[BaseGeometry] = []
    thin: list[BaseGeometry] = []
    doors: list[BaseGeometry] = []
    for index, feature in enumerate(geojson.get("features") or ()):
        if not isinstance(feature, Mapping):
            raise ValueError(f"feature {index}: not a GeoJSON feature")
        kind = _kind(feature)
        if not isinstance(kind, str) or kind not in _WALKABLE_KINDS | _BARRIER_KINDS | _DOOR_KINDS:
            continue
        try:
            geometry = shapely.geometry.shape(feature["geometry"])
        except (KeyError, TypeError, ValueError, AttributeError, shapely.errors.ShapelyError):
            raise ValueError(f"feature {index} ({kind}): not a GeoJSON geometry") from None
        dim = shapely.get_dimensions(geometry)
        if geometry.is_empty:
            continue
        if kind in _WALKABLE_KINDS and dim == 2:
            walkable += _polygons(geometry)
        elif kind in _BARRIER_KINDS and dim == 2:
            solids += _polygons(geometry)
        elif kind in _BARRIER_KINDS and dim == 1:
            thin.append(geometry)
        elif kind in _DOOR_KINDS and dim == 2:
            doors += _polygons(geometry)
        elif kind in _DOOR_KINDS and dim == 1:
            doors.append(shapely.buffer(geometry, DOOR_SNAP_M, cap_style="flat"))
        else:
            raise ValueError(f"feature {index} ({kind}): unexpected {geometry.geom_type}")
    if not walkable:
        raise ValueError(
            "no walkable polygon (features with properties.kind 'walkable' or 'outline')"
        )
    door_area = shapely.union_all(doors)
    area = shapely.difference(
        shapely.union_all(walkable), shapely.difference(shapely.union_all(solids), door_area)
    )
    if area.is_empty or area.area <= 0:
        raise ValueError("the walkable area is empty")
    walls = np.concatenate(
        [
            _segments(area.boundary),
            _segments(shapely.difference(shapely.union_all(thin), door_area)),
        ]
    )
    return FloorPlan(*_raster(area, cell_m), walls=walls)


def _kind(feature: Mapping[str, Any]) -> Any:
    """A feature's ``properties.kind``; None when its properties are not an object."""
    properties = feature.get("properties")
    return properties.get("kind") if isinstance(properties, Mapping) else None


PLAN_MARGIN_M = 10.0
"""How far outside its plan's walkable extent a sample may lie and still be used (a
wrong anchor or a typo must not stretch a floor's maps across a city)."""


def plan_extent(geojson: Mapping[str, Any] | None) -> tuple[float, float, float, float] | None:
    """``(x0, y0, x1, y1)``: the bounding box of a plan's walkable features (what
    ``plan_from_geojson`` builds the walkable area from), without rasterising; None when
    the plan has none or they are not readable geometries."""
    boxes = []
    for feature in (geojson or {}).get("features") or ():
        if not isinstance(feature, Mapping):
            continue
        if _kind(feature) not in _WALKABLE_KINDS:
            continue
        try:
            geometry = shapely.geometry.shape(feature["geometry"])
        except (KeyError, TypeError, ValueError, AttributeError, shapely.errors.ShapelyError):
            continue
        if not geometry.is_empty:
            boxes.append(geometry.bounds)
    if not boxes:
        return None
    b = np.array(boxes, dtype=np.float64)
    return float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())


def walkable_at(plan: FloorPlan, xy: ArrayLike) -> NDArray[np.bool_]:
    """Whether points fall in walkable cells.

    Parameters
    ----------
    plan : FloorPlan
    xy : array_like, shape (n, 2)
        Points (m).

    Returns
    -------
    ndarray, shape (n,), bool
        False outside the raster and for non-finite points.
    """
    xy = _points(xy)
    cell, inside = _cells(plan, xy)
    out: NDArray[np.bool_] = plan.walkable.ravel()[cell]
    out &= inside
    return out


def crosses_wall(plan: FloorPlan, a: ArrayLike, b: ArrayLike) -> NDArray[np.bool_]:
    """Whether the moves ``a -> b`` meet any wall segment (closed segments).

    Parameters
    ----------
    plan : FloorPlan
    a, b : array_like, shape (n, 2)
        Start and end points (m).

    Returns
    -------
    ndarray, shape (n,), bool
        True when the segment crosses, touches or runs along a wall; True for a move with
        a non-finite coordinate.
    """
    a, b = _points(a), _points(b)
    if a.shape != b.shape:
        raise ValueError(f"a and b differ in shape: {a.shape} and {b.shape}")
    return _crossing(plan, a, b)


def valid_moves(plan: FloorPlan, a: ArrayLike, b: ArrayLike) -> NDArray[np.bool_]:
    """``walkable_at(plan, b) & ~crosses_wall(plan, a, b)``, shape (n,)."""
    a, b = _points(a), _points(b)
    if a.shape != b.shape:
        raise ValueError(f"a and b differ in shape: {a.shape} and {b.shape}")
    ok = walkable_at(plan, b)
    if ok.all():  # only the moves that end in walkable cells need the crossing test
        ok = ~_crossing(plan, a, b)
    elif ok.any():
        rows = np.flatnonzero(ok)
        ok[rows] = ~_crossing(plan, a[rows], b[rows])
    return ok


def random_walkable_points(
    plan: FloorPlan,
    n: int,
    rng: np.random.Generator,
    centre: ArrayLike | None = None,
    radius_m: float | None = None,
) -> FloatArray:
    """Points drawn uniformly over the walkable cells, optionally within a disc.

    A draw picks a walkable cell uniformly, then a point uniformly in it; it is redrawn
    (cell and point) when it lies outside the disc or when the segment from its cell's
    centre to it crosses a wall, so every point lies inside the walkable area itself, not
    just in a walkable cell, and the accepted points are uniform over what is left. A
    point still refused after 64 redraws (a disc with almost no walkable area in it) is
    put at the centre of a candidate cell.

    Parameters
    ----------
    plan : FloorPlan
    n : int
        Number of points.
    rng : numpy.random.Generator
    centre : array_like, shape (2,), optional
        Centre of the disc (m); give both ``centre`` and ``radius_m`` or neither.
    radius_m : float, optional
        Radius of the disc (m).

    Returns
    -------
    ndarray, shape (n, 2), float64

    Raises
    ------
    ValueError
        No walkable cell (within the disc), a negative ``n``, or only one of ``centre``
        and ``radius_m``.
    """
    if n < 0:
        raise ValueError(f"n must not be negative, not {n}")
    if (centre is None) != (radius_m is None):
        raise ValueError("give both centre and radius_m, or neither")
    iy, ix = np.nonzero(plan.walkable)
    cell_centres = np.asarray(plan.origin_m) + (np.column_stack([ix, iy]) + 0.5) * plan.cell_m
    disc: tuple[FloatArray, float] | None = None
    if centre is not None and radius_m is not None:
        c = np.asarray(centre, dtype=np.float64).reshape(2)
        if not (np.isfinite(c).all() and math.isfinite(radius_m) and radius_m >= 0):
            raise ValueError(f"bad disc: centre {c.tolist()}, radius_m {radius_m}")
        reach = radius_m + plan.cell_m * math.sqrt(0.5)  # a cell meets the disc
        near = np.sum((cell_centres - c) ** 2, axis=1) <= reach**2
        cell_centres = cell_centres[near]
        disc = (c, radius_m)
    if cell_centres.shape[0] == 0:
        raise ValueError("no walkable cell" + (" within the disc" if disc else ""))
    out = np.empty((n, 2))
    todo = np.arange(n)
    for _ in range(_RANDOM_POINT_ROUNDS):
        if todo.size == 0:
            return out
        cells = cell_centres[rng.integers(cell_centres.shape[0], size=todo.size)]
        points = cells + rng.uniform(-0.5, 0.5, size=(todo.size, 2)) * plan.cell_m
        ok = ~crosses_wall(plan, cells, points)
        if disc is not None:
            ok &= np.sum((points - disc[0]) ** 2, axis=1) <= disc[1] ** 2
        out[todo[ok]] = points[ok]
        todo = todo[~ok]
    out[todo] = cell_centres[rng.integers(cell_centres.shape[0], size=todo.size)]
    return out


def _take(rows: FloatArray, index: NDArray[np.intp]) -> FloatArray:
    """``rows[index]`` along the first axis: ``np.take`` is ~8x faster than fancy indexing
    on an (n, 2) array (numpy 2.4)."""
    return np.take(rows, index, axis=0)


def _points(xy: ArrayLike) -> FloatArray:
    points = np.asarray(xy, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2), not {points.shape}")
    return points


def _polygons(geometry: BaseGeometry) -> list[BaseGeometry]:
    """The polygonal parts of a repaired (multi)polygon: a self-touching ring repaired
    by ``make_valid`` may leave lines or points beside the polygons."""
    parts = shapely.get_parts(shapely.make_valid(geometry))
    return [p for p in parts.tolist() if shapely.get_dimensions(p) == 2]


def _segments(geometry: BaseGeometry) -> FloatArray:
    """Edges ``[x1, y1, x2, y2]`` of the lines of a (multi)line geometry, shape (m, 4)."""
    parts = shapely.get_parts(geometry)
    xy, part = shapely.get_coordinates(parts, return_index=True)
    same = part[1:] == part[:-1]
    segments = np.column_stack([xy[:-1][same], xy[1:][same]])
    return segments[np.any(segments[:, :2] != segments[:, 2:], axis=1)].reshape(-1, 4)


def _raster(
    area: BaseGeometry, cell_m: float
) -> tuple[tuple[float, float], float, NDArray[np.bool_]]:
    """``(origin_m, cell_m, walkable)`` of the cells whose centres lie inside ``area``."""
    x_min, y_min, x_max, y_max = area.bounds
    x0, y0 = math.floor(x_min / cell_m) * cell_m, math.floor(y_min / cell_m) * cell_m
    nx, ny = math.ceil((x_max - x0) / cell_m), math.ceil((y_max - y0) / cell_m)
    xs = x0 + (np.arange(nx) + 0.5) * cell_m
    ys = y0 + (np.arange(ny) + 0.5) * cell_m
    shapely.prepare(area)
    walkable = shapely.contains_xy(area, *np.meshgrid(xs, ys))
    return (x0, y0), cell_m, np.asarray(walkable, dtype=bool)


def _build_index(walls: FloatArray, bucket_m: float, reach_m: float) -> _WallIndex:
    """Bucket the walls; bucket ``(i, j)`` lists every wall that may meet its square grown
    by ``reach_m`` to the right and up (a superset, from bounding boxes of short pieces)."""
    if walls.shape[0] == 0:
        empty = np.zeros(1, dtype=np.intp)
        return _WallIndex((0.0, 0.0), bucket_m, reach_m, 0, 0, empty, empty[:0], np.zeros((0, 8)))
    lo = walls.reshape(-1, 2, 2).min(axis=1).min(axis=0) - reach_m - bucket_m
    hi = walls.reshape(-1, 2, 2).max(axis=1).max(axis=0)
    nx, ny = (np.floor((hi - lo) / bucket_m).astype(np.intp) + 1).tolist()
    # cut walls into pieces no longer than a bucket, so their boxes stay small
    length = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    n_pieces = np.maximum(np.ceil(length / bucket_m).astype(np.intp), 1)
    wall = np.repeat(np.arange(walls.shape[0]), n_pieces)
    k = np.arange(wall.size) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces)
    t = np.column_stack([k, k + 1]) / n_pieces[wall][:, None]  # (n, 2) piece ends
    w = walls[wall]
    px = w[:, :1] + t * (w[:, 2:3] - w[:, :1])
    py = w[:, 1:2] + t * (w[:, 3:4] - w[:, 1:2])
    # bucket i meets the piece when lo + i b <= max and lo + (i + 1) b + reach >= min
    i0 = np.ceil((px.min(axis=1) - lo[0] - reach_m) / bucket_m - 1).astype(np.intp)
    i1 = np.floor((px.max(axis=1) - lo[0]) / bucket_m).astype(np.intp)
    j0 = np.ceil((py.min(axis=1) - lo[1] - reach_m) / bucket_m - 1).astype(np.intp)
    j1 = np.floor((py.max(axis=1) - lo[1]) / bucket_m).astype(np.intp)
    i0, i1 = np.clip(i0, 0, nx - 1), np.clip(i1, 0, nx - 1)
    j0, j1 = np.clip(j0, 0, ny - 1), np.clip(j1, 0, ny - 1)
    wide, high = i1 - i0 + 1, j1 - j0 + 1
    count = wide * high
    piece = np.repeat(np.arange(wall.size), count)
    r = np.arange(piece.size) - np.repeat(np.cumsum(count) - count, count)
    bucket = (j0[piece] + r // wide[piece]) * nx + i0[piece] + r % wide[piece]
    pairs = np.unique(bucket * walls.shape[0] + wall[piece])
    bucket, entries = np.divmod(pairs, walls.shape[0])
    start = np.searchsorted(bucket, np.arange(nx * ny + 1)).astype(np.intp)
    entries = entries.astype(np.intp)
    ends = walls[entries].reshape(-1, 2, 2)
    segments = np.concatenate([walls[entries], ends.min(axis=1), ends.max(axis=1)], axis=1)
    return _WallIndex(
        (float(lo[0]), float(lo[1])), bucket_m, reach_m, nx, ny, start, entries, segments
    )


def _clearance(plan: FloorPlan) -> NDArray[np.uint8]:
    """Per raster cell, a lower bound of the distance from any point of the cell to any
    wall, in ``1 / CLEARANCE_STEPS`` of a cell rounded down, shape (ny, nx) (module
    docstring)."""
    ny, nx = plan.walkable.shape
    c = plan.cell_m
    # one cell of padding all round: its ring stands for every wall outside the raster
    marked = np.ones((ny + 2, nx + 2), dtype=bool)
    marked[1:-1, 1:-1] = False
    walls = plan.walls
    if walls.shape[0]:
        # cut into pieces at most half a cell long: a piece's box spans at most 2 x 2 cells
        length = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
        n_pieces = np.maximum(np.ceil(length / (0.5 * c)).astype(np.intp), 1)
        wall = np.repeat(np.arange(walls.shape[0]), n_pieces)
        k = np.arange(wall.size) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces)
        t = np.column_stack([k, k + 1]) / n_pieces[wall][:, None]
        w = walls[wall]
        px = w[:, :1] + t * (w[:, 2:3] - w[:, :1])
        py = w[:, 1:2] + t * (w[:, 3:4] - w[:, 1:2])
        x0, y0 = plan.origin_m[0] - c, plan.origin_m[1] - c  # corner of the padded raster
        i0, i1 = (
            np.clip(np.floor((v - x0) / c), 0, nx + 1).astype(np.intp)
            for v in (px.min(1), px.max(1))
        )
        j0, j1 = (
            np.clip(np.floor((v - y0) / c), 0, ny + 1).astype(np.intp)
            for v in (py.min(1), py.max(1))
        )
        for j in (j0, j1):
            for i in (i0, i1):
                marked[j, i] = True
    # the cells next to a marked one: the distance between the centres of cell c and its
    # nearest grown cell is the gap between the squares of c and its nearest marked cell
    grown = ndimage.binary_dilation(marked, structure=np.ones((3, 3), dtype=bool))
    cells = np.asarray(ndimage.distance_transform_edt(~grown), dtype=np.float64)[1:-1, 1:-1]
    return np.minimum(np.floor(cells * CLEARANCE_STEPS), 255).astype(np.uint8)


def _cells(plan: FloorPlan, xy: FloatArray) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Flat raster index of each point's cell (0 outside the raster) and whether it is
    inside the raster (False for NaN)."""
    ny, nx = plan.walkable.shape
    fx = xy[:, 0] - plan.origin_m[0]
    fx /= plan.cell_m
    np.floor(fx, out=fx)
    fy = xy[:, 1] - plan.origin_m[1]
    fy /= plan.cell_m
    np.floor(fy, out=fy)
    inside = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)  # False for NaN
    if not inside.all():
        fx[~inside] = 0.0
        fy[~inside] = 0.0
    fy *= nx
    fy += fx
    return fy.astype(np.intp), inside


def _crossing(plan: FloorPlan, a: FloatArray, b: FloatArray) -> NDArray[np.bool_]:
    """``crosses_wall`` on validated points of the same shape (n, 2)."""
    finite = np.isfinite(a) & np.isfinite(b)
    finite = finite[:, 0] & finite[:, 1]
    out: NDArray[np.bool_] = np.logical_not(finite)
    if plan.walls.shape[0] == 0 or not finite.any():
        return out
    rows: slice | NDArray[np.intp] = slice(None)
    if not finite.all():
        rows = np.flatnonzero(finite)
        a, b = _take(a, rows), _take(b, rows)
    # a move shorter than the clearance of its start cell meets no wall: only the others
    # need the segment tests
    cell, inside = _cells(plan, a)
    dx = b[:, 0] - a[:, 0]
    dy = b[:, 1] - a[:, 1]
    dx *= dx
    dy *= dy
    dx += dy
    clear = dx < plan._clear_below.take(plan._clearance.take(cell))
    clear &= inside
    todo = np.flatnonzero(~clear)
    if todo.size:
        hit = _moves_cross(plan._index, _take(a, todo), _take(b, todo))
        out[todo if isinstance(rows, slice) else rows[todo]] = hit
    return out


def _moves_cross(index: _WallIndex, p: FloatArray, q: FloatArray) -> NDArray[np.bool_]:
    """Whether finite moves ``p -> q`` meet a wall: through the index, long moves cut."""
    extent = np.maximum(np.abs(q[:, 0] - p[:, 0]), np.abs(q[:, 1] - p[:, 1]))
    long = extent > index.reach_m
    if not long.any():
        return _pieces_cross(index, p, q)
    # cut long moves into pieces no longer than the reach along x and y
    short = np.flatnonzero(~long)
    rows = np.flatnonzero(long)
    n_pieces = np.ceil(extent[rows] / index.reach_m).astype(np.intp)
    pl, ql = _take(p, rows), _take(q, rows)
    move = np.repeat(np.arange(rows.size), n_pieces)
    k = np.arange(move.size) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces)
    d = (ql - pl)[move]
    t = np.column_stack([k, k + 1]) / n_pieces[move][:, None]  # (n_pieces, 2)
    ends = pl[move][:, None] + t[..., None] * d[:, None]  # (n_pieces, 2 ends, 2)
    last = k == n_pieces[move] - 1
    ends[last, 1] = ql[move[last]]  # exactly b, not a + 1.0 * (b - a)
    # the short moves and the pieces of the long ones, in one pass through the index
    hit = _pieces_cross(
        index,
        np.concatenate([_take(p, short), ends[:, 0]]),
        np.concatenate([_take(q, short), ends[:, 1]]),
    )
    out = np.zeros(p.shape[0], dtype=bool)
    out[short] = hit[: short.size]
    out[rows] = np.bincount(move, weights=hit[short.size :], minlength=rows.size) > 0
    return out


def _pieces_cross(index: _WallIndex, p: FloatArray, q: FloatArray) -> NDArray[np.bool_]:
    """Whether segments ``p -> q`` (extent at most the reach along x and y) meet a wall.

    Column by column: numpy is slow on (n, 2) arrays broadcast against (2,).
    """
    x_lo = np.minimum(p[:, 0], q[:, 0])
    x_hi = np.maximum(p[:, 0], q[:, 0])
    y_lo = np.minimum(p[:, 1], q[:, 1])
    y_hi = np.maximum(p[:, 1], q[:, 1])
    i = x_lo - index.origin_m[0]
    i /= index.bucket_m
    np.floor(i, out=i)
    j = y_lo - index.origin_m[1]
    j /= index.bucket_m
    np.floor(j, out=j)
    # a move left of or below the grid ends before the first wall; right or above: after
    inside = (i >= 0) & (i < index.nx) & (j >= 0) & (j < index.ny)
    j *= index.nx
    j += i
    if not inside.all():
        j[~inside] = 0
    bucket = j.astype(np.intp)
    first = index.start.take(bucket)
    count = index.start.take(bucket + 1)
    count -= first
    if not inside.all():
        count[~inside] = 0
    piece = np.repeat(np.arange(p.shape[0]), count)
    first -= np.cumsum(count)
    first += count
    entry = np.repeat(first, count)
    entry += np.arange(piece.size)
    w = _take(index.segments, entry)
    # closed boxes that do not overlap share no point: only the other pairs are tested
    near = x_lo.take(piece) <= w[:, 6]
    near &= w[:, 4] <= x_hi.take(piece)
    near &= y_lo.take(piece) <= w[:, 7]
    near &= w[:, 5] <= y_hi.take(piece)
    pair = np.flatnonzero(near)
    out = np.zeros(p.shape[0], dtype=bool)
    if pair.size:
        piece, w = piece.take(pair), _take(w, pair)
        hit = _segments_meet(_take(p, piece), _take(q, piece), w[:, :2], w[:, 2:4])
        out[piece[hit]] = True
    return out


def _segments_meet(p: FloatArray, q: FloatArray, c: FloatArray, d: FloatArray) -> NDArray[np.bool_]:
    """Whether closed segments ``p -> q`` and ``c -> d`` share a point, row by row."""
    r, s = q - p, d - c
    o1 = _cross(r, c - p)
    o2 = _cross(r, d - p)
    o3 = _cross(s, p - c)
    o4 = _cross(s, q - c)
    s1, s2, s3, s4 = np.sign(o1), np.sign(o2), np.sign(o3), np.sign(o4)  # o1 * o2 may underflow
    hit = (s1 * s2 < 0) & (s3 * s4 < 0)  # proper crossing
    zero = (s1 == 0) | (s2 == 0) | (s3 == 0) | (s4 == 0)
    if zero.any():  # an end on the other segment (touching, collinear overlap)
        z = np.flatnonzero(zero)
        pz, qz, cz, dz = p[z], q[z], c[z], d[z]
        hit[z] |= (
            ((s1[z] == 0) & _within_box(cz, pz, qz))
            | ((s2[z] == 0) & _within_box(dz, pz, qz))
            | ((s3[z] == 0) & _within_box(pz, cz, dz))
            | ((s4[z] == 0) & _within_box(qz, cz, dz))
        )
    return hit


def _cross(u: FloatArray, v: FloatArray) -> FloatArray:
    return np.asarray(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], dtype=np.float64)


def _within_box(x: FloatArray, p: FloatArray, q: FloatArray) -> NDArray[np.bool_]:
    """Whether ``x`` lies in the bounding box of ``p`` and ``q`` (for points collinear
    with ``p -> q``: on the segment)."""
    return np.asarray(np.all((np.minimum(p, q) <= x) & (x <= np.maximum(p, q)), axis=1))
