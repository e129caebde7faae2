"""The weight updates of ``particle_weight_update``: eq (b)-(c) of ``papers/001_*`` and the
DTW baseline by hand, and a likelihood of the wrong shape."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.positioning.filters.particle_cloud import ParticleParams
from server.positioning.filters.particle_weight_update import (
    dtw_update,
    mass_centered_update,
    reweight,
)
from server.positioning.magnetic.sequence_distance import densified, dtw_distance
from tests.support.toy_plans import assert_normalised, cloud, fixed_map, weights_of, with_window


def test_mass_centered_update_is_eq_c_by_hand() -> None:
    params = ParticleParams()
    observed = [40.0, 42.0, 41.0]  # |deltas| so far 2, 1; the new reading 45 adds 4
    p = with_window(
        cloud([(1.0, 1.0)] * 5),
        mags=[
            [50.0, 52.0, 51.0],  # deltas 2, 1, then 4: MMSE 0 -> capped at T
            [40.0, 40.0, 40.0],  # deltas 0, 0, then 0: MMSE (2 + 1 + 4) / 3
            [40.0, 43.0, 41.0],  # deltas 3, 2, then 5: MMSE 1
            [40.0, 42.0, 41.0],  # the next map value is unknown: median award
            [40.0, 41.0, 41.0],  # deltas 1, 0, then 2: MMSE (1 + 1 + 2) / 3
        ],
        observed=observed,
    )
    q = mass_centered_update(p, 45.0, fixed_map([55.0, 40.0, 46.0, math.nan, 43.0]), params)
    award = np.array([params.t, 7.0 / 3.0, 1.0, math.nan, 4.0 / 3.0])
    award[3] = np.median(award[[0, 1, 2, 4]])
    expected = (1.0 / award) / np.sum(1.0 / award)
    np.testing.assert_allclose(weights_of(q), expected, rtol=1e-5)
    assert q.count == 4
    np.testing.assert_array_equal(q.observed, [40.0, 42.0, 41.0, 45.0])
    np.testing.assert_array_equal(q.mags[:, -1], [55.0, 40.0, 46.0, math.nan, 43.0])
    assert_normalised(q)


def test_award_parameter_k_cancels_in_the_normalisation() -> None:
    p = with_window(cloud([(1.0, 1.0)] * 3), [[40.0], [41.0], [44.0]], [42.0])
    new = fixed_map([43.0, 43.5, 40.0])
    a = mass_centered_update(p, 44.0, new, ParticleParams(k=70.0))
    b = mass_centered_update(p, 44.0, new, ParticleParams(k=0.1))
    np.testing.assert_allclose(a.log_w, b.log_w, rtol=1e-6)
    assert not np.allclose(a.log_w, p.log_w)


def test_a_window_of_one_magnitude_weights_nothing() -> None:
    p = cloud([(1.0, 1.0), (2.0, 1.0)], weights=[0.25, 0.75])
    q = mass_centered_update(p, 44.0, fixed_map([40.0, 50.0]), ParticleParams())
    assert q.count == 1
    np.testing.assert_array_equal(q.log_w, p.log_w)
    r = dtw_update(p, 44.0, fixed_map([40.0, 50.0]), ParticleParams())
    np.testing.assert_array_equal(r.log_w, p.log_w)


def test_no_known_map_value_leaves_the_weights() -> None:
    p = with_window(cloud([(1.0, 1.0), (2.0, 1.0)], weights=[0.25, 0.75]), [[40.0], [41.0]], [42.0])
    q = mass_centered_update(p, 44.0, fixed_map([math.nan, math.nan]), ParticleParams())
    assert q.count == 2
    np.testing.assert_array_equal(q.log_w, p.log_w)


@pytest.mark.parametrize("per_step", [1, 5, 34])
def test_dtw_update_uses_the_same_award_with_the_dtw_distance(per_step: int) -> None:
    """Over the sampled sequences: ``per_step`` samples per step, ``L = 3 per_step + 1``."""
    params = ParticleParams(dtw_samples_per_step=per_step)
    observed = [40.0, 42.0, 41.0]
    mags = [[50.0, 52.0, 51.0], [40.0, 42.0, 41.0], [41.0, 41.0, 42.0], [40.0, 40.0, 42.0]]
    new = [55.0, 45.0, 44.0, 45.0]
    p = with_window(cloud([(1.0, 1.0)] * 4), mags, observed)
    q = dtw_update(p, 45.0, fixed_map(new), params)
    full = np.column_stack([mags, new])
    length = 3 * per_step + 1
    obs, cand = densified([*observed, 45.0], per_step), densified(full, per_step)
    assert obs.shape == (length,)
    assert cand.shape == (4, length)
    d = dtw_distance(obs, cand) / length  # mean error per sample
    assert d[1] == 0.0  # the identical sequence: capped at T
    award = np.maximum(d, params.t)
    np.testing.assert_allclose(weights_of(q), (1 / award) / np.sum(1 / award), rtol=1e-5)


def test_reweight_refuses_a_likelihood_of_another_length() -> None:
    with pytest.raises(ValueError, match="broadcast"):
        reweight(cloud([(0.0, 0.0)] * 3), np.zeros((3, 1)))
