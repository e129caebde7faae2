"""RANSAC lines through straight stretches and the projection of outliers (``papers/003_*``
eq 2-3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from server.positioning.motion.straight_lines import project_to_line, ransac_line, straighten_track
from server.positioning.motion.turns import STRAIGHT, TURN

FloatArray = NDArray[np.float64]


def same_line(
    got: tuple[float, float, float] | None, want: tuple[float, float, float], atol: float = 1e-9
) -> None:
    """``a x + b y + c = 0`` lines equal up to scale and sign; ``got`` normalised."""
    assert got is not None
    a, b, c = want
    want_unit = np.array([a, b, c]) / math.hypot(a, b)
    assert math.hypot(got[0], got[1]) == pytest.approx(1.0)
    sign = np.sign(np.dot(got, want_unit))
    np.testing.assert_allclose(sign * np.array(got), want_unit, rtol=0.0, atol=atol)


def total_least_squares(points: FloatArray) -> tuple[float, float, float]:
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre)
    a, b = vt[-1]
    return float(a), float(b), float(-(a * centre[0] + b * centre[1]))


def test_ransac_recovers_a_line_among_outliers() -> None:
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 20.0, 25)
    on_line = np.column_stack([x, 0.5 * x + 1.0 + rng.normal(0.0, 0.1, x.size)])
    outliers = np.array([[5.0, 10.0], [10.0, -6.0], [15.0, 16.0], [2.0, -5.0]])
    points = np.vstack([on_line, outliers])
    line = ransac_line(points)
    same_line(line, total_least_squares(on_line))  # refitted to exactly the inliers
    same_line(line, (0.5, -1.0, 1.0), atol=0.1)  # 0.5 x - y + 1 = 0
    # more pairs than max_pairs: sampled with the generator
    sampled = ransac_line(points, max_pairs=50, rng=np.random.default_rng(0))
    same_line(sampled, total_least_squares(on_line))
    with pytest.raises(ValueError, match="rng"):
        ransac_line(points, max_pairs=50)


def test_ransac_needs_two_distinct_points() -> None:
    assert ransac_line(np.empty((0, 2))) is None
    assert ransac_line(np.array([[1.0, 2.0]])) is None
    assert ransac_line(np.array([[1.0, 2.0], [1.0, 2.0]])) is None
    same_line(ransac_line(np.array([[0.0, 0.0], [3.0, 0.0]])), (0.0, 1.0, 0.0))


@pytest.mark.parametrize("line", [(0.0, 1.0, 0.0), (0.0, 2.0, 0.0)], ids=["unit", "scaled"])
def test_only_far_points_are_projected_onto_the_line(line: tuple[float, float, float]) -> None:
    points = np.array([[1.0, 0.5], [2.0, 3.0], [3.0, -2.0], [4.0, -1.5]])
    before = points.copy()
    moved = project_to_line(points, line)
    np.testing.assert_allclose(moved, [[1.0, 0.5], [2.0, 0.0], [3.0, 0.0], [4.0, -1.5]])
    np.testing.assert_array_equal(points, before)  # the input is left alone


def test_projection_is_the_foot_of_the_perpendicular() -> None:
    line = (1.0, 1.0, -2.0)  # x + y = 2, not normalised
    moved = project_to_line(np.array([[4.0, 4.0], [1.5, 1.0]]), line, threshold_m=1.0)
    # (4, 4) is 6 / sqrt(2) = 4.2 m away: its foot is (1, 1); (1.5, 1) is 0.35 m away
    np.testing.assert_allclose(moved, [[1.0, 1.0], [1.5, 1.0]])


def test_straighten_track_moves_only_outliers_of_long_straight_stretches() -> None:
    # ten straight steps along y = 0 with one 3 m off; a turn; then a 3-step stretch
    xy = np.array(
        [[float(i), 0.0] for i in range(10)] + [[10.0, 1.0], [10.0, 2.0], [10.0, 3.0], [10.0, 9.0]]
    )
    xy[4, 1] = 3.0
    status = np.array([STRAIGHT] * 10 + [TURN] + [STRAIGHT] * 3)
    segment = np.array([0] * 10 + [0] + [1] * 3)
    out = straighten_track(xy, status, segment, np.random.default_rng(0))
    np.testing.assert_allclose(out[4], [4.0, 0.0], atol=1e-9)  # onto the line (eq 3)
    np.testing.assert_allclose(np.delete(out[:10], 4, axis=0), np.delete(xy[:10], 4, axis=0))
    np.testing.assert_array_equal(out[10:], xy[10:])  # a turn and a short stretch: as they were
