"""The estimate of a particle cloud (``particle_estimate``) by hand: mean, covariance,
floor."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.filters.particle_estimate import estimate, position
from tests.support.toy_plans import cloud


def test_estimate_by_hand() -> None:
    p = cloud(
        [(0.0, 0.0), (2.0, 0.0), (0.0, 4.0), (2.0, 4.0)],
        weights=[0.1, 0.2, 0.3, 0.4],
        floors=[-1, -1, 2, 3],
    )
    e = estimate(p)
    np.testing.assert_allclose(e.xy, [1.2, 2.8], rtol=1e-6)
    # var x = 0.6 * 0.4 * 4, var y = 0.7 * 0.3 * 16, cov = sum w (x - 1.2)(y - 2.8)
    cov_xy = 0.1 * 1.2 * 2.8 - 0.2 * 0.8 * 2.8 - 0.3 * 1.2 * 1.2 + 0.4 * 0.8 * 1.2
    np.testing.assert_allclose(e.cov, [[0.96, cov_xy], [cov_xy, 3.36]], rtol=1e-5)
    assert e.floor == 3  # 0.4 on floor 3 against 0.3 on each of -1 and 2
    assert e.ess == pytest.approx(1.0 / 0.3, rel=1e-5)


def test_estimate_floor_is_the_heaviest_including_negative_levels() -> None:
    p = cloud([(0.0, 0.0)] * 4, weights=[0.3, 0.3, 0.35, 0.05], floors=[-1, -1, 2, 3])
    assert estimate(p).floor == -1


@settings(max_examples=100, deadline=None)
@given(
    weights=st.lists(
        st.sampled_from([0.0, 1.0]) | st.floats(1e-6, 1.0), min_size=1, max_size=60
    ).filter(lambda w: sum(w) > 0),
    floor_of=st.lists(st.integers(-2, 3), min_size=60, max_size=60),
    seed=st.integers(0, 2**32 - 1),
)
def test_position_is_the_estimates_mean_and_floor(
    weights: list[float], floor_of: list[int], seed: int
) -> None:
    n = len(weights)
    xy = np.random.default_rng(seed).normal(0.0, 20.0, (n, 2))
    p = cloud([(float(x), float(y)) for x, y in xy], weights=weights, floors=floor_of[:n])
    mean, floor = position(p)
    e = estimate(p)
    np.testing.assert_array_equal(mean, e.xy)
    assert floor == e.floor
