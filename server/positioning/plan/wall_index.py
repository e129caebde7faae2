"""The wall index and clearance raster behind a floor plan's wall-crossing test.

``floor_plan.crosses_wall`` asks whether moves meet any wall segment of a plan. This module
holds what answers it quickly and exactly: a bucket grid over the walls
(``build_wall_index``, queried by ``moves_cross``), a raster of each cell's clearance from
the walls (``clearance_raster``), and the closed-segment test itself (``segments_meet``).

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

The segment test (``segments_meet``): closed segments ``p -> q`` and ``c -> d`` share a
point when the orientations ``(q - p) x (c - p)`` and ``(q - p) x (d - p)`` have opposite
signs and so do ``(d - c) x (p - c)`` and ``(d - c) x (q - c)`` (a proper crossing), or
when an end lies on the other segment (an orientation of 0 and the end within the other
segment's bounding box: touching, or running along it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

FloatArray = NDArray[np.float64]

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


def take_rows(rows: FloatArray, index: NDArray[np.intp]) -> FloatArray:
    """``rows[index]`` along the first axis: ``np.take`` is ~8x faster than fancy indexing
    on an (n, 2) array (numpy 2.4)."""
    return np.take(rows, index, axis=0)


@dataclass(frozen=True, eq=False)
class WallIndex:
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
    walls: NDArray[np.intp]  # (n_entries,) rows of the plan's walls
    # per entry: the wall [x1, y1, x2, y2] and its bounding box [x_min, y_min, x_max, y_max]
    segments: FloatArray  # (n_entries, 8)

    def kernel_args(
        self,
    ) -> tuple[float, float, float, float, int, int, NDArray[np.intp], FloatArray]:
        """The index as the compiled wall test takes it (``move_test_kernels.moves_cross``)."""
        x0, y0 = self.origin_m
        return x0, y0, self.bucket_m, self.reach_m, self.nx, self.ny, self.start, self.segments


def build_wall_index(walls: FloatArray, bucket_m: float, reach_m: float) -> WallIndex:
    """Bucket the walls; bucket ``(i, j)`` lists every wall that may meet its square grown
    by ``reach_m`` to the right and up (a superset, from bounding boxes of short pieces)."""
    if walls.shape[0] == 0:
        empty = np.zeros(1, dtype=np.intp)
        return WallIndex((0.0, 0.0), bucket_m, reach_m, 0, 0, empty, empty[:0], np.zeros((0, 8)))
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
    return WallIndex(
        (float(lo[0]), float(lo[1])), bucket_m, reach_m, nx, ny, start, entries, segments
    )


def clearance_raster(
    walls: FloatArray, origin_m: tuple[float, float], cell_m: float, shape: tuple[int, ...]
) -> NDArray[np.uint8]:
    """Per raster cell, a lower bound of the distance from any point of the cell to any
    wall, in ``1 / CLEARANCE_STEPS`` of a cell rounded down, shape (ny, nx) (module
    docstring).

    Parameters
    ----------
    walls : ndarray, shape (m, 4)
        Wall segments ``[x1, y1, x2, y2]`` (m).
    origin_m, cell_m, shape
        The raster: lower-left corner of cell ``(0, 0)``, cell side, ``(ny, nx)``.
    """
    ny, nx = shape
    c = cell_m
    # one cell of padding all round: its ring stands for every wall outside the raster
    marked = np.ones((ny + 2, nx + 2), dtype=bool)
    marked[1:-1, 1:-1] = False
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
        x0, y0 = origin_m[0] - c, origin_m[1] - c  # corner of the padded raster
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


def moves_cross(index: WallIndex, p: FloatArray, q: FloatArray) -> NDArray[np.bool_]:
    """Whether finite moves ``p -> q`` meet a wall: through the index, long moves cut."""
    extent = np.maximum(np.abs(q[:, 0] - p[:, 0]), np.abs(q[:, 1] - p[:, 1]))
    long = extent > index.reach_m
    if not long.any():
        return _pieces_cross(index, p, q)
    # cut long moves into pieces no longer than the reach along x and y
    short = np.flatnonzero(~long)
    rows = np.flatnonzero(long)
    n_pieces = np.ceil(extent[rows] / index.reach_m).astype(np.intp)
    pl, ql = take_rows(p, rows), take_rows(q, rows)
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
        np.concatenate([take_rows(p, short), ends[:, 0]]),
        np.concatenate([take_rows(q, short), ends[:, 1]]),
    )
    out = np.zeros(p.shape[0], dtype=bool)
    out[short] = hit[: short.size]
    out[rows] = np.bincount(move, weights=hit[short.size :], minlength=rows.size) > 0
    return out


def _pieces_cross(index: WallIndex, p: FloatArray, q: FloatArray) -> NDArray[np.bool_]:
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
    w = take_rows(index.segments, entry)
    # closed boxes that do not overlap share no point: only the other pairs are tested
    near = x_lo.take(piece) <= w[:, 6]
    near &= w[:, 4] <= x_hi.take(piece)
    near &= y_lo.take(piece) <= w[:, 7]
    near &= w[:, 5] <= y_hi.take(piece)
    pair = np.flatnonzero(near)
    out = np.zeros(p.shape[0], dtype=bool)
    if pair.size:
        piece, w = piece.take(pair), take_rows(w, pair)
        hit = segments_meet(take_rows(p, piece), take_rows(q, piece), w[:, :2], w[:, 2:4])
        out[piece[hit]] = True
    return out


def segments_meet(p: FloatArray, q: FloatArray, c: FloatArray, d: FloatArray) -> NDArray[np.bool_]:
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
