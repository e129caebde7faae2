"""A recorded walk's steps: the step tracker fed the walk's raw samples in blocks, and the
steps between its first and last waypoint.

The synthetic walk (``tests.support.synthetic_phone``) goes straight at 1.4 m/s, heading
30 deg, for 60 s, stepping at 2 Hz in a clean 40 µT field; the ILC sample trace is 6 s of a
recorded walk with four waypoints.
"""

from __future__ import annotations

import math
from dataclasses import fields, replace
from functools import cache

import numpy as np
import pytest

from server.positioning.model.events import ImuEvent
from server.positioning.model.walk import Walk, trace_from_events
from server.positioning.motion.step_tracker import (
    StepBlock,
    TrackerParams,
    initial_tracker,
    track,
)
from server.positioning.motion.turns import STRAIGHT
from server.positioning.motion.walk_steps import (
    MIN_ANCHORED_PATH_M,
    STEP_BLOCK_MS,
    anchored_steps,
    walk_steps,
)
from server.storage.ilc_trace_format import IlcWalk
from tests.support import synthetic_phone

T0 = int(synthetic_phone.T0_MS)
PARAMS = TrackerParams()


@cache
def straight_walk() -> Walk:
    """The synthetic phone's 60 s walk as one block of raw samples, no waypoints."""
    phone = synthetic_phone.walk(disturbed_s=None)
    block = ImuEvent(T0, accel=phone.accel, gyro=phone.gyro, magnetic=phone.magnetic)
    return trace_from_events([block])


def with_waypoints(trace: Walk, waypoints: list[tuple[int, float, float]]) -> Walk:
    rows = np.array(waypoints, dtype=np.float64).reshape(-1, 3)
    return replace(
        trace,
        waypoint_t_ms=rows[:, 0].astype(np.int64),
        waypoint_xy_m=np.ascontiguousarray(rows[:, 1:]),
    )


def assert_same_steps(found: StepBlock, expected: StepBlock) -> None:
    for f in fields(StepBlock):
        a, b = getattr(found, f.name), getattr(expected, f.name)
        assert a.dtype == b.dtype, f.name
        np.testing.assert_array_equal(a, b, err_msg=f.name)


def picked(steps: StepBlock, keep: slice) -> StepBlock:
    return StepBlock(*(getattr(steps, f.name)[keep] for f in fields(StepBlock)))


def by_hand(trace: Walk, params: TrackerParams, block_ms: int) -> StepBlock:
    """The tracker fed the walk's blocks one by one, its steps joined."""
    state = initial_tracker(params)
    parts: list[StepBlock] = []
    for imu in trace.imu_events(block_ms):
        state, block = track(state, imu, params)
        parts.append(block)
    return StepBlock(
        *(np.concatenate([getattr(b, f.name) for b in parts]) for f in fields(StepBlock))
    )


# ---- walk_steps -------------------------------------------------------------------------


def test_the_steps_of_a_straight_walk() -> None:
    steps = walk_steps(straight_walk(), PARAMS)
    # 2 steps a second for 60 s, the first once the detector has settled
    assert len(steps) == 118
    assert np.all(np.diff(steps.t_ms) > 0)
    assert T0 < steps.t_ms[0] < T0 + 1500
    assert T0 + 59_000 < steps.t_ms[-1] < T0 + 60_000
    assert np.diff(steps.t_ms).mean() == pytest.approx(500.0, abs=5.0)
    # the walker's 30 deg, straight throughout, in a 40 µT field; 84 m walked, the
    # uncalibrated step-length model says some 78
    assert math.degrees(float(np.median(steps.heading_rad))) == pytest.approx(30.0, abs=2.0)
    assert math.degrees(float(np.nanmedian(steps.north_rad))) == pytest.approx(30.0, abs=2.0)
    assert set(steps.status.tolist()) == {STRAIGHT}
    assert float(np.nanmedian(steps.magnitude_ut)) == pytest.approx(40.0, abs=0.5)
    assert float(steps.length_m.sum()) == pytest.approx(78.3, abs=2.0)


@pytest.mark.parametrize("block_ms", [250, STEP_BLOCK_MS, 5000])
def test_walk_steps_is_the_tracker_fed_the_blocks_by_hand(block_ms: int) -> None:
    trace = straight_walk()
    assert_same_steps(walk_steps(trace, PARAMS, block_ms), by_hand(trace, PARAMS, block_ms))
    # the steps found, their lengths and headings do not depend on how the samples are cut
    # (the compass-referenced heading does: it settles as the blocks come)
    cut, whole = walk_steps(trace, PARAMS, block_ms), walk_steps(trace, PARAMS)
    for name in ("t_ms", "length_m", "heading_rad", "status"):
        np.testing.assert_array_equal(getattr(cut, name), getattr(whole, name), err_msg=name)


def test_walk_steps_reads_the_tracker_params() -> None:
    trace = straight_walk()
    longer = TrackerParams(step_scale=1.5)
    found = walk_steps(trace, longer)
    assert_same_steps(found, by_hand(trace, longer, STEP_BLOCK_MS))
    plain = walk_steps(trace, PARAMS)
    np.testing.assert_array_equal(found.t_ms, plain.t_ms)
    np.testing.assert_allclose(found.length_m, 1.5 * plain.length_m)


def test_walk_steps_of_the_ilc_sample_trace(raw_trace: IlcWalk) -> None:
    steps = walk_steps(raw_trace, PARAMS)
    assert len(steps) == 11
    assert raw_trace.t_first_ms < steps.t_ms[0] < steps.t_ms[-1] < raw_trace.t_last_ms
    assert_same_steps(steps, by_hand(raw_trace, PARAMS, STEP_BLOCK_MS))


def test_a_walk_without_motion_samples_has_no_steps() -> None:
    still = trace_from_events([], [(T0, 0.0, 0.0), (T0 + 10_000, 10.0, 0.0)])
    steps = walk_steps(still, PARAMS)
    assert len(steps) == 0
    assert steps.t_ms.dtype == np.dtype(np.int64)
    assert steps.length_m.dtype == np.dtype(np.float64)
    assert steps.status.dtype == np.dtype(np.int64)
    # anchors far enough apart, but nothing to find between them: no steps, not None
    found = anchored_steps(still, PARAMS)
    assert found is not None
    assert len(found) == 0


# ---- anchored_steps ---------------------------------------------------------------------


def test_anchored_steps_keep_the_steps_after_the_first_waypoint_up_to_the_last() -> None:
    trace = straight_walk()
    steps = walk_steps(trace, PARAMS)
    first, last = int(steps.t_ms[10]), int(steps.t_ms[30])
    # waypoints at two steps' own times, 14 m apart, one more in between
    found = anchored_steps(
        with_waypoints(trace, [(first, 0.0, 0.0), (first + 4000, 5.6, 0.0), (last, 14.0, 0.0)]),
        PARAMS,
    )
    assert found is not None
    # the step at the first waypoint is before the walk's anchored part, the last one's in
    assert_same_steps(found, picked(steps, slice(11, 31)))
    assert len(found) == 20
    # waypoints between steps: the steps between them
    between = anchored_steps(
        with_waypoints(trace, [(first + 1, 0.0, 0.0), (last - 1, 14.0, 0.0)]), PARAMS
    )
    assert between is not None
    assert_same_steps(between, picked(steps, slice(11, 30)))


def test_anchored_steps_of_the_ilc_sample_trace(raw_trace: IlcWalk) -> None:
    # its four waypoints span 6.2 m of path around all 11 steps
    found = anchored_steps(raw_trace, PARAMS)
    assert found is not None
    assert_same_steps(found, walk_steps(raw_trace, PARAMS))
    # its middle two lie 2 m apart: too close to turn steps onto
    middle = replace(
        raw_trace,
        waypoint_t_ms=raw_trace.waypoint_t_ms[1:3],
        waypoint_xy_m=raw_trace.waypoint_xy_m[1:3],
    )
    assert anchored_steps(middle, PARAMS) is None


@pytest.mark.parametrize(
    "waypoints",
    [
        [],
        [(T0 + 5000, 0.0, 0.0)],  # one waypoint: no anchored part
    ],
)
def test_anchored_steps_need_two_waypoints(waypoints: list[tuple[int, float, float]]) -> None:
    assert anchored_steps(with_waypoints(straight_walk(), waypoints), PARAMS) is None


@pytest.mark.parametrize(
    ("xy", "anchored"),
    [
        ([(0.0, 0.0), (3.0, 4.0)], True),  # 5 m: just enough
        ([(0.0, 0.0), (2.9, 4.0)], False),  # 4.94 m
        ([(0.0, 0.0), (3.0, 0.0), (0.0, 0.0)], True),  # 6 m out and back: the path counts
        ([(0.0, 0.0), (2.0, 0.0), (0.0, 0.0)], False),  # 4 m out and back
    ],
)
def test_anchored_steps_need_waypoints_min_anchored_path_apart_along_the_path(
    xy: list[tuple[float, float]], anchored: bool
) -> None:
    assert MIN_ANCHORED_PATH_M == 5.0
    waypoints = [(T0 + 10_000 * (k + 1), x, y) for k, (x, y) in enumerate(xy)]
    found = anchored_steps(with_waypoints(straight_walk(), waypoints), PARAMS)
    if not anchored:
        assert found is None
        return
    assert found is not None
    steps = walk_steps(straight_walk(), PARAMS)
    inside = (steps.t_ms > waypoints[0][0]) & (steps.t_ms <= waypoints[-1][0])
    np.testing.assert_array_equal(found.t_ms, steps.t_ms[inside])
    assert len(found) == 20 * (len(xy) - 1)
