"""Straight stretches of a walked track: a RANSAC line, and the outliers moved onto it.

``ransac_line`` / ``project_to_line`` are ``papers/003_*`` section III, eq 2-3: a
straight-line model of the step positions of a straight stretch (the steps labelled
``turns.STRAIGHT`` of one segment), found by RANSAC, and outlying step positions (more
than 1.5 m from it) moved onto the line; ``straighten_track`` applies them to every
stretch of a track.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from server.positioning.motion.turns import STRAIGHT

FloatArray = NDArray[np.float64]


def ransac_line(
    points: FloatArray,
    threshold_m: float = 1.5,
    rng: np.random.Generator | None = None,
    max_pairs: int = 500,
) -> tuple[float, float, float] | None:
    """Line ``a x + b y + c = 0`` (with ``a² + b² = 1``) through the most step positions
    within ``threshold_m`` (RANSAC, ``papers/003_*`` section III), refitted by total
    least squares to its inliers.

    Every pair of points is tried when there are at most ``max_pairs`` of them, otherwise
    ``max_pairs`` pairs drawn with ``rng``. None for fewer than two distinct points.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    if n < 2:
        return None
    i, j = np.triu_indices(n, k=1)
    if i.size > max_pairs:
        if rng is None:
            raise ValueError("rng is needed to sample pairs from this many points")
        pick = rng.choice(i.size, size=max_pairs, replace=False)
        i, j = i[pick], j[pick]
    d = pts[j] - pts[i]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 1e-9
    if not ok.any():
        return None
    i, d, length = i[ok], d[ok], length[ok]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    c = -np.einsum("ij,ij->i", normal, pts[i])
    dist = np.abs(pts @ normal.T + c)  # (n, pairs)
    best = int(np.argmax((dist <= threshold_m).sum(axis=0)))
    inliers = pts[dist[:, best] <= threshold_m]
    centre = inliers.mean(axis=0)
    _, _, vt = np.linalg.svd(inliers - centre)
    a, b = float(vt[-1, 0]), float(vt[-1, 1])  # normal: the direction of least spread
    return a, b, float(-(a * centre[0] + b * centre[1]))


def project_to_line(
    points: FloatArray, line: tuple[float, float, float], threshold_m: float = 1.5
) -> FloatArray:
    """Move points farther than ``threshold_m`` from the line onto it (``papers/003_*``
    eq 2-3: the perpendicular distance and the foot of the perpendicular)."""
    a, b, c = line
    pts = np.array(points, dtype=np.float64)
    norm2 = a * a + b * b
    signed = (pts @ np.array([a, b]) + c) / math.sqrt(norm2)  # eq 2 without the abs
    far = np.abs(signed) > threshold_m
    pts[far] -= np.outer(signed[far] / math.sqrt(norm2), [a, b])
    return pts


def straighten_track(
    xy: FloatArray,
    status: NDArray[np.int64],
    segment: NDArray[np.int64],
    rng: np.random.Generator,
    threshold_m: float = 1.5,
    min_points: int = 4,
) -> FloatArray:
    """Step positions of a walked track with the outliers of each straight stretch moved
    onto its RANSAC line (``papers/003_*`` section III, eq 2-3).

    A stretch is the straight-walking steps (``status == STRAIGHT``) of one ``segment``;
    stretches of fewer than ``min_points`` steps, and steps while turning, are left as
    they are. This is the track generation of the crowdsourcing pipeline: it looks at a
    whole stretch, so it is for walks already recorded, not for live tracking. ``rng``
    draws the RANSAC pairs of stretches too long to try every pair.
    """
    out = np.array(xy, dtype=np.float64)
    straight = status == STRAIGHT
    for seg in np.unique(segment[straight]):
        rows = np.flatnonzero(straight & (segment == seg))
        if rows.size < min_points:
            continue
        line = ransac_line(out[rows], threshold_m, rng)
        if line is not None:
            out[rows] = project_to_line(out[rows], line, threshold_m)
    return out
