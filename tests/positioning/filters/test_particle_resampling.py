"""Systematic resampling and the effective sample size of ``particle_resampling``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.filters.particle_cloud import ParticleParams
from server.positioning.filters.particle_resampling import (
    effective_sample_size,
    resample_when_low,
    systematic_resample,
)
from tests.support.toy_plans import assert_normalised, assert_same, cloud, weights_of


@settings(max_examples=150, deadline=None)
@given(
    weights=st.lists(
        st.sampled_from([0.0, 1.0]) | st.floats(1e-6, 1.0), min_size=1, max_size=60
    ).filter(lambda w: sum(w) > 0),
    seed=st.integers(0, 2**32 - 1),
)
def test_systematic_resampling_keeps_n_and_copies_floor_or_ceil(
    weights: list[float], seed: int
) -> None:
    n = len(weights)
    p = cloud([(float(i), 0.0) for i in range(n)], weights=weights)
    q = systematic_resample(p, np.random.default_rng(seed))
    assert q.n == n
    assert q.count == p.count
    np.testing.assert_allclose(q.log_w, -math.log(n), rtol=1e-6)
    assert_normalised(q)
    copies = np.bincount(q.xy[:, 0].astype(np.intp), minlength=n)
    w = weights_of(p)
    w /= w.sum()
    expected = n * w
    assert np.all(copies >= np.floor(expected - 1e-6))
    assert np.all(copies <= np.ceil(expected + 1e-6))
    assert np.all(copies[w == 0.0] == 0)


@settings(max_examples=100, deadline=None)
@given(
    weights=st.lists(
        st.sampled_from([0.0, 1.0]) | st.floats(1e-6, 1.0), min_size=1, max_size=60
    ).filter(lambda w: sum(w) > 0),
    fraction=st.sampled_from([0.0, 0.5, 0.9, 1.0]),
    seed=st.integers(0, 2**32 - 1),
)
def test_resample_when_low_resamples_below_the_ess_threshold_only(
    weights: list[float], fraction: float, seed: int
) -> None:
    p = cloud([(float(i), 0.0) for i in range(len(weights))], weights=weights)
    params = ParticleParams(resample_ess_fraction=fraction)
    got = resample_when_low(p, np.random.default_rng(seed), params)
    if effective_sample_size(p) < fraction * p.n:
        assert_same(got, systematic_resample(p, np.random.default_rng(seed)))
    else:
        assert got is p


def test_effective_sample_size() -> None:
    assert effective_sample_size(cloud([(0.0, 0.0)] * 8)) == pytest.approx(8.0)
    assert effective_sample_size(cloud([(0.0, 0.0)] * 3, weights=[1, 0, 0])) == 1.0
