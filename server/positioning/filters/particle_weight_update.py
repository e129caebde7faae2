"""The particle filter's weight updates: the mass-centered magnetic update of
``papers/001_*`` (Shao et al.), the DTW baseline it is compared with, and any other
likelihood (``reweight``).

Mass-centered weight update (section III-C/D, eq b-c). After each step the map magnitude
at the new positions and the observed magnitude enter the windows, and::

    MMSE(i, t) = 1/W sum_{j=0}^{W-1} | |s_i^{t-j} - s_i^{t-j-1}| - |s_obs^{t-j} - s_obs^{t-j-1}| |
                                                                                         (b)
    w_i^t = K w_i^{t-1} / max(MMSE(i, t), T)                                             (c)

(``magnetic.sequence_distance.mmse``). Until the window is full the mean runs over the steps
it holds; with fewer than two magnitudes the weights are left alone. Weights are
kept as normalised logarithms: ``log w_i <- log w_i + log K - log max(MMSE, T)``, then
``log w_i -= log sum_j exp(log w_j)``. ``K`` multiplies every weight alike, so it cancels
in this normalisation (and in any resampling, which only sees relative weights): eq (c)
as printed does not depend on ``K``. The paper's sensitivity to ``K`` (Figure 9) must come from
something the paper does not print; ``K`` is applied anyway so the update is eq (c) as
written. A particle whose window meets an unknown map cell has no MMSE; it is neither
rewarded nor punished but gets the median ``max(MMSE, T)`` of the living particles that
have one (with none, the weights stay as they are). The paper's map covers every
reachable place, so it has no such rule.

DTW baseline (section IV-B, the Magicol method [11]): the same filter and window, with
the classic DTW distance ``D_i`` between the observed and the particle's magnetic
sequences over the window (``server.positioning.magnetic.sequence_distance.dtw_distance``) in place
of the MMSE::

    w_i^t = K w_i^{t-1} / max(D_i / L, T)

A Magicol-style matcher compares the magnetometer's samples over the last steps, not one
magnitude per step, and its cost grows with the square of the sequence length: the
sequences here hold ``dtw_samples_per_step`` samples per step (``L = W m + 1`` for a full
window; the default, 34, is a 50 Hz magnetometer over the paper's 0.67 s step period), so
the baseline does the work the paper timed. A step event carries one magnitude, and the
cloud keeps one map magnitude per particle and step, so both sequences are interpolated
linearly between those (``sequence_distance.densified``); ``dtw_samples_per_step = 1``
compares the step magnitudes alone. Only the sequence distance changes -- same award,
same cap, same window, same treatment of unknown cells. ``D_i / L`` is, like the MMSE, a
mean absolute error in µT per sample (a constant error ``e`` gives ``e`` in both), so
``T`` means the same for both. DTW compares raw magnitudes: unlike eq (b) it does not
cancel a magnetometer offset (section II, Figure 1).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from server.positioning.filters import particle_kernels
from server.positioning.filters.particle_cloud import (
    MapSampler,
    ParticleParams,
    Particles,
    Weighting,
    live_rows,
    normalised,
    take_rows,
    unchecked,
)
from server.positioning.magnetic import magnetic_kernels
from server.positioning.magnetic.sequence_distance import densified, dtw_distance, mmse


def mass_centered_update(
    p: Particles, observed_ut: float, sample_map: MapSampler, params: ParticleParams
) -> Particles:
    """Push a step's magnitudes into the windows and weight by eq (b)-(c).

    Parameters
    ----------
    p : Particles
        After ``particle_move.move`` (or just initialised, to record the first magnitude).
    observed_ut : float
        Field magnitude the phone measured at this step (µT), finite.
    sample_map : callable
        ``sample_map(floor (m,), xy (m, 2)) -> (m,)`` map magnitude, NaN where unknown;
        called with the living particles only.
    params : ParticleParams

    Returns
    -------
    Particles
    """
    return weight_update(p, observed_ut, sample_map, params, "mass_centered")


def dtw_update(
    p: Particles, observed_ut: float, sample_map: MapSampler, params: ParticleParams
) -> Particles:
    """As ``mass_centered_update`` with the DTW distance of the baseline (module docstring)."""
    return weight_update(p, observed_ut, sample_map, params, "dtw")


def weight_update(
    p: Particles,
    observed_ut: float,
    sample_map: MapSampler,
    params: ParticleParams,
    weighting: Weighting,
    compiled: bool = True,
) -> Particles:
    """Shared body of the two updates (module docstring); the mass-centered one after the
    map sampling in one compiled pass (``particle_kernels.mass_centered_weights``) unless
    ``compiled`` is False (the numpy reference below, which the DTW baseline runs)."""
    if not math.isfinite(observed_ut):
        raise ValueError(f"observed_ut must be finite, got {observed_ut}")
    slots = p.observed.shape[0]
    if slots != params.window + 1:
        raise ValueError(f"cloud window {slots - 1} differs from params.window {params.window}")
    finite = np.isfinite(p.log_w)
    n_live = int(np.count_nonzero(finite))
    live = live_rows(finite, n_live)
    xy = take_rows(p.xy, live).astype(np.float64)
    m_live = np.asarray(sample_map(take_rows(p.floor, live), xy), np.float64)
    if m_live.shape != (n_live,):
        raise ValueError(f"sample_map must return shape ({n_live},), got {m_live.shape}")
    observed = np.append(p.observed[1:], np.float32(observed_ut))
    count = min(p.count + 1, slots)
    if compiled and weighting == "mass_centered":
        rows = np.arange(p.n, dtype=np.intp) if isinstance(live, slice) else live
        mags, log_w32 = particle_kernels.mass_centered_weights(
            np.ascontiguousarray(p.mags),
            rows,
            m_live,
            observed,
            count,
            np.ascontiguousarray(p.log_w),
            params.t,
            math.log(params.k),
        )
        return unchecked(p, mags=mags, observed=observed, count=count, log_w=log_w32)
    # the windows move one slot to the left; the new magnitudes fill the last column
    mags = np.empty(p.mags.shape, dtype=np.float32)
    # shifted through the flat buffer (a strided 2-D copy is ~10x slower): row i's
    # last slot briefly holds row i + 1's oldest magnitude, then the new one
    mags.reshape(-1)[:-1] = p.mags.reshape(-1)[1:]
    if n_live == p.n:
        mags[:, -1] = m_live
    else:
        mags[:, -1] = np.nan
        mags[live, -1] = m_live
    out = unchecked(p, mags=mags, observed=observed, count=count)
    if count < 2 or n_live == 0:
        return out
    obs = observed[-count:]
    cand = take_rows(mags, live)[:, -count:]
    if weighting == "mass_centered":
        d = mmse(obs, cand)
    else:  # the sampled sequences of the DTW baseline (module docstring)
        per_step = params.dtw_samples_per_step
        seq, sampled = densified(obs, per_step), densified(cand, per_step)
        distance = magnetic_kernels.dtw if compiled else dtw_distance
        d = distance(seq, np.ascontiguousarray(sampled)) / seq.shape[0]
    known = np.isfinite(d)
    if not known.any():
        return out
    award = np.maximum(d, params.t)  # eq (c): K / max(distance, T)
    if not known.all():
        award[~known] = np.median(award[known])
    gain = np.log(award)
    np.subtract(math.log(params.k), gain, out=gain)
    log_w = p.log_w.astype(np.float64)
    if n_live == p.n:
        log_w += gain
    else:
        log_w[live] += gain
    return unchecked(out, log_w=normalised(log_w))


def mass_centered_update_reference(
    p: Particles, observed_ut: float, sample_map: MapSampler, params: ParticleParams
) -> Particles:
    """``mass_centered_update`` in numpy (the reference the compiled pass is tested
    against)."""
    return weight_update(p, observed_ut, sample_map, params, "mass_centered", compiled=False)


def reweight(p: Particles, log_likelihood: ArrayLike) -> Particles:
    """Weights multiplied by a likelihood given as its log per particle, normalised."""
    ll = np.asarray(log_likelihood, dtype=np.float64)
    log_w = normalised(np.add(p.log_w, ll, dtype=np.float64))
    if log_w.shape != p.log_w.shape:
        raise ValueError(f"log_likelihood must broadcast to shape {p.log_w.shape}, got {ll.shape}")
    return unchecked(p, log_w=log_w)
