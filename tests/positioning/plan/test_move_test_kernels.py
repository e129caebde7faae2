"""The compiled move test (``move_test_kernels``) against its numpy references, on random
inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.plan import move_test_kernels
from server.positioning.plan.floor_plan import valid_moves, valid_moves_reference
from server.positioning.plan.wall_index import moves_cross
from tests.support.toy_plans import room


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), reach=st.sampled_from([0.3, 1.0, 4.0]))
def test_moves_cross_matches_the_numpy_index(seed: int, reach: float) -> None:
    """Random moves over the toy room, short and long, some ending exactly on walls."""
    rng = np.random.default_rng(seed)
    index = room()._index
    n = 400
    a = rng.uniform([-2, -2], [22, 12], (n, 2))
    b = a + rng.normal(0, reach, (n, 2))
    b[:20, 0] = 10.0  # onto the thin wall at x = 10
    b[20:40] = a[20:40]  # no move at all
    expected = moves_cross(index, a, b)
    got = move_test_kernels.moves_cross(a, b, *index.kernel_args())
    np.testing.assert_array_equal(got, expected)
    assert expected.any()
    assert not expected.all()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), reach=st.sampled_from([0.2, 0.7, 3.0]))
def test_valid_moves_matches_the_numpy_reference(seed: int, reach: float) -> None:
    rng = np.random.default_rng(seed)
    n = 500
    a = rng.uniform([-1, -1], [21, 11], (n, 2))
    b = a + rng.normal(0, reach, (n, 2))
    a[:5, 0] = np.nan  # non-finite starts and ends
    b[5:10, 1] = np.inf
    got = valid_moves(room(), a, b)
    np.testing.assert_array_equal(got, valid_moves_reference(room(), a, b))
    assert got.any()
    assert not got.all()
