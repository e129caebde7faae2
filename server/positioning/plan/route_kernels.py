"""Compiled (numba) profile of segments over a floor's rasters, for pulling a route
straight (``routes.pulled_straight``): along each segment, sampled every ``step_m``
(ends included, at least two samples), the lowest clearance and the mean wall penalty
(the trapezoid rule over the samples, as the graph's edge costs average their two ends'
penalties). One pass per segment where numpy needs several temporary arrays of samples;
``segment_profiles_reference`` is the same in numpy, for the tests.

Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@njit(cache=True)
def segment_profiles(
    a: FloatArray,
    b: FloatArray,
    clearance: NDArray[np.float32],
    penalty: NDArray[np.float32],
    x0: float,
    y0: float,
    cell_m: float,
    step_m: float,
    outside_penalty: float,
) -> tuple[FloatArray, FloatArray]:
    """Per segment ``a[k] -> b[k]`` (shapes (m, 2)): the lowest clearance (0 outside the
    rasters) and the mean penalty (``outside_penalty`` outside) of its samples."""
    m = a.shape[0]
    ny, nx = clearance.shape
    low = np.empty(m)
    mean = np.empty(m)
    for k in range(m):
        dx = b[k, 0] - a[k, 0]
        dy = b[k, 1] - a[k, 1]
        n = max(2, math.ceil(math.hypot(dx, dy) / step_m) + 1)
        lowest = math.inf
        total = 0.0
        previous = 0.0
        for i in range(n):
            t = i / (n - 1)
            ix = math.floor((a[k, 0] + t * dx - x0) / cell_m)
            iy = math.floor((a[k, 1] + t * dy - y0) / cell_m)
            if 0 <= ix < nx and 0 <= iy < ny:
                c = float(clearance[iy, ix])
                p = float(penalty[iy, ix])
            else:
                c = 0.0
                p = outside_penalty
            lowest = min(lowest, c)
            if i > 0:
                total += (previous + p) / 2.0
            previous = p
        low[k] = lowest
        mean[k] = total / (n - 1)
    return low, mean


def segment_profiles_reference(
    a: FloatArray,
    b: FloatArray,
    clearance: NDArray[np.float32],
    penalty: NDArray[np.float32],
    x0: float,
    y0: float,
    cell_m: float,
    step_m: float,
    outside_penalty: float,
) -> tuple[FloatArray, FloatArray]:
    """``segment_profiles`` in numpy, one segment at a time."""
    ny, nx = clearance.shape
    low, mean = np.empty(a.shape[0]), np.empty(a.shape[0])
    for k in range(a.shape[0]):
        n = max(2, math.ceil(float(np.hypot(*(b[k] - a[k]))) / step_m) + 1)
        t = np.arange(n) / (n - 1)
        points = a[k] + t[:, None] * (b[k] - a[k])
        ix = np.floor((points[:, 0] - x0) / cell_m).astype(np.int64)
        iy = np.floor((points[:, 1] - y0) / cell_m).astype(np.int64)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        c = np.zeros(n)
        p = np.full(n, outside_penalty)
        c[inside] = clearance[iy[inside], ix[inside]]
        p[inside] = penalty[iy[inside], ix[inside]]
        low[k] = c.min()
        mean[k] = float(np.sum((p[:-1] + p[1:]) / 2.0)) / (n - 1)
    return low, mean
