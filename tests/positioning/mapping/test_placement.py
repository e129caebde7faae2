"""Placing samples from steps and anchors: the alignment undoes a heading offset and a
step-length scale, smoothing spreads drift between anchors, refusals say why."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.mapping.placement import PlacementParams, place_samples

T0 = 1_000_000


def l_walk(n_east: int = 30, n_north: int = 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step times, true step vectors and true positions after each step: east, then north,
    0.7 m steps every 0.5 s, starting at (5, 5)."""
    headings = np.array([math.pi / 2] * n_east + [0.0] * n_north)
    t = T0 + 500 * np.arange(1, headings.size + 1)
    vectors = 0.7 * np.column_stack([np.sin(headings), np.cos(headings)])
    positions = np.array([5.0, 5.0]) + np.cumsum(vectors, axis=0)
    return t, headings, positions


@settings(max_examples=40, deadline=None)
@given(offset=st.floats(-math.pi, math.pi), scale=st.floats(0.65, 1.9))
def test_two_anchors_undo_a_heading_offset_and_a_scale(offset: float, scale: float) -> None:
    t, headings, truth = l_walk()
    anchors_t = [T0, t[-1]]
    anchors_xy = [[5.0, 5.0], truth[-1]]
    # the phone's heading is off by `offset` and its steps `scale` times too long
    query = t[::3] - 100
    got = place_samples(
        t, np.full(t.size, 0.7 * scale), headings + offset, anchors_t, anchors_xy, query
    )
    assert got.placed.all()
    want = np.column_stack(
        [
            np.interp(query, np.r_[T0, t], np.r_[5.0, truth[:, 0]]),
            np.interp(query, np.r_[T0, t], np.r_[5.0, truth[:, 1]]),
        ]
    )
    np.testing.assert_allclose(got.xy_m, want, atol=1e-6)
    assert got.scale == pytest.approx(1.0 / scale)
    assert got.not_used == ()


def test_drift_is_spread_between_anchors_and_uncertainty_peaks_between_them() -> None:
    t, headings, truth = l_walk(40, 40)
    # a gyro drifting 0.3 degrees per step
    drifted = headings + np.deg2rad(0.3) * np.arange(t.size)
    anchors_t = [T0, t[39], t[-1]]
    anchors_xy = [[5.0, 5.0], truth[39], truth[-1]]
    got = place_samples(t, np.full(t.size, 0.7), drifted, anchors_t, anchors_xy, t)
    assert got.placed.all()
    errors = np.linalg.norm(got.xy_m - truth, axis=1)
    # dead reckoning from the first anchor only
    vectors = 0.7 * np.column_stack([np.sin(drifted), np.cos(drifted)])
    forward = np.array([5.0, 5.0]) + np.cumsum(vectors, axis=0)
    dr_errors = np.linalg.norm(forward - truth, axis=1)
    assert errors.max() < 0.5 * dr_errors.max()
    assert errors[39] < 1e-6  # at the middle anchor
    assert got.std_m[20] > got.std_m[2]
    assert got.std_m[20] > got.std_m[37]


def test_refusals_say_why() -> None:
    t, headings, truth = l_walk()
    lengths = np.full(t.size, 0.7)
    # a walk that comes back to where it started cannot fix the rotation
    back = np.r_[np.full(20, math.pi / 2), np.full(20, -math.pi / 2)]
    loop_t = T0 + 500 * np.arange(1, 41)
    loop = place_samples(loop_t, np.full(40, 0.7), back, [T0, loop_t[-1]], [[5, 5], [5, 5]], t)
    assert not loop.placed.any()
    assert "too close together" in loop.not_used[0]
    assert loop.not_used_samples == (t.size,)  # each reason with the samples it cost
    # anchors three times as far apart as the steps walked
    far = truth[-1] + 2 * (truth[-1] - [5.0, 5.0])
    stretched = place_samples(t, lengths, headings, [T0, t[-1]], [[5, 5], far], t)
    assert not stretched.placed.any()
    assert "disagree" in stretched.not_used[0]
    assert math.isnan(stretched.scale)
    # a middle anchor 30 m off: both its legs miss by more than 20 m and are not used
    anchors_xy = [[5.0, 5.0], truth[29] + [0.0, 30.0], truth[-1]]
    params = PlacementParams(min_scale=0.1, max_scale=10.0)
    wrong = place_samples(t, lengths, headings, [T0, t[29], t[-1]], anchors_xy, t, params)
    assert len([r for r in wrong.not_used if r.startswith("leg")]) >= 1
    assert not wrong.placed.all()
    assert sum(wrong.not_used_samples) == np.count_nonzero(~wrong.placed)
    # samples outside the anchors' span
    outside = place_samples(t, lengths, headings, [t[5], t[-5]], [truth[5], truth[-5]], t)
    assert not outside.placed[:5].any()
    assert outside.placed[5:-5].all()
    assert "before the first or after the last anchor" in outside.not_used[-1]
    assert outside.not_used_samples == (9,)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match="two anchors"):
        place_samples([1], [0.7], [0.0], [0], [[0, 0]], [0])
    with pytest.raises(ValueError, match="anchor_xy_m"):
        place_samples([1], [0.7], [0.0], [0, 2], [[0, 0]], [0])
    with pytest.raises(ValueError, match="sorted"):
        place_samples([2, 1], [0.7, 0.7], [0.0, 0.0], [0, 2], [[0, 0], [1, 1]], [0])
