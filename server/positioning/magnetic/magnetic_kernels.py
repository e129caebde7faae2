"""Compiled (numba) forms of the particle filter's magnetic loops: the map sampled at
each particle and the sequence distances of its weight update, one particle at a time,
where numpy needs several passes over temporary arrays.

Each kernel computes what its numpy reference computes, with the same float64 operations
in the same order, so the answers agree exactly (the tests compare them on random
inputs):

* ``bilinear``: ``magnetic._bilinear`` -- bilinear interpolation over the known corners,
  NaN outside the grid or where the known corners weigh too little;
* ``mmse``: ``sequence_distance.mmse`` -- eq (b) of ``papers/001_*`` per candidate row,
  ``inf`` for a row with a NaN;
* ``dtw``: ``sequence_distance.dtw_distance`` per candidate, two rows of the table at a
  time.

Compiled on first use and cached on disk (``cache=True``); no Python object crosses into
them. ``filters.particle_kernels.constrained_step`` runs ``bilinear`` in its fused step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
# a magnetic grid as ``bilinear`` and ``particle_kernels.constrained_step`` take it
# (``field_grid.kernel_args``)
GridArgs = tuple[float, float, float, int, int, FloatArray, FloatArray, float]


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
