"""Compiled (numba) forms of the particle filter's hot loops, one move or particle at a
time, where numpy needs several passes over temporary arrays.

Each kernel computes what its numpy reference computes, with the same float64 operations
in the same order, so the answers agree exactly (the tests compare them on random
inputs):

* ``moves_cross``: ``wall_index.moves_cross`` -- long moves cut into pieces no longer
  than the index's reach (ends at ``a + k/n (b - a)``, the last exactly ``b``), each piece
  tested against the walls of its bucket whose boxes meet its box, by the closed-segment
  orientation test of ``wall_index.segments_meet``;
* ``bilinear``: ``magnetic._bilinear`` -- bilinear interpolation over the known corners,
  NaN outside the grid or where the known corners weigh too little;
* ``mmse``: ``sequence_distance.mmse`` -- eq (b) of ``papers/001_*`` per candidate row,
  ``inf`` for a row with a NaN;
* ``valid_moves``: ``floor_plan.valid_moves_reference`` -- the end in a walkable raster
  cell, then the clearance shortcut, then ``moves_cross``'s test, in one pass;
* ``mass_centered_weights``: the mass-centered branch of ``particle._weight_update`` after
  the map sampling (window shift, eq (b)-(c), the median for unknown windows and
  ``particle_cloud.normalised``), whose log-sum-exp adds in another order than numpy's
  pairwise sum: the float32 log weights agree to a unit in the last place;
* ``constrained_step``: ``particle.step``'s move and mass-centered update for a cloud on
  one floor, in one call over the kernels above (``particle.step_on_floor``), with
  ``effective_sample_size`` and ``systematic_rows`` (``particle._resample``'s rows, in one
  merge pass over the sorted points);
* ``dtw``: ``sequence_distance.dtw_distance`` per candidate, two rows of the table at a
  time.

Compiled on first use and cached on disk (``cache=True``); no Python object crosses into
them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
# a floor plan and a magnetic grid as ``constrained_step`` takes them
# (``floor_plan.kernel_args``, ``field_grid.kernel_args``)
PlanArgs = tuple[
    NDArray[np.bool_], float, float, float, int, int, NDArray[np.uint8], FloatArray, int,
    float, float, float, float, int, int, NDArray[np.intp], FloatArray,
]  # fmt: skip
GridArgs = tuple[float, float, float, int, int, FloatArray, FloatArray, float]


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
def bilinear(
    pts: FloatArray,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    nx: int,
    ny: int,
    filled: FloatArray,
    known: FloatArray,
    min_weight: float,
) -> FloatArray:
    """The grid's field at each point (``filled``/``known`` flat, row-major (ny, nx))."""
    n = pts.shape[0]
    out = np.full(n, np.nan)
    di = min(nx - 1, 1)
    dj = nx * min(ny - 1, 1)
    for k in range(n):
        u = (pts[k, 0] - origin_x) / cell_m - 0.5
        v = (pts[k, 1] - origin_y) / cell_m - 0.5
        if not (u >= -0.5 and u <= nx - 0.5 and v >= -0.5 and v <= ny - 0.5):
            continue
        u = max(min(u, nx - 1.0), 0.0)
        v = max(min(v, ny - 1.0), 0.0)
        i0 = min(math.floor(u), max(nx - 2, 0))
        j0 = min(math.floor(v), max(ny - 2, 0))
        fx, fy = u - i0, v - j0
        gx, gy = 1.0 - fx, 1.0 - fy
        base = int(j0 * nx + i0)
        total = 0.0
        weight = 0.0
        for offset, w in ((0, gx * gy), (di, fx * gy), (dj, gx * fy), (dj + di, fx * fy)):
            w = w * known[base + offset]
            weight += w
            total += w * filled[base + offset]
        if weight > min_weight:
            out[k] = total / weight
    return out


@njit(cache=True)
def mmse(observed: FloatArray, candidates: FloatArray) -> FloatArray:
    """Eq (b) per row of ``candidates`` (n, w) against ``observed`` (w,)."""
    n, w = candidates.shape
    out = np.empty(n)
    for k in range(n):
        total = 0.0
        for j in range(w - 1):
            total += abs(
                abs(candidates[k, j + 1] - candidates[k, j]) - abs(observed[j + 1] - observed[j])
            )
        total /= w - 1
        out[k] = np.inf if math.isnan(total) else total
    return out


@njit(cache=True)
def dtw(observed: FloatArray, candidates: FloatArray) -> FloatArray:
    """``sequence_distance.dtw_distance`` per row of ``candidates`` (n, m) against
    ``observed`` (w,): the same recursion row by row over two rows of the table, ``inf``
    for a row with a NaN."""
    n, m = candidates.shape
    w = observed.shape[0]
    out = np.empty(n)
    prev = np.empty(m)
    row = np.empty(m)
    for i in range(n):
        b = candidates[i]
        prev[0] = abs(observed[0] - b[0])
        for ell in range(1, m):
            prev[ell] = prev[ell - 1] + abs(observed[0] - b[ell])
        for k in range(1, w):
            a = observed[k]
            row[0] = prev[0] + abs(a - b[0])
            for ell in range(1, m):
                best = min(prev[ell], row[ell - 1], prev[ell - 1])
                row[ell] = abs(a - b[ell]) + best
            prev, row = row, prev
        total = prev[m - 1]
        out[i] = np.inf if math.isnan(total) else total
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


@njit(cache=True)
def step_ends(
    a: FloatArray,
    noise: FloatArray,
    length_m: float,
    heading_rad: float,
    step_sd_m: float,
    heading_sd_rad: float,
) -> NDArray[np.float32]:
    """``particle.move``'s new positions: ``a + max(S + σ_S n0, 0) (sin, cos)(θ + σ_θ n1)``
    rounded to float32; ``noise`` is (2, n) for the n rows of ``a``."""
    n = a.shape[0]
    out = np.empty((n, 2), dtype=np.float32)
    for k in range(n):
        length = max(noise[0, k] * step_sd_m + length_m, 0.0)
        heading = noise[1, k] * heading_sd_rad + heading_rad
        out[k, 0] = math.sin(heading) * length + a[k, 0]
        out[k, 1] = math.cos(heading) * length + a[k, 1]
    return out


@njit(cache=True)
def normalised(log_w: FloatArray) -> NDArray[np.float32]:
    """``particle_cloud.normalised``: ``log_w - logsumexp(log_w)`` as float32."""
    top = -np.inf
    for x in log_w:
        if math.isfinite(x) and x > top:
            top = x
    out = np.full(log_w.shape[0], -np.inf, dtype=np.float32)
    if top == -np.inf:
        return out
    total = 0.0
    for x in log_w:
        if math.isfinite(x):
            total += math.exp(x - top)
    total = top + math.log(total)
    for k in range(log_w.shape[0]):
        out[k] = log_w[k] - total
    return out


@njit(cache=True)
def mass_centered_weights(
    mags: NDArray[np.float32],
    live: NDArray[np.intp],
    m_live: FloatArray,
    observed: NDArray[np.float32],
    count: int,
    log_w: NDArray[np.float32],
    t: float,
    log_k: float,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``particle._weight_update`` after the map sampling, for the mass-centered update:
    the windows shifted with the new map magnitudes (``m_live`` for the rows ``live``,
    NaN for the dead), then eq (b)-(c) and the normalisation; the log weights come back
    unchanged when there is nothing to weigh by."""
    n, slots = mags.shape
    shifted = np.empty((n, slots), dtype=np.float32)
    for k in range(n):
        for j in range(slots - 1):
            shifted[k, j] = mags[k, j + 1]
        shifted[k, slots - 1] = np.nan
    for r in range(live.shape[0]):
        shifted[live[r], slots - 1] = m_live[r]
    if count < 2 or live.shape[0] == 0:
        return shifted, log_w
    first = slots - count
    award = np.empty(live.shape[0])
    known = np.zeros(live.shape[0], dtype=np.bool_)
    for r in range(live.shape[0]):
        row = live[r]
        total = 0.0
        for j in range(first, slots - 1):
            step = abs(float(shifted[row, j + 1]) - float(shifted[row, j]))
            total += abs(step - abs(float(observed[j + 1]) - float(observed[j])))
        total /= count - 1
        if math.isfinite(total):
            known[r] = True
            award[r] = max(total, t)
    if not known.any():
        return shifted, log_w
    if not known.all():
        middle = np.median(award[known])
        for r in range(live.shape[0]):
            if not known[r]:
                award[r] = middle
    log_w64 = log_w.astype(np.float64)
    for r in range(live.shape[0]):
        log_w64[live[r]] += log_k - math.log(award[r])
    return shifted, normalised(log_w64)


@njit(cache=True)
def constrained_step(
    xy: NDArray[np.float32],
    log_w: NDArray[np.float32],
    mags: NDArray[np.float32],
    observed: NDArray[np.float32],
    count: int,
    noise: FloatArray,
    length_m: float,
    heading_rad: float,
    step_sd_m: float,
    heading_sd_rad: float,
    has_plan: bool,
    plan: PlanArgs,
    has_grid: bool,
    grid: GridArgs,
    weigh: bool,
    t: float,
    log_k: float,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], float]:
    """``particle.move`` and, when ``weigh``, the mass-centered update, for a cloud on one
    floor: each living particle moved (``step_ends``), its move tested (``valid_moves``
    when ``has_plan``, else only for a finite end), the log weights normalised, then the
    map sampled at the living particles (``bilinear`` when ``has_grid``, else unknown) and
    ``mass_centered_weights``. ``observed`` and ``count`` are the windows after the step.
    Returns the new positions, log weights and map windows and the effective sample size
    (0 for a dead cloud, which comes back as it went in when it was dead before)."""
    n = xy.shape[0]
    live = np.empty(n, dtype=np.intp)
    n_live = 0
    for k in range(n):
        if math.isfinite(log_w[k]):  # else -inf: dead
            live[n_live] = k
            n_live += 1
    if n_live == 0:
        return xy, log_w, mags, 0.0
    # the moves of the living, then the array kernels over them (a call per particle
    # to a compiled helper measured 2.5x slower than these loops)
    a = np.empty((n_live, 2))
    b = np.empty((n_live, 2))
    b32 = np.empty((n_live, 2), dtype=np.float32)
    for r in range(n_live):
        k = live[r]
        a[r, 0], a[r, 1] = xy[k, 0], xy[k, 1]
        length = max(noise[0, k] * step_sd_m + length_m, 0.0)
        heading = noise[1, k] * heading_sd_rad + heading_rad
        b32[r, 0] = math.sin(heading) * length + a[r, 0]
        b32[r, 1] = math.cos(heading) * length + a[r, 1]
        b[r, 0], b[r, 1] = b32[r, 0], b32[r, 1]
    if has_plan:
        ok = valid_moves(a, b, *plan)
    else:
        ok = np.empty(n_live, dtype=np.bool_)
        for r in range(n_live):
            ok[r] = math.isfinite(b[r, 0]) and math.isfinite(b[r, 1])
    new_xy = xy.copy()
    log_w64 = np.full(n, -np.inf)
    moved = 0
    for r in range(n_live):
        if ok[r]:
            k = live[r]
            new_xy[k, 0], new_xy[k, 1] = b32[r, 0], b32[r, 1]
            log_w64[k] = log_w[k]
            live[moved] = k  # the living after the move, in order
            b[moved, 0], b[moved, 1] = b[r, 0], b[r, 1]
            moved += 1
    new_log_w = normalised(log_w64)
    if moved == 0:
        return new_xy, new_log_w, mags, 0.0
    new_mags = mags
    if weigh:
        m_live = bilinear(b[:moved], *grid) if has_grid else np.full(moved, np.nan)
        new_mags, new_log_w = mass_centered_weights(
            mags, live[:moved], m_live, observed, count, new_log_w, t, log_k
        )
    return new_xy, new_log_w, new_mags, effective_sample_size(new_log_w)


@njit(cache=True)
def _weights(log_w: NDArray[np.float32]) -> FloatArray:
    """``particle_cloud.weights``: the float64 weights renormalised."""
    w: FloatArray = np.exp(log_w.astype(np.float64))
    w /= w.sum()
    return w


@njit(cache=True)
def effective_sample_size(log_w: NDArray[np.float32]) -> float:
    """``1 / sum w_i^2`` of the weights (0 when every particle is dead)."""
    w = _weights(log_w)
    total = 0.0
    for x in w:
        total += x * x
    return 1.0 / total if math.isfinite(total) and total > 0.0 else 0.0


@njit(cache=True)
def systematic_rows(log_w: NDArray[np.float32], u: float) -> NDArray[np.intp]:
    """``particle._resample``'s rows: for each point ``(u + k) / n`` the first particle
    whose cumulative weight exceeds it (``searchsorted(..., side="right")``), in one merge
    pass over the sorted points."""
    n = log_w.shape[0]
    cdf = np.cumsum(_weights(log_w))
    cdf /= cdf[-1]
    rows = np.empty(n, dtype=np.intp)
    j = 0
    for k in range(n):
        point = (u + k) / n
        while j < n - 1 and cdf[j] <= point:
            j += 1
        rows[k] = j
    return rows


# ``constrained_step`` without a plan or a map: arrays of the right types, never read
NO_PLAN: PlanArgs = (
    np.zeros(1, dtype=np.bool_), 0.0, 0.0, 1.0, 0, 0, np.zeros(1, dtype=np.uint8),
    np.zeros(256), 0, 0.0, 0.0, 1.0, 1.0, 0, 0, np.zeros(1, dtype=np.intp), np.zeros((0, 8)),
)  # fmt: skip
NO_GRID: GridArgs = (0.0, 0.0, 1.0, 0, 0, np.zeros(1), np.zeros(1), 0.0)


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel on tiny inputs, so the first
    request that needs one does not wait for the compiler (a few seconds when cold)."""
    xy = np.zeros((1, 2))
    start = np.zeros(2, dtype=np.intp)
    segments = np.zeros((0, 8))
    moves_cross(xy, xy, 0.0, 0.0, 1.0, 1.0, 1, 1, start, segments)
    valid_moves(
        xy, xy, np.ones(1, dtype=np.bool_), 0.0, 0.0, 1.0, 1, 1, np.zeros(1, dtype=np.uint8),
        np.zeros(256), 0, 0.0, 0.0, 1.0, 1.0, 1, 1, start, segments,
    )  # fmt: skip
    bilinear(xy, 0.0, 0.0, 1.0, 1, 1, np.zeros(1), np.ones(1), 1e-9)
    mmse(np.zeros(2), np.zeros((1, 2)))
    dtw(np.zeros(2), np.zeros((1, 2)))
    step_ends(xy, np.zeros((2, 1)), 0.7, 0.0, 0.1, 0.1)
    mags = np.zeros((1, 2), dtype=np.float32)
    live = np.zeros(1, dtype=np.intp)
    mass_centered_weights(
        mags, live, np.zeros(1), np.zeros(2, dtype=np.float32), 2,
        np.zeros(1, dtype=np.float32), 0.05, 4.2,
    )  # fmt: skip
    far = np.full((1, 2), 1e6, dtype=np.float32)  # outside the dummy plan and map
    log_w = np.zeros(1, dtype=np.float32)
    for known in (False, True):
        constrained_step(
            far, log_w, mags, np.zeros(2, dtype=np.float32), 2, np.zeros((2, 1)), 0.7, 0.0,
            0.1, 0.1, known, NO_PLAN, known, NO_GRID, known, 0.05, 4.2,
        )  # fmt: skip
    systematic_rows(log_w, 0.5)
