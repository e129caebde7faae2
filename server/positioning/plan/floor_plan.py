"""Floor plans: a walkable raster and an exact wall-crossing test for particle moves.

The map constraint of the particle filter (``papers/001_*`` section III-B and III-D:
"particles outside reachable areas are removed according to the floor plan", "users have
no possibility to walk through a wall"): a particle moved from ``a`` to ``b`` survives
when ``b`` is reachable and the segment ``a -> b`` meets no wall.

Plans are built from GeoJSON by ``geojson_plan`` (whose docstring gives how the walkable
area ``W`` and the wall segments follow from the format of ``geojson_format``); the wall index
and clearance raster that make the crossing test fast are in ``wall_index``.

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from server.positioning.plan import move_test_kernels
from server.positioning.plan.wall_index import (
    CLEARANCE_MARGIN_M,
    CLEARANCE_STEPS,
    WALL_BUCKET_M,
    WALL_REACH_M,
    WallIndex,
    build_wall_index,
    clearance_raster,
    take_rows,
)

FloatArray = NDArray[np.float64]

_RANDOM_POINT_ROUNDS = 64  # redraws in random_walkable_points before the fallback


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
    _index: WallIndex = field(init=False, repr=False)
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
        index = build_wall_index(self.walls, WALL_BUCKET_M, WALL_REACH_M)
        object.__setattr__(self, "_index", index)
        clearance = clearance_raster(self.walls, self.origin_m, self.cell_m, self.walkable.shape)
        object.__setattr__(self, "_clearance", clearance.ravel())
        steps = np.arange(256) * (self.cell_m / CLEARANCE_STEPS) - CLEARANCE_MARGIN_M
        object.__setattr__(self, "_clear_below", np.maximum(steps, 0.0) ** 2)


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
    """``walkable_at(plan, b) & ~crosses_wall(plan, a, b)``, shape (n,): compiled
    (``move_test_kernels.valid_moves``; ``valid_moves_reference`` is the same in numpy)."""
    a, b = _points(a), _points(b)
    if a.shape != b.shape:
        raise ValueError(f"a and b differ in shape: {a.shape} and {b.shape}")
    out: NDArray[np.bool_] = move_test_kernels.valid_moves(a, b, *kernel_args(plan))
    return out


def kernel_args(plan: FloorPlan) -> move_test_kernels.PlanArgs:
    """The plan as the compiled move test takes it (``move_test_kernels.valid_moves``,
    ``particle_kernels.constrained_step``): raster, clearance and wall index."""
    ny, nx = plan.walkable.shape
    return (
        plan.walkable.ravel(), float(plan.origin_m[0]), float(plan.origin_m[1]),
        float(plan.cell_m), nx, ny, plan._clearance, plan._clear_below, plan.walls.shape[0],
        *plan._index.kernel_args(),
    )  # fmt: skip


def valid_moves_reference(plan: FloorPlan, a: ArrayLike, b: ArrayLike) -> NDArray[np.bool_]:
    """``valid_moves`` in numpy (the reference the kernel is tested against)."""
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


def _points(xy: ArrayLike) -> FloatArray:
    points = np.asarray(xy, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2), not {points.shape}")
    return points


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
        a, b = take_rows(a, rows), take_rows(b, rows)
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
        # wall_index.moves_cross, compiled (kernels)
        hit = move_test_kernels.moves_cross(
            take_rows(a, todo), take_rows(b, todo), *plan._index.kernel_args()
        )
        out[todo if isinstance(rows, slice) else rows[todo]] = hit
    return out
