"""Sample positions between ground-truth waypoints."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.mapping.labelled import interpolate_track

WT = np.array([0, 1000, 3000])
WXY = np.array([(0.0, 0.0), (10.0, 0.0), (10.0, 20.0)])


def test_midpoints_are_exact() -> None:
    xy, valid = interpolate_track(WT, WXY, [500, 2000, 1250])
    assert valid.all()
    np.testing.assert_array_equal(xy, [(5.0, 0.0), (10.0, 10.0), (10.0, 2.5)])


def test_waypoint_times_give_the_waypoints() -> None:
    xy, valid = interpolate_track(WT, WXY, WT)
    assert valid.all()
    np.testing.assert_array_equal(xy, WXY)


def test_samples_outside_the_walk_are_invalid() -> None:
    xy, valid = interpolate_track(WT, WXY, [-1, 0, 3000, 3001])
    np.testing.assert_array_equal(valid, [False, True, True, False])
    assert np.isnan(xy[~valid]).all()
    np.testing.assert_array_equal(xy[valid], [(0.0, 0.0), (10.0, 20.0)])


def test_extrapolation_window_clamps_to_the_end_waypoints() -> None:
    t = [-101, -100, -1, 3050, 3100, 3101]
    xy, valid = interpolate_track(WT, WXY, t, max_extrapolation_ms=100)
    np.testing.assert_array_equal(valid, [False, True, True, True, True, False])
    np.testing.assert_array_equal(xy[valid], [(0.0, 0.0), (0.0, 0.0), (10.0, 20.0), (10.0, 20.0)])


def test_duplicate_times_jump_without_dividing_by_zero() -> None:
    # a double tap at t = 1000: the walk reaches B, then continues from C
    wt = [0, 1000, 1000, 2000]
    wxy = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (20.0, 10.0)]
    xy, valid = interpolate_track(wt, wxy, [500, 900, 1000, 1500, 2000])
    assert valid.all()
    np.testing.assert_allclose(xy, [(5.0, 0.0), (9.0, 0.0), (10.0, 10.0), (15.0, 10.0), (20, 10)])


def test_duplicate_times_at_the_ends() -> None:
    wt = [0, 0, 1000, 1000]
    wxy = [(0.0, 0.0), (1.0, 0.0), (3.0, 0.0), (4.0, 0.0)]
    xy, valid = interpolate_track(wt, wxy, [-10, 0, 500, 1000, 1010], max_extrapolation_ms=10)
    assert valid.all()
    np.testing.assert_allclose(xy[:, 0], [0.0, 1.0, 2.0, 4.0, 4.0])


def test_one_waypoint_and_none() -> None:
    xy, valid = interpolate_track([1000], [(2.0, 3.0)], [999, 1000, 1001], max_extrapolation_ms=1)
    assert valid.all()
    np.testing.assert_array_equal(xy, [(2.0, 3.0)] * 3)
    xy, valid = interpolate_track([1000], [(2.0, 3.0)], [999])
    assert not valid.any()
    xy, valid = interpolate_track([], [], [0, 1])
    assert xy.shape == (2, 2)
    assert not valid.any()
    assert np.isnan(xy).all()


def test_waypoints_are_sorted_and_epoch_times_stay_exact() -> None:
    t0 = 1_600_000_000_123
    xy, valid = interpolate_track([t0 + 3000, t0, t0 + 1000], WXY[[2, 0, 1]], [t0 + 500, t0 + 2000])
    assert valid.all()
    np.testing.assert_array_equal(xy, [(5.0, 0.0), (10.0, 10.0)])


def test_matches_numpy_interp_for_distinct_times() -> None:
    rng = np.random.default_rng(1)
    wt = np.cumsum(rng.integers(1, 2000, size=20))
    wxy = rng.uniform(-50.0, 50.0, size=(20, 2))
    t = rng.integers(wt[0], wt[-1], size=200, endpoint=True)
    xy, valid = interpolate_track(wt, wxy, t)
    assert valid.all()
    np.testing.assert_allclose(xy[:, 0], np.interp(t, wt, wxy[:, 0]), atol=1e-9)
    np.testing.assert_allclose(xy[:, 1], np.interp(t, wt, wxy[:, 1]), atol=1e-9)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="waypoint_xy_m"):
        interpolate_track([0, 1], [(0.0, 0.0)], [0])
    with pytest.raises(ValueError, match="max_extrapolation_ms"):
        interpolate_track(WT, WXY, [0], max_extrapolation_ms=-1)


def _on_segment(p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
    """p lies on the segment ab: its distances to a and b add up to |ab|."""
    d = float(np.linalg.norm(p - a) + np.linalg.norm(p - b) - np.linalg.norm(b - a))
    return abs(d) <= 1e-6


@given(
    gaps=st.lists(st.integers(0, 5000), min_size=1, max_size=8),
    coords=st.lists(st.floats(-100.0, 100.0), min_size=18, max_size=18),
    fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=10),
)
def test_points_lie_between_their_neighbouring_waypoints(
    gaps: list[int], coords: list[float], fractions: list[float]
) -> None:
    wt = np.concatenate([[0], np.cumsum(gaps)]).astype(np.int64)
    wxy = np.array(coords[: 2 * wt.size], dtype=np.float64).reshape(-1, 2)
    t = np.round(np.array(fractions) * wt[-1]).astype(np.int64)
    xy, valid = interpolate_track(wt, wxy, t)
    assert valid.all()
    for p, ti in zip(xy, t.tolist(), strict=True):
        legs = [j for j in range(wt.size - 1) if wt[j] <= ti <= wt[j + 1]]
        assert any(_on_segment(p, wxy[j], wxy[j + 1]) for j in legs)
