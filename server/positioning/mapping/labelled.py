"""Positions of timed samples along a walk whose ground truth is known only at waypoints.

A surveyor walks a path and taps the screen at known points (waypoints); the sensor
samples in between carry only a time. This is how the Indoor Location Competition 2.0
(ILC) traces label their data: positions are given at the waypoints alone, and the usual
practice is to place the samples between two waypoints by linear interpolation in time.
The assumption is that the surveyor walks straight from one tap to the next at constant
speed. For waypoints ``(t_j, p_j)`` sorted by time and a sample at ``t`` with
``t_j <= t <= t_{j+1}``::

    p(t) = p_j + (t - t_j) / (t_{j+1} - t_j) * (p_{j+1} - p_j)

Rules at the edges:

* a sample before the first or after the last waypoint is invalid, unless it is at most
  ``max_extrapolation_ms`` away from that end waypoint; it then takes the end waypoint's
  position (clamped, not extrapolated along the first or last leg);
* waypoints with the same time (a double tap) give a jump, not a division by zero: a
  sample at that time takes the last of them, and samples before it run towards the
  first of them;
* invalid samples get NaN positions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def interpolate_track(
    waypoint_t_ms: ArrayLike,
    waypoint_xy_m: ArrayLike,
    t_ms: ArrayLike,
    *,
    max_extrapolation_ms: int = 0,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Positions of samples between ground-truth waypoints (see the module docstring).

    Parameters
    ----------
    waypoint_t_ms : array_like, shape (n,)
        Waypoint times in ms. Sorted here (stably, so waypoints with equal times keep
        their order).
    waypoint_xy_m : array_like, shape (n, 2)
        Waypoint positions in metres.
    t_ms : array_like, shape (m,)
        Sample times in ms, in any order.
    max_extrapolation_ms : int
        How far before the first or after the last waypoint a sample may be and still be
        placed (at that waypoint).

    Returns
    -------
    xy_m : ndarray, shape (m, 2), float64
        Sample positions; NaN where not valid.
    valid : ndarray, shape (m,), bool
        True where the sample lies within the waypoints' time span (widened by
        ``max_extrapolation_ms``).

    Raises
    ------
    ValueError
        On mismatched shapes or a negative ``max_extrapolation_ms``.
    """
    wt = np.asarray(waypoint_t_ms, dtype=np.float64).ravel()
    wxy = np.asarray(waypoint_xy_m, dtype=np.float64)
    t = np.asarray(t_ms, dtype=np.float64).ravel()
    if wxy.size == 0 and wt.size == 0:
        wxy = wxy.reshape(0, 2)
    if wxy.shape != (wt.size, 2):
        raise ValueError(f"waypoint_xy_m must have shape ({wt.size}, 2), got {wxy.shape}")
    if max_extrapolation_ms < 0:
        raise ValueError(f"max_extrapolation_ms must be >= 0, got {max_extrapolation_ms}")

    xy = np.full((t.size, 2), np.nan)
    if wt.size == 0:
        return xy, np.zeros(t.size, dtype=bool)
    order = np.argsort(wt, kind="stable")
    wt, wxy = wt[order], wxy[order]
    valid = (t >= wt[0] - max_extrapolation_ms) & (t <= wt[-1] + max_extrapolation_ms)
    if wt.size == 1:
        xy[valid] = wxy[0]
        return xy, valid

    # leg j runs from waypoint j to j + 1; the last waypoint at or before t starts it
    j = np.clip(np.searchsorted(wt, t, side="right") - 1, 0, wt.size - 2)
    t0, t1 = wt[j], wt[j + 1]
    span = t1 - t0
    frac = np.where(t >= t1, 1.0, 0.0)  # at or after the leg's end (or before its start)
    moving = (span > 0) & (t > t0) & (t < t1)
    frac[moving] = (t[moving] - t0[moving]) / span[moving]
    p0, p1 = wxy[j], wxy[j + 1]
    xy[valid] = (p0 + frac[:, None] * (p1 - p0))[valid]
    return xy, valid
