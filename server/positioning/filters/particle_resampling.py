"""Resampling of the particle cloud (``papers/001_*`` Algorithm 1), and the effective
sample size that says when.

Resampling: systematic (``papers/001_*`` ref [24], Arulampalam et al. 2002, Algorithm 2)
with one uniform draw ``u ~ U[0, 1/N)`` and the ``N`` points ``u + k/N``; particle ``i``
is copied ``floor(N w_i)`` or ``ceil(N w_i)`` times; weights reset to ``1/N``. Algorithm 1
resamples at every step; here (``particle.step``) the cloud is resampled when the
effective sample size ``N_eff = 1 / sum w_i^2`` falls below ``resample_ess_fraction * N``
(ref [24] resamples below a threshold ``N_T``; ``N_T = N/2`` by default, the common
choice), which keeps the weights' memory across steps where the field says little;
``resample_ess_fraction = 1`` resamples at every step whose weights are not all equal, as
Algorithm 1 does (on the acceptance corridor of the tests both converge alike).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters.particle_cloud import ParticleParams, Particles, unchecked, weights

FloatArray = NDArray[np.float64]


def alive(p: Particles) -> bool:
    """Whether any particle has a finite weight."""
    return bool(np.isfinite(p.log_w).any())


def effective_sample_size(p: Particles) -> float:
    """``N_eff = 1 / sum w_i^2`` (0 for a dead cloud)."""
    if not alive(p):
        return 0.0
    w = weights(p)
    return float(1.0 / np.dot(w, w))


def systematic_resample(p: Particles, rng: np.random.Generator) -> Particles:
    """Systematic resampling (ref [24]); ``N`` kept, weights reset to ``1/N``.

    Parameters
    ----------
    p : Particles
        A living cloud.
    rng : numpy.random.Generator
        Draws one uniform number.

    Returns
    -------
    Particles
        Rows (position, floor, map magnitudes) copied by ``searchsorted`` of the points
        ``(u + k) / N`` in the cumulative weights; the observed window is shared.

    Raises
    ------
    ValueError
        When every particle is dead.
    """
    if not alive(p):
        raise ValueError("cannot resample a cloud whose particles are all dead")
    return _resample(p, weights(p), rng)


def _resample(p: Particles, w: FloatArray, rng: np.random.Generator) -> Particles:
    """``systematic_resample`` of a living cloud with weights ``w`` (``_weights``)."""
    n = p.n
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    # points below 1, so the index stays below n; a dead particle (zero weight) spans an
    # empty interval [cdf[i-1], cdf[i]) and is never chosen
    points = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cdf, points, side="right")
    return unchecked(
        p,
        xy=np.take(p.xy, idx, axis=0),
        floor=p.floor.take(idx),
        log_w=np.full(n, -math.log(n), dtype=np.float32),
        mags=np.take(p.mags, idx, axis=0),
    )


def resample_when_low(p: Particles, rng: np.random.Generator, params: ParticleParams) -> Particles:
    """``systematic_resample`` of a living cloud whose ``N_eff`` fell below
    ``params.resample_ess_fraction * N`` (module docstring, "Resampling"), else the cloud
    as it is."""
    w = weights(p)  # as effective_sample_size and systematic_resample, computed once
    if 1.0 / np.dot(w, w) < params.resample_ess_fraction * p.n:
        return _resample(p, w, rng)
    return p
