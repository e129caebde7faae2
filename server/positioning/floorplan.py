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
first. Segment intersection is the orientation (cross-product) test, vectorised over all
(piece, candidate wall) pairs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
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

    The four fields are the whole plan (a plan is rebuilt from them); the wall index used
    by ``crosses_wall`` is derived from ``walls`` on construction.
    """

    origin_m: tuple[float, float]
    cell_m: float
    walkable: NDArray[np.bool_]
    walls: FloatArray
    _index: _WallIndex = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cell_m) and self.cell_m > 0):
            raise ValueError(f"cell_m must be positive, not {self.cell_m}")
        if self.walkable.ndim != 2 or self.walkable.dtype != np.bool_:
            raise ValueError(f"walkable must be a 2-D bool array, not {self.walkable.dtype}")
        if self.walls.ndim != 2 or self.walls.shape[1] != 4:
            raise ValueError(f"walls must have shape (m, 4), not {self.walls.shape}")
        # a derived cache on a frozen instance: the documented idiom for __post_init__
        object.__setattr__(self, "_index", _build_index(self.walls, WALL_BUCKET_M, WALL_REACH_M))


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
        kind = (feature.get("properties") or {}).get("kind")
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


def plan_extent(geojson: Mapping[str, Any] | None) -> tuple[float, float, float, float] | None:
    """``(x0, y0, x1, y1)``: the bounding box of a plan's walkable features (what
    ``plan_from_geojson`` builds the walkable area from), without rasterising; None when
    the plan has none or they are not readable geometries."""
    boxes = []
    for feature in (geojson or {}).get("features") or ():
        if not isinstance(feature, Mapping):
            continue
        if (feature.get("properties") or {}).get("kind") not in _WALKABLE_KINDS:
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
    ny, nx = plan.walkable.shape
    # column by column: reductions over an axis of length 2 are slow in numpy
    fx = np.floor((xy[:, 0] - plan.origin_m[0]) / plan.cell_m)
    fy = np.floor((xy[:, 1] - plan.origin_m[1]) / plan.cell_m)
    inside = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)  # False for NaN
    out = np.zeros(xy.shape[0], dtype=bool)
    out[inside] = plan.walkable[fy[inside].astype(np.intp), fx[inside].astype(np.intp)]
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
    finite = np.isfinite(a) & np.isfinite(b)
    finite = finite[:, 0] & finite[:, 1]
    out: NDArray[np.bool_] = np.logical_not(finite)
    if plan.walls.shape[0] == 0 or not finite.any():
        return out
    index = plan._index
    p, q = a[finite], b[finite]
    extent = np.abs(q - p)
    n_pieces = np.ceil(np.maximum(extent[:, 0], extent[:, 1]) / index.reach_m).astype(np.intp)
    n_pieces = np.maximum(n_pieces, 1)
    if np.all(n_pieces == 1):
        out[finite] = _pieces_cross(plan.walls, index, p, q)
        return out
    # cut long moves into pieces no longer than the reach along x and y
    move = np.repeat(np.arange(p.shape[0]), n_pieces)
    k = np.arange(move.size) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces)
    d = (q - p)[move]
    t = np.column_stack([k, k + 1]) / n_pieces[move][:, None]  # (n_pieces, 2)
    ends = p[move][:, None] + t[..., None] * d[:, None]  # (n_pieces, 2 ends, 2)
    last = k == n_pieces[move] - 1
    ends[last, 1] = q[move[last]]  # exactly b, not a + 1.0 * (b - a)
    piece_hit = _pieces_cross(plan.walls, index, ends[:, 0], ends[:, 1])
    out[finite] = np.bincount(move, weights=piece_hit, minlength=p.shape[0]) > 0
    return out


def valid_moves(plan: FloorPlan, a: ArrayLike, b: ArrayLike) -> NDArray[np.bool_]:
    """``walkable_at(plan, b) & ~crosses_wall(plan, a, b)``, shape (n,)."""
    ok = walkable_at(plan, b)
    if ok.any():  # only the moves that end in walkable cells need the crossing test
        ok[ok] = ~crosses_wall(plan, _points(a)[ok], _points(b)[ok])
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
        return _WallIndex((0.0, 0.0), bucket_m, reach_m, 0, 0, empty, empty[:0])
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
    return _WallIndex(
        (float(lo[0]), float(lo[1])), bucket_m, reach_m, nx, ny, start, entries.astype(np.intp)
    )


def _pieces_cross(
    walls: FloatArray, index: _WallIndex, p: FloatArray, q: FloatArray
) -> NDArray[np.bool_]:
    """Whether segments ``p -> q`` (extent at most the reach along x and y) meet a wall."""
    corner = np.minimum(p, q) - np.asarray(index.origin_m)
    i = np.floor(corner[:, 0] / index.bucket_m).astype(np.intp)
    j = np.floor(corner[:, 1] / index.bucket_m).astype(np.intp)
    # a move left of or below the grid ends before the first wall; right or above: after
    inside = (i >= 0) & (i < index.nx) & (j >= 0) & (j < index.ny)
    bucket = np.where(inside, j * index.nx + i, 0)
    first = index.start[bucket]
    count = np.where(inside, index.start[bucket + 1] - first, 0)
    piece = np.repeat(np.arange(p.shape[0]), count)
    entry = np.arange(piece.size) + np.repeat(first - (np.cumsum(count) - count), count)
    w = walls[index.walls[entry]]
    hit = _segments_meet(p[piece], q[piece], w[:, :2], w[:, 2:])
    out = np.zeros(p.shape[0], dtype=bool)
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
