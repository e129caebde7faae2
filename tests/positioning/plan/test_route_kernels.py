"""The compiled segment profile equals its numpy reference, on random rasters and
segments in and out of them."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.plan.route_kernels import (
    segment_profiles,
    segment_profiles_reference,
)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 20), step=st.floats(0.1, 2.0))
def test_the_kernel_is_its_reference(seed: int, m: int, step: float) -> None:
    rng = np.random.default_rng(seed)
    clearance = rng.uniform(0, 3, size=(30, 40)).astype(np.float32)
    penalty = rng.uniform(0, 0.5, size=(30, 40)).astype(np.float32)
    a = rng.uniform(-2, 12, size=(m, 2))
    b = rng.uniform(-2, 12, size=(m, 2))
    args = (clearance, penalty, -1.0, 0.5, 0.25, step, 0.5)
    low, mean = segment_profiles(a, b, *args)
    ref_low, ref_mean = segment_profiles_reference(a, b, *args)
    np.testing.assert_array_equal(low, ref_low)
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-12, atol=1e-12)


def test_a_segment_outside_the_rasters_has_no_clearance_and_the_outside_penalty() -> None:
    clearance = np.ones((4, 4), dtype=np.float32)
    penalty = np.zeros((4, 4), dtype=np.float32)
    low, mean = segment_profiles(
        np.array([[10.0, 10.0]]), np.array([[12.0, 10.0]]), clearance, penalty,
        0.0, 0.0, 1.0, 0.5, 0.7,
    )  # fmt: skip
    assert low.tolist() == [0.0]
    assert mean.tolist() == [0.7]
