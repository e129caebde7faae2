"""What the particle cloud says (``papers/001_*`` Algorithm 1 line 14): the position,
its uncertainty and the floor.

Estimate: the weighted mean ``sum w_i (x_i, y_i)`` (Algorithm 1 line 14 is the plain mean
of the resampled particles, the same thing in expectation) with the weighted covariance
``sum w_i (p_i - mean)(p_i - mean)^T`` as its uncertainty, the floor holding most weight,
and ``N_eff``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters.particle_cloud import Estimate, Particles, weights
from server.positioning.filters.particle_resampling import alive

FloatArray = NDArray[np.float64]


def estimate(p: Particles) -> Estimate:
    """Weighted mean, weighted covariance, majority floor by weight (and the weight on
    it) and ``N_eff``.

    Raises
    ------
    ValueError
        When every particle is dead.
    """
    if not alive(p):
        raise ValueError("a cloud whose particles are all dead has no estimate")
    w, d, mean = _weighted_mean(p)
    # d = xy - mean (in place of the float64 copy) and d * w[:, None], column by column:
    # broadcasting over rows of two is ~3x slower (the same numbers, the same C-ordered
    # arrays for the product)
    dw = np.empty_like(d)
    for axis in (0, 1):
        np.subtract(d[:, axis], mean[axis], out=d[:, axis])
        np.multiply(d[:, axis], w, out=dw[:, axis])
    cov = dw.T @ d
    cov = 0.5 * (cov + cov.T)
    floor, floor_prob = _majority_floor(p, w)
    ess = float(1.0 / np.dot(w, w))
    return Estimate(xy=mean, cov=cov, floor=floor, ess=ess, floor_prob=floor_prob)


def position(p: Particles) -> tuple[FloatArray, int]:
    """``estimate``'s mean and floor alone (what a scan compares with its fix), without
    the covariance.

    Raises
    ------
    ValueError
        When every particle is dead.
    """
    if not alive(p):
        raise ValueError("a cloud whose particles are all dead has no estimate")
    w, _, mean = _weighted_mean(p)
    return mean, _majority_floor(p, w)[0]


def _weighted_mean(p: Particles) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The weights, the positions (a float64 copy, the caller's to change) and their
    weighted mean, of a living cloud."""
    w = weights(p)
    xy = p.xy.astype(np.float64)
    return w, xy, w @ xy


def _majority_floor(p: Particles, w: FloatArray) -> tuple[int, float]:
    """The floor holding the most weight and the share it holds."""
    first = p.floor[0]
    if (p.floor == first).all():  # one floor: no need to sort them
        return int(first), 1.0
    floors, which = np.unique(p.floor, return_inverse=True)
    per_floor = np.bincount(which, weights=w)
    return int(floors[np.argmax(per_floor)]), float(per_floor.max())
