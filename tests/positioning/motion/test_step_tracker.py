"""Raw IMU blocks through the step tracker: steps, their headings and turn labels.

The walk comes from ``client_sim.imu``: 60 s at 1.8 steps/s (108 steps) heading -60 deg,
a smooth right-angle turn to the right between 30 and 32 s, then 30 deg. The phone is
held in front, top edge raised 20 deg, swaying a few degrees; the gyro has a bias of about
0.4 deg/s (0.34 deg/s about the vertical), the magnetometer sees a clean 45 µT field.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from client_sim.imu import Block, Gait, ImuTrace, Sensors, blocks, synthesize_walk
from server.positioning.model import state_codec
from server.positioning.model.events import Event, ImuEvent, MagEvent, RadioReading, WifiEvent
from server.positioning.motion.step_tracker import (
    HeadingSource,
    Step,
    StepBlock,
    TrackerParams,
    TrackerState,
    initial_tracker,
    timeline,
    track,
)
from server.positioning.motion.turns import STRAIGHT, TURN

FloatArray = NDArray[np.float64]

HEADING_0 = math.radians(-60.0)
TURN_S = (30.0, 32.0)


@cache
def walk() -> ImuTrace:
    return synthesize_walk(
        [(0.0, HEADING_0), (TURN_S[0], HEADING_0), (TURN_S[1], HEADING_0 + math.pi / 2)],
        62.0,
        np.random.default_rng(1),
        walking=[(0.0, 60.0)],
        gait=Gait(
            tilt_x_rad=math.radians(20.0),
            heading_sway_rad=math.radians(3.0),
            sway_x_rad=math.radians(2.0),
            sway_y_rad=math.radians(2.0),
        ),
        sensors=Sensors(gyro_bias_rads=(0.002, -0.003, 0.006)),
    )


def imu_event(block: Block, sensors: tuple[str, ...]) -> ImuEvent:
    def pick(name: str, width: int) -> FloatArray:
        samples: FloatArray = getattr(block, name)
        return samples if name in sensors else np.empty((0, width))

    return ImuEvent(
        block.t_ms,
        accel=pick("accel", 4),
        gyro=pick("gyro", 4),
        magnetic=pick("magnetic", 4),
        rotation=pick("rotation", 5),
    )


NO_ROTATION = ("accel", "gyro", "magnetic")


def run(
    params: TrackerParams,
    block_ms: float = 1000.0,
    sensors: tuple[str, ...] = NO_ROTATION,
    state: TrackerState | None = None,
    start: int = 0,
) -> tuple[TrackerState, list[StepBlock]]:
    state = state if state is not None else initial_tracker(params)
    out = []
    for block in blocks(walk(), block_ms)[start:]:
        state, steps = track(state, imu_event(block, sensors), params)
        out.append(steps)
    return state, out


def cat(found: list[StepBlock]) -> StepBlock:
    def join(name: str) -> Any:
        return np.concatenate([getattr(b, name) for b in found])

    return StepBlock(*(join(name) for name in StepBlock.__dataclass_fields__))


def seconds(t_ms: NDArray[np.int64]) -> FloatArray:
    return np.asarray((t_ms - walk().t0_ms) / 1000.0, dtype=np.float64)


def true_heading(t_ms: NDArray[np.int64]) -> FloatArray:
    trace = walk()
    return np.asarray(np.interp(t_ms, trace.t_ms, np.unwrap(trace.heading)), dtype=np.float64)


def error_deg(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.asarray(np.abs(np.degrees(np.angle(np.exp(1j * (a - b))))), dtype=np.float64)


def assert_same_blocks(a: StepBlock, b: StepBlock) -> None:
    for name in StepBlock.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_fused_heading_steps_through_a_right_angle_turn() -> None:
    _, found = run(TrackerParams(heading="fused"))
    steps = cat(found)
    t_s = seconds(steps.t_ms)

    assert len(steps) == walk().n_steps == 108
    np.testing.assert_array_equal(np.diff(steps.t_ms) > 0, True)
    np.testing.assert_allclose(steps.length_m, 0.55 * 3.8**0.25, atol=0.02)  # papers/003_* eq 1
    # compass-referenced from the first magnetometer sample; within 3 deg once settled
    settled = t_s > 2.0
    assert np.max(error_deg(steps.heading_rad, true_heading(steps.t_ms))[settled]) < 3.0
    # the turn: straight before, a turn, a new straight segment after
    before, after = t_s < TURN_S[0], t_s > TURN_S[1] + 3.0
    assert (steps.status[before] == STRAIGHT).all()
    assert (steps.segment[before] == 0).all()
    during = steps.status[~before & ~after]
    assert (during == TURN).sum() >= 3
    assert (steps.status[after] == STRAIGHT).all()
    assert (steps.segment[after] == 1).all()
    # north-referenced once the compass was seen in an earlier block: NaN in the first
    first_block = np.isin(steps.t_ms, found[0].t_ms)
    assert first_block.sum() == 1
    assert np.isnan(steps.north_rad[first_block]).all()
    # the same as the heading from the first step after the compass was first seen; a step
    # found in the second block but earlier gets the first north-referenced value
    later = steps.t_ms >= blocks(walk())[1].t_ms
    np.testing.assert_array_equal(steps.north_rad[later], steps.heading_rad[later])
    assert np.max(error_deg(steps.north_rad[~first_block], steps.heading_rad[~first_block])) < 1.0


def test_rotation_vector_heading_is_the_true_heading_and_north_at_once() -> None:
    _, found = run(TrackerParams(heading="rotation"), sensors=(*NO_ROTATION, "rotation"))
    steps = cat(found)
    assert len(steps) == walk().n_steps
    assert np.max(error_deg(steps.heading_rad, true_heading(steps.t_ms))) < 0.5
    np.testing.assert_array_equal(steps.north_rad, steps.heading_rad)


@pytest.mark.parametrize(
    ("source", "sensors", "tolerance_deg"),
    [
        # the bias about the vertical, 0.26 deg/s, adds 2.3 deg between the two means
        ("fused", ("accel", "gyro"), 3.0),
        # Cui's EKF (Q = R = I) follows the accelerometer sample by sample, so the forward
        # surge tilts its vertical in step with the phone's sway about its y axis and the
        # yaw drifts 0.55 deg/s on this walk even without a gyro bias (0.8 deg/s with it)
        ("attitude", NO_ROTATION, 10.0),
    ],
    ids=["gyro only", "attitude EKF"],
)
def test_relative_headings_turn_by_the_right_angle(
    source: HeadingSource, sensors: tuple[str, ...], tolerance_deg: float
) -> None:
    _, found = run(TrackerParams(heading=source), sensors=sensors)
    steps = cat(found)
    t_s = seconds(steps.t_ms)
    assert len(steps) == walk().n_steps
    heading = np.unwrap(steps.heading_rad)
    before = (t_s > TURN_S[0] - 4.0) & (t_s < TURN_S[0])
    after = (t_s > TURN_S[1] + 3.0) & (t_s < TURN_S[1] + 7.0)
    turned = heading[after].mean() - heading[before].mean()
    assert math.degrees(turned) == pytest.approx(90.0, abs=tolerance_deg)
    assert (steps.status[before] == STRAIGHT).all()
    assert steps.status[(t_s > TURN_S[0]) & (t_s < TURN_S[1] + 2.0)].max() == TURN
    if source == "fused":  # no compass: the heading starts from 0 and north is never known
        assert np.isnan(steps.north_rad).all()
        assert error_deg(steps.heading_rad[:1], np.zeros(1))[0] < 3.0


def test_tracker_state_round_trips_mid_walk() -> None:
    params = TrackerParams()
    _, whole = run(params)
    cut = 23
    state = initial_tracker(params)
    for block in blocks(walk())[:cut]:
        state, _ = track(state, imu_event(block, NO_ROTATION), params)
    arrays = {k: np.array(v) for k, v in state_codec.to_arrays(state).items()}
    restored = state_codec.from_arrays(TrackerState, arrays)
    for key, value in state_codec.to_arrays(restored).items():
        np.testing.assert_array_equal(value, arrays[key], err_msg=key)
    _, resumed = run(params, state=restored, start=cut)
    assert len(cat(resumed)) > 0
    assert_same_blocks(cat(resumed), cat(whole[cut:]))


def test_same_steps_from_blocks_of_one_or_two_and_a_half_seconds() -> None:
    params = TrackerParams()
    one = cat(run(params, block_ms=1000.0)[1])
    longer_blocks = run(params, block_ms=2500.0)[1]
    longer = cat(longer_blocks)
    for name in ("t_ms", "length_m", "status", "segment"):
        np.testing.assert_array_equal(getattr(longer, name), getattr(one, name), err_msg=name)
    np.testing.assert_allclose(longer.heading_rad, one.heading_rad, rtol=0.0, atol=1e-9)
    # north is known from the second block on, whatever the blocks' length
    known = ~np.isnan(longer.north_rad)
    np.testing.assert_array_equal(known, ~np.isin(longer.t_ms, longer_blocks[0].t_ms))
    np.testing.assert_allclose(longer.north_rad[known], one.north_rad[known], rtol=0.0, atol=1e-9)


def test_step_scale_multiplies_the_lengths() -> None:
    one = cat(run(TrackerParams())[1])
    scaled = cat(run(TrackerParams(step_scale=1.2))[1])
    np.testing.assert_allclose(scaled.length_m, 1.2 * one.length_m)


def test_timeline_merges_steps_and_scans_in_time_order() -> None:
    params = TrackerParams()
    first = blocks(walk())[:6]
    _, found = run(params)
    steps = cat(found[:6])
    at_step = int(steps.t_ms[2])
    scans = [
        WifiEvent(at_step, (RadioReading("02:00:00:00:00:01", -60.0),)),
        WifiEvent(walk().t0_ms + 100, ()),
    ]
    imus = [imu_event(b, NO_ROTATION) for b in first]
    events: list[Event] = [imus[3], scans[0], *imus[:3], MagEvent(at_step), *imus[4:], scans[1]]
    _, items = timeline(initial_tracker(params), events, params)

    assert [i for i in items if not isinstance(i, Step)] == [scans[1], scans[0]]
    got = [i for i in items if isinstance(i, Step)]
    assert [s.t_ms for s in got] == steps.t_ms.tolist()
    assert got[2].length_m == steps.length_m[2]
    assert got[2].heading_rad == steps.heading_rad[2]
    assert all(s.straight for s in got)
    assert items.index(got[2]) + 1 == items.index(scans[0])  # the step first at the same ms
    times = [i.t_ms for i in items]
    assert times == sorted(times)


def test_blocks_without_gyro_or_accelerometer() -> None:
    params = TrackerParams()
    state = initial_tracker(params)
    state, steps = track(state, imu_event(blocks(walk())[5], ("magnetic",)), params)
    assert len(steps) == 0
    found = []
    for block in blocks(walk())[6:10]:
        state, steps = track(state, imu_event(block, ("accel",)), params)
        found.append(steps)
    steps = cat(found)
    assert len(steps) >= 5
    assert np.isnan(steps.heading_rad).all()
    assert np.isnan(steps.north_rad).all()
    assert (steps.status == STRAIGHT).all()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"heading": "compass"}, "heading"), ({"step_scale": 0.0}, "step_scale")],
)
def test_tracker_params_are_validated(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TrackerParams(**kwargs)  # type: ignore[arg-type]
