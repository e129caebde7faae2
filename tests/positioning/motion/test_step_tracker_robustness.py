"""The step tracker on awkward input: blocks sent twice, long blocks, gaps, samples with
no gravity, an uncalibrated magnetometer, diverging sensors."""

from __future__ import annotations

import math

import numpy as np

from client_sim.imu import ImuTrace, blocks, synthesize_walk
from server.positioning.model import state_codec
from server.positioning.model.events import ImuEvent
from server.positioning.motion.step_tracker import (
    StepBlock,
    TrackerParams,
    TrackerState,
    initial_tracker,
    track,
)

T0 = 1_700_000_000_000


def walk_with_turns() -> ImuTrace:
    knots = np.array(
        [
            [0.0, 0.0],
            [8.0, 0.0],
            [10.0, math.pi / 2],
            [18.0, math.pi / 2],
            [20.0, math.pi],
            [30.0, math.pi],
        ]
    )
    return synthesize_walk(knots, 30.0, np.random.default_rng(3), t0_ms=T0)


def events(trace: ImuTrace, block_ms: float, calibrated: bool = True) -> list[ImuEvent]:
    return [
        ImuEvent(
            b.t_ms,
            accel=b.accel,
            gyro=b.gyro,
            magnetic=b.magnetic,
            rotation=b.rotation,
            magnetic_calibrated=calibrated,
        )
        for b in blocks(trace, block_ms)
    ]


def run(evs: list[ImuEvent], params: TrackerParams) -> tuple[TrackerState, list[StepBlock]]:
    state = initial_tracker(params)
    out = []
    for e in evs:
        state, found = track(state, e, params)
        out.append(found)
    return state, out


def headings(found: list[StepBlock]) -> np.ndarray:
    return np.concatenate([b.heading_rad for b in found])


def test_long_blocks_give_each_step_the_heading_of_its_own_moment() -> None:
    trace = walk_with_turns()
    for source in ("fused", "rotation"):
        params = TrackerParams(heading=source)
        _, short = run(events(trace, 1000), params)
        _, long = run(events(trace, 10_000), params)
        a, b = headings(short), headings(long)
        assert a.size == b.size > 40
        diff = np.abs(np.angle(np.exp(1j * (a - b))))
        assert np.nanmax(diff) < math.radians(2.0), (source, np.nanmax(diff))


def test_a_block_sent_twice_is_used_once() -> None:
    trace = walk_with_turns()
    evs = events(trace, 1000)
    params = TrackerParams()
    state, _ = run(evs[:12], params)
    again, repeat = track(state, evs[11], params)
    assert len(repeat) == 0
    np.testing.assert_array_equal(
        state_codec.to_arrays(again.fusion)["heading"],
        state_codec.to_arrays(state.fusion)["heading"],
    )
    _, once = run(evs, params)
    _, twice = run([*evs[:12], evs[11], *evs[12:]], params)
    np.testing.assert_allclose(headings(twice), headings(once))


def test_an_uncalibrated_magnetometer_gives_no_north() -> None:
    trace = walk_with_turns()
    evs = [
        ImuEvent(
            e.t_ms,
            accel=e.accel,
            gyro=e.gyro,
            magnetic=e.magnetic + np.array([0.0, 60.0, -40.0, 20.0]),  # a hard-iron offset
            magnetic_calibrated=False,
        )
        for e in events(trace, 1000)
    ]
    _, found = run(evs, TrackerParams())
    assert np.isnan(np.concatenate([b.north_rad for b in found])).all()


def test_zero_gravity_samples_gaps_and_wild_gyro_leave_a_finite_state() -> None:
    rng = np.random.default_rng(0)
    t = T0 + 20.0 * np.arange(200)
    t[100:] += 60_000  # a minute without samples
    accel = np.column_stack([t, rng.uniform(-160, 160, (200, 3))])
    accel[::7, 1:] = 0.0  # no gravity direction at all
    gyro = np.column_stack([t, rng.uniform(-35, 35, (200, 3))])
    magnetic = np.column_stack([t, rng.uniform(-5000, 5000, (200, 3))])
    for source in ("fused", "attitude"):
        params = TrackerParams(heading=source)
        state = initial_tracker(params)
        for part in np.array_split(np.arange(200), 5):
            e = ImuEvent(
                int(t[part[0]]), accel=accel[part], gyro=gyro[part], magnetic=magnetic[part]
            )
            state, _ = track(state, e, params)
        for name, value in state_codec.to_arrays(state).items():
            if name in ("seen_ms", "detector.machine"):  # -inf / inf mean "none yet" there
                continue
            assert np.isfinite(value[~np.isnan(value)]).all(), (source, name)
        assert np.isfinite(state.attitude.D).all()
        assert math.isfinite(state.fusion.heading)
