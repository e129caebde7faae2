"""Compiled (numba) forms of the floor plan's move test, one move at a time, where numpy
needs several passes over temporary arrays: the particle filter's hot loop of line 9 of
``papers/001_*`` Algorithm 1.

Each kernel computes what its numpy reference computes, with the same float64 operations
in the same order, so the answers agree exactly (the tests compare them on random
inputs):

* ``moves_cross``: ``wall_index.moves_cross`` -- long moves cut into pieces no longer
  than the index's reach (ends at ``a + k/n (b - a)``, the last exactly ``b``), each piece
  tested against the walls of its bucket whose boxes meet its box, by the closed-segment
  orientation test of ``wall_index.segments_meet``;
* ``valid_moves``: ``floor_plan.valid_moves_reference`` -- the end in a walkable raster
  cell, then the clearance shortcut, then ``moves_cross``'s test, in one pass.

Compiled on first use and cached on disk (``cache=True``); no Python object crosses into
them. ``filters.particle_kernels.constrained_step`` runs ``valid_moves`` in its fused
step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
# a floor plan as ``valid_moves`` and ``particle_kernels.constrained_step`` take it
# (``floor_plan.kernel_args``)
PlanArgs = tuple[
    NDArray[np.bool_], float, float, float, int, int, NDArray[np.uint8], FloatArray, int,
    float, float, float, float, int, int, NDArray[np.intp], FloatArray,
]  # fmt: skip


@njit(cache=True)
def _sign(x: float) -> float:
    return (x > 0.0) - (x < 0.0)


@njit(cache=True)
def _within(x: float, y: float, px: float, py: float, qx: float, qy: float) -> bool:
    return min(px, qx) <= x <= max(px, qx) and min(py, qy) <= y <= max(py, qy)


@njit(cache=True)
def _segments_meet(
    px: float, py: float, qx: float, qy: float, cx: float, cy: float, dx: float, dy: float
) -> bool:
    rx, ry = qx - px, qy - py
    sx, sy = dx - cx, dy - cy
    s1 = _sign(rx * (cy - py) - ry * (cx - px))
    s2 = _sign(rx * (dy - py) - ry * (dx - px))
    s3 = _sign(sx * (py - cy) - sy * (px - cx))
    s4 = _sign(sx * (qy - cy) - sy * (qx - cx))
    if s1 * s2 < 0 and s3 * s4 < 0:
        return True
    return (
        (s1 == 0 and _within(cx, cy, px, py, qx, qy))
        or (s2 == 0 and _within(dx, dy, px, py, qx, qy))
        or (s3 == 0 and _within(px, py, cx, cy, dx, dy))
        or (s4 == 0 and _within(qx, qy, cx, cy, dx, dy))
    )


@njit(cache=True)
def _piece_crosses(
    px: float,
    py: float,
    qx: float,
    qy: float,
    origin_x: float,
    origin_y: float,
    bucket_m: float,
    nx: int,
    ny: int,
    start: NDArray[np.intp],
    segments: FloatArray,
) -> bool:
    x_lo, x_hi = min(px, qx), max(px, qx)
    y_lo, y_hi = min(py, qy), max(py, qy)
    i = math.floor((x_lo - origin_x) / bucket_m)
    j = math.floor((y_lo - origin_y) / bucket_m)
    if not (0 <= i < nx and 0 <= j < ny):
        return False
    bucket = int(j) * nx + int(i)
    for e in range(start[bucket], start[bucket + 1]):
        w = segments[e]
        near = x_lo <= w[6] and w[4] <= x_hi and y_lo <= w[7] and w[5] <= y_hi
        if near and _segments_meet(px, py, qx, qy, w[0], w[1], w[2], w[3]):
            return True
    return False


@njit(cache=True)
def _move_crosses(
    ax: float,
    ay: float,
    bx: float,
    by: float,
    origin_x: float,
    origin_y: float,
    bucket_m: float,
    reach_m: float,
    nx: int,
    ny: int,
    start: NDArray[np.intp],
    segments: FloatArray,
) -> bool:
    """Whether the finite move ``a -> b`` meets a wall: in pieces no longer than the reach."""
    dx, dy = bx - ax, by - ay
    extent = max(abs(dx), abs(dy))
    pieces = 1 if extent <= reach_m else math.ceil(extent / reach_m)
    for m in range(pieces):
        sx, sy = ax + (m / pieces) * dx, ay + (m / pieces) * dy
        if m == pieces - 1:
            ex, ey = bx, by
        else:
            ex, ey = ax + ((m + 1) / pieces) * dx, ay + ((m + 1) / pieces) * dy
        if _piece_crosses(sx, sy, ex, ey, origin_x, origin_y, bucket_m, nx, ny, start, segments):
            return True
    return False


@njit(cache=True)
def moves_cross(
    p: FloatArray,
    q: FloatArray,
    origin_x: float,
    origin_y: float,
    bucket_m: float,
    reach_m: float,
    nx: int,
    ny: int,
    start: NDArray[np.intp],
    segments: FloatArray,
) -> NDArray[np.bool_]:
    """Whether each finite move ``p[k] -> q[k]`` meets a wall of the index."""
    out = np.zeros(p.shape[0], dtype=np.bool_)
    for k in range(p.shape[0]):
        out[k] = _move_crosses(
            p[k, 0], p[k, 1], q[k, 0], q[k, 1],
            origin_x, origin_y, bucket_m, reach_m, nx, ny, start, segments,
        )  # fmt: skip
    return out


@njit(cache=True)
def _cell(x: float, y: float, x0: float, y0: float, cell_m: float, nx: int, ny: int) -> int:
    """Flat raster index of a point's cell; -1 outside the raster (and for NaN)."""
    fx = math.floor((x - x0) / cell_m)
    fy = math.floor((y - y0) / cell_m)
    if fx >= 0 and fx < nx and fy >= 0 and fy < ny:
        return int(fy) * nx + int(fx)
    return -1


@njit(cache=True)
def valid_moves(
    a: FloatArray,
    b: FloatArray,
    walkable: NDArray[np.bool_],
    x0: float,
    y0: float,
    cell_m: float,
    nx: int,
    ny: int,
    clearance: NDArray[np.uint8],
    clear_below: FloatArray,
    n_walls: int,
    origin_x: float,
    origin_y: float,
    bucket_m: float,
    reach_m: float,
    bucket_nx: int,
    bucket_ny: int,
    start: NDArray[np.intp],
    segments: FloatArray,
) -> NDArray[np.bool_]:
    """``floor_plan.valid_moves``: ``b`` in a walkable cell and ``a -> b`` meeting no wall
    (moves shorter than the clearance of their start's cell skip the segment tests)."""
    n = a.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        ax, ay, bx, by = a[k, 0], a[k, 1], b[k, 0], b[k, 1]
        end = _cell(bx, by, x0, y0, cell_m, nx, ny)
        if end < 0 or not walkable[end]:
            continue
        if not (math.isfinite(ax) and math.isfinite(ay)):
            continue
        if n_walls == 0:
            out[k] = True
            continue
        here = _cell(ax, ay, x0, y0, cell_m, nx, ny)
        dx, dy = bx - ax, by - ay
        if here >= 0 and dx * dx + dy * dy < clear_below[clearance[here]]:
            out[k] = True
            continue
        out[k] = not _move_crosses(
            ax, ay, bx, by,
            origin_x, origin_y, bucket_m, reach_m, bucket_nx, bucket_ny, start, segments,
        )  # fmt: skip
    return out
