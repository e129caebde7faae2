"""Placing a walk's samples on the floor from its steps and a few known points (anchors).

A crowdsourced walk knows where it is only at its anchors: an entrance or an elevator
(BLE beacon, GNSS fix), or a surveyor's tap on the map (a waypoint). In between, the
phone's steps tell how it moved. This module turns steps + anchors into a position (and
an uncertainty) for any sample time of the walk, in two stages:

1. **Alignment** (``papers/003_*`` section IV-C, eq 5-7): the dead-reckoned track
   ``p_i`` (steps integrated from the origin with the tracker's heading, which is
   relative: its offset from north is unknown) is mapped onto the anchors by one
   similarity transform ``x = s R p + t``, fitted by least squares (Umeyama,
   ``alignment.similarity_transform``) between the track's positions at the anchor
   times and the anchors. With two anchors it is exact at both; it fixes the heading
   offset and a step-length scale. A scale outside ``[min_scale, max_scale]`` means the
   steps and the anchors disagree, and the walk is refused.
2. **Smoothing** (``papers/000_*`` section II, eq 8-9): between consecutive anchors the
   aligned steps are smoothed forward and backward (``alignment.smooth_between_anchors``),
   which spreads the leg's remaining closing error and gives each position its
   uncertainty. A leg whose forward solution misses its end anchor by more than
   ``lambda_d = 20 m`` (Li's endpoint test) is not used.

A sample at time ``t`` inside a used leg takes the position linearly interpolated between
the smoothed positions after the steps around ``t`` (the anchor positions at the leg's
ends). Samples before the first or after the last anchor, and in refused legs, are not
placed. Steps are ``(t_ms, length_m, heading_rad)`` with the heading clockwise from the
tracker's reference (x east, y north: a step moves by ``(L sin h, L cos h)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from server.positioning.mapping.alignment import (
    MAX_ENDPOINT_MISMATCH_M,
    DeadReckoningNoise,
    similarity_transform,
    smooth_between_anchors,
)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PlacementParams:
    # step-length scale the anchors may imply (ours; the paper has none): the paper's own
    # step-length constants overestimate ILC walkers' steps by ~24 % (bench/accuracy.md)
    min_scale: float = 0.5
    max_scale: float = 1.6
    # RMS distance of the anchors from their centre below which they cannot fix a rotation
    # (a walk that starts and ends at one elevator with nothing in between)
    min_spread_m: float = 1.5
    max_mismatch_m: float = MAX_ENDPOINT_MISMATCH_M  # lambda_d of papers/000_*
    noise: DeadReckoningNoise = field(default_factory=DeadReckoningNoise)


@dataclass(frozen=True)
class Placement:
    """Positions of the query times.

    Attributes
    ----------
    xy_m : ndarray, shape (n, 2)
        Positions (m); NaN where not placed.
    std_m : ndarray, shape (n,)
        Location uncertainty (m, 2-D RMS); NaN where not placed.
    placed : ndarray, shape (n,), bool
    scale, rotation_rad : float
        The alignment (NaN when refused).
    not_used : tuple of str
        Why parts of the walk were not used, for the upload report.
    not_used_samples : tuple of int
        How many of the query samples each reason of ``not_used`` left unplaced (each
        sample counted for one reason at most).
    """

    xy_m: FloatArray
    std_m: FloatArray
    placed: NDArray[np.bool_]
    scale: float
    rotation_rad: float
    not_used: tuple[str, ...]
    not_used_samples: tuple[int, ...] = ()


def place_samples(
    step_t_ms: ArrayLike,
    step_length_m: ArrayLike,
    step_heading_rad: ArrayLike,
    anchor_t_ms: ArrayLike,
    anchor_xy_m: ArrayLike,
    query_t_ms: ArrayLike,
    params: PlacementParams | None = None,
) -> Placement:
    """Positions of samples taken at ``query_t_ms`` (see the module docstring).

    Parameters
    ----------
    step_t_ms, step_length_m, step_heading_rad : array_like, shape (k,)
        The steps, sorted by time; headings in radians, clockwise.
    anchor_t_ms : array_like, shape (a,)
        Times of the known positions, sorted, at least two.
    anchor_xy_m : array_like, shape (a, 2)
        The known positions (m).
    query_t_ms : array_like, shape (n,)
        Times of the samples to place.
    params : PlacementParams, optional

    Returns
    -------
    Placement
    """
    p = params or PlacementParams()
    t = np.asarray(step_t_ms, dtype=np.float64)
    length = np.asarray(step_length_m, dtype=np.float64)
    heading = np.asarray(step_heading_rad, dtype=np.float64)
    at = np.asarray(anchor_t_ms, dtype=np.float64)
    axy = np.asarray(anchor_xy_m, dtype=np.float64)
    q = np.asarray(query_t_ms, dtype=np.float64)
    if not (t.ndim == 1 and length.shape == t.shape and heading.shape == t.shape):
        raise ValueError("step_t_ms, step_length_m and step_heading_rad must share shape (k,)")
    if at.ndim != 1 or axy.shape != (at.size, 2):
        raise ValueError(f"anchor_xy_m must have shape ({at.size}, 2), got {axy.shape}")
    if q.ndim != 1:
        raise ValueError(f"query_t_ms must have shape (n,), got {q.shape}")
    if at.size < 2:
        raise ValueError("at least two anchors are needed")
    if np.any(np.diff(at) < 0) or np.any(np.diff(t) < 0):
        raise ValueError("steps and anchors must be sorted by time")
    ok = np.isfinite(length) & np.isfinite(heading)
    t, length, heading = t[ok], length[ok], heading[ok]

    out_xy = np.full((q.size, 2), np.nan)
    out_std = np.full(q.size, np.nan)
    nan = float("nan")

    def refused(reason: str) -> Placement:
        placed = np.zeros(q.size, dtype=bool)
        return Placement(out_xy, out_std, placed, nan, nan, (reason,), (q.size,))

    # dead reckoning from the origin; position after each step, and at any time
    vectors = np.column_stack([length * np.sin(heading), length * np.cos(heading)])
    track = np.vstack([np.zeros((1, 2)), np.cumsum(vectors, axis=0)])
    at_anchor = track[np.searchsorted(t, at, side="right")]
    spread = min(_spread(at_anchor), _spread(axy))
    if spread < p.min_spread_m:
        return refused(
            f"the anchors lie within {spread:.1f} m of their centre (by the steps or on the "
            f"map): too close together to turn the steps onto them (at least "
            f"{p.min_spread_m:g} m)"
        )
    fit = similarity_transform(at_anchor, axy)
    if not (p.min_scale <= fit.scale <= p.max_scale):
        return refused(
            f"steps and anchors disagree: the anchors stretch the steps by {fit.scale:.2f} "
            f"(allowed {p.min_scale}-{p.max_scale})"
        )
    aligned = vectors @ fit.matrix.T  # the rotation and scale act on every step

    refused_legs: list[tuple[str, NDArray[np.bool_]]] = []  # why, and the leg's samples
    placed = np.zeros(q.size, dtype=bool)
    for k in range(at.size - 1):
        t0, t1 = at[k], at[k + 1]
        in_leg = (t > t0) & (t <= t1)
        leg = smooth_between_anchors(aligned[in_leg], axy[k], axy[k + 1], noise=p.noise)
        miss = float(np.linalg.norm(leg.forward_xy[-1] - axy[k + 1]))
        if miss > p.max_mismatch_m:
            why = (
                f"leg {k + 1} ({(t1 - t0) / 1000:.0f} s): its steps end {miss:.1f} m from the "
                f"next anchor (more than {p.max_mismatch_m:g} m)"
            )
            refused_legs.append((why, (q >= t0) & (q <= t1)))
            continue
        # knots: the leg's start, each step, the leg's end (positions after each step)
        knot_t = np.concatenate([[t0], t[in_leg], [t1]])
        knot_xy = np.vstack([leg.xy, leg.xy[-1:]])
        knot_std = np.concatenate([leg.std_m, leg.std_m[-1:]])
        rows = (q >= t0) & (q <= t1) & ~placed
        if t1 == t0:
            continue
        out_xy[rows, 0] = np.interp(q[rows], knot_t, knot_xy[:, 0])
        out_xy[rows, 1] = np.interp(q[rows], knot_t, knot_xy[:, 1])
        out_std[rows] = np.interp(q[rows], knot_t, knot_std)
        placed |= rows
    # a sample at the end of a refused leg may be placed by its neighbour, or be the start
    # of the next refused leg: counted once, for the first leg it is lost to
    not_used: list[tuple[str, int]] = []
    counted = placed.copy()
    for why, in_leg_q in refused_legs:
        not_used.append((why, int(np.count_nonzero(in_leg_q & ~counted))))
        counted |= in_leg_q
    outside = int(np.count_nonzero((q < at[0]) | (q > at[-1])))
    if outside:
        not_used.append((f"{outside} samples before the first or after the last anchor", outside))
    return Placement(
        out_xy,
        out_std,
        placed,
        fit.scale,
        fit.rotation_rad,
        tuple(why for why, _ in not_used),
        tuple(n for _, n in not_used),
    )


def _spread(points: FloatArray) -> float:
    """RMS distance of points from their centroid (m)."""
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))
