"""Synthetic raw IMU: sample clocks, physics the sensors must agree on, and the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from client_sim.imu import T0_MS, G, Gait, ImuTrace, Sensors, blocks, synthesize_walk
from server.api.schemas.events import ImuIn

FloatArray = NDArray[np.float64]

QUIET = Sensors(
    accel_noise_ms2=0.0, gyro_noise_rads=0.0, magnetic_noise_ut=0.0, pressure_noise_hpa=0.0
)
TILTED = Gait(
    tilt_x_rad=math.radians(25.0),
    tilt_y_rad=math.radians(-5.0),
    heading_sway_rad=math.radians(3.0),
    sway_x_rad=math.radians(2.0),
    sway_y_rad=math.radians(2.0),
)
L_TURN = [(0.0, 0.2), (10.0, 0.2), (12.0, 0.2 - math.pi / 2)]  # a left turn at 10-12 s
UP_A_FLOOR = [(0.0, 0.0), (8.0, 0.0), (12.0, 3.5)]  # 3.5 m up at 8-12 s


def trace_of(
    seed: int = 0,
    gait: Gait = TILTED,
    sensors: Sensors = QUIET,
    walking: list[tuple[float, float]] | None = None,
    duration_s: float = 20.0,
    height: list[tuple[float, float]] | None = None,
) -> ImuTrace:
    return synthesize_walk(
        L_TURN,
        duration_s,
        np.random.default_rng(seed),
        walking=walking,
        gait=gait,
        sensors=sensors,
        height=height,
    )


def quaternion(samples: FloatArray) -> Rotation:
    return Rotation.from_quat(samples[:, 1:5])


def test_sample_clocks() -> None:
    sensors = Sensors(
        gyro_hz=100.0,
        accel_offset_ms=3,
        magnetic_hz=30.0,
        magnetic_offset_ms=7,
        pressure_hz=20.0,
        pressure_offset_ms=11,
    )
    trace = synthesize_walk(L_TURN, 20.0, np.random.default_rng(0), sensors=sensors, t0_ms=5000)
    assert trace.accel.shape == (1000, 4)
    assert trace.gyro.shape == (2000, 4)
    assert trace.magnetic.shape == (600, 4)
    assert trace.rotation.shape == (1000, 5)
    assert trace.pressure.shape == (400, 2)
    clocks = ((trace.accel, 3), (trace.gyro, 0), (trace.magnetic, 7), (trace.pressure, 11))
    for samples, offset_ms in clocks:
        t = samples[:, 0]
        assert t[0] == 5000 + offset_ms
        assert t[-1] < 5000 + 20_000
        np.testing.assert_array_equal(t, np.round(t))  # whole milliseconds
        assert np.all(np.diff(t) > 0)
    np.testing.assert_array_equal(np.unique(np.diff(trace.magnetic[:, 0])), [33.0, 34.0])
    np.testing.assert_array_equal(np.diff(trace.pressure[:, 0]), 50.0)
    np.testing.assert_array_equal(trace.t_ms, trace.gyro[:, 0])
    assert trace.t_ms.dtype == np.int64
    assert trace.heading.shape == (2000,)
    assert trace.xy.shape == (2000, 2)
    assert trace.height_m.shape == (2000,)


def test_the_same_generator_state_gives_the_same_trace() -> None:
    sensors = Sensors(gyro_bias_rads=(0.01, 0.0, -0.01))
    gait = Gait(tremor_ms2=0.3)
    a, b = (trace_of(seed=4, gait=gait, sensors=sensors) for _ in range(2))
    c = trace_of(seed=5, gait=gait, sensors=sensors)
    names = ("accel", "gyro", "magnetic", "rotation", "pressure", "heading", "xy", "step_t_ms")
    for name in (*names, "height_m"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert not np.array_equal(a.accel, c.accel)
    np.testing.assert_array_equal(a.rotation, c.rotation)  # the truth is not random


def test_accelerometer_averages_to_gravity_and_bounces_once_a_step() -> None:
    trace = trace_of(sensors=Sensors())
    magnitude = np.linalg.norm(trace.accel[:, 1:], axis=1)
    assert magnitude.mean() == pytest.approx(G, abs=0.05)
    # the vertical (from the rotation vector) is g + 2.5 sin(phase): peaks and valleys
    up = quaternion(trace.rotation).apply(trace.accel[:, 1:])[:, 2]
    at = np.searchsorted(trace.accel[:, 0], trace.step_t_ms)
    np.testing.assert_allclose(up[at], G - 2.5, atol=0.2)
    at = np.searchsorted(trace.accel[:, 0], trace.peak_t_ms)
    np.testing.assert_allclose(up[at], G + 2.5, atol=0.2)


def test_standing_still_reads_gravity_and_the_field() -> None:
    trace = trace_of(walking=[])
    R = quaternion(trace.rotation)
    np.testing.assert_allclose(R.apply(trace.accel[:, 1:]), [[0.0, 0.0, G]] * 1000, atol=1e-9)
    np.testing.assert_allclose(
        R.apply(trace.magnetic[:, 1:]), [[0.0, 20.0, -40.0]] * 1000, atol=1e-9
    )
    assert trace.n_steps == 0
    np.testing.assert_allclose(trace.xy, 0.0)


def test_gyro_integrates_to_the_heading_profile() -> None:
    bias = (0.0, 0.0, 0.01)
    tilted = Gait(tilt_x_rad=math.radians(25.0), tilt_y_rad=math.radians(-5.0))
    trace = trace_of(gait=tilted, sensors=Sensors(gyro_noise_rads=0.0, gyro_bias_rads=bias))
    up = quaternion(trace.rotation).inv().apply([0.0, 0.0, 1.0])  # up in phone axes
    rate = np.einsum("ij,ij->i", trace.gyro[:, 1:] - bias, up)  # counter-clockwise
    dt = np.diff(trace.gyro[:, 0]) / 1000.0
    turned = -np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)])
    np.testing.assert_allclose(turned, np.unwrap(trace.heading) - trace.heading[0], atol=1e-3)
    assert math.degrees(turned[-1]) == pytest.approx(-90.0, abs=0.5)
    # the rotation vector is the attitude the gyro integrates
    q = Rotation.from_quat(trace.rotation[:, 1:])
    step = (q[:-1].inv() * q[1:]).as_rotvec() / dt[:, None]
    np.testing.assert_allclose(
        step, 0.5 * (trace.gyro[1:, 1:] + trace.gyro[:-1, 1:]) - bias, atol=2e-3
    )


def test_rotation_vector_is_a_canonical_unit_quaternion_along_the_heading() -> None:
    trace = trace_of()
    q = trace.rotation[:, 1:]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.all(q[:, 3] >= 0.0)
    y_axis = quaternion(trace.rotation).apply([0.0, 1.0, 0.0])
    np.testing.assert_allclose(np.arctan2(y_axis[:, 0], y_axis[:, 1]), trace.heading, atol=1e-9)
    # the top edge is raised by tilt_x (plus its sway)
    raised = np.degrees(np.arcsin(y_axis[:, 2]))
    assert raised.min() > 22.0
    assert raised.max() < 28.0


def test_flat_phone_compass_reads_the_heading() -> None:
    trace = trace_of(gait=Gait())
    m = trace.magnetic[:, 1:]
    # phone x east of its y axis: B = (0, 20, -40) reads (-20 sin h, 20 cos h, -40)
    np.testing.assert_allclose(np.arctan2(-m[:, 0], m[:, 1]), trace.heading, atol=1e-9)
    np.testing.assert_allclose(m[:, 2], -40.0)
    assert trace.heading[0] == pytest.approx(0.2)
    assert trace.heading[-1] == pytest.approx(0.2 - math.pi / 2)


def test_disturbance_is_added_in_the_world_frame_where_the_walker_is() -> None:
    seen: list[tuple[FloatArray, FloatArray]] = []

    def local(t_s: FloatArray, xy_m: FloatArray) -> FloatArray:
        seen.append((t_s, xy_m))
        return np.column_stack([np.full_like(t_s, 5.0), np.zeros_like(t_s), xy_m[:, 1]])

    trace = synthesize_walk(
        [(0.0, 0.0)], 10.0, np.random.default_rng(0), gait=Gait(), sensors=QUIET, disturbance=local
    )
    (t_s, xy_m), *_ = seen
    np.testing.assert_allclose(t_s, (trace.magnetic[:, 0] - T0_MS) / 1000.0)
    np.testing.assert_allclose(xy_m, trace.xy, atol=1e-9)  # same clocks by default
    np.testing.assert_allclose(
        trace.magnetic[:, 1:],
        np.column_stack([np.full(500, 5.0), np.full(500, 20.0), -40.0 + trace.xy[:, 1]]),
    )


def test_steps_and_positions() -> None:
    gait = Gait(cadence_hz=2.0, step_length_m=0.75)
    trace = synthesize_walk(
        [(0.0, 0.0)],
        20.0,
        np.random.default_rng(0),
        walking=[(1.0, 6.0), (8.0, 13.3)],
        gait=gait,
    )
    assert trace.n_steps == 10 + 10  # 5.3 s make 10 whole steps
    starts = np.array([1000.0] * 10 + [8000.0] * 10) + 500.0 * np.tile(np.arange(10), 2)
    np.testing.assert_array_equal(trace.step_t_ms - T0_MS, starts + 375.0)
    np.testing.assert_array_equal(trace.peak_t_ms - T0_MS, starts + 125.0)
    t_s = (trace.t_ms - T0_MS) / 1000.0
    np.testing.assert_allclose(trace.xy[:, 0], 0.0)
    np.testing.assert_allclose(trace.xy[t_s >= 13.0, 1], 20 * 0.75)
    np.testing.assert_allclose(trace.xy[(t_s >= 6.0) & (t_s <= 8.0), 1], 10 * 0.75)
    np.testing.assert_allclose(trace.xy[t_s <= 1.0, 1], 0.0)
    # standing: the accelerometer reads gravity alone (the gait phase is a whole cycle)
    standing = (trace.accel[:, 0] - T0_MS >= 6000) & (trace.accel[:, 0] - T0_MS < 8000)
    quiet = synthesize_walk(
        [(0.0, 0.0)], 20.0, np.random.default_rng(0), walking=[(1.0, 6.0)], gait=gait
    )
    np.testing.assert_array_equal(trace.accel[standing], quiet.accel[standing])


def test_positions_follow_the_course() -> None:
    trace = trace_of(gait=Gait(cadence_hz=2.0, step_length_m=0.5), duration_s=20.0)
    t_s = (trace.t_ms - T0_MS) / 1000.0
    at_10, at_12 = np.searchsorted(t_s, [10.0, 12.0])
    # 10 s at 1 m/s heading 0.2 rad, a left turn while walking, then heading 0.2 - pi/2
    np.testing.assert_allclose(trace.xy[at_10], [10.0 * math.sin(0.2), 10.0 * math.cos(0.2)])
    leg = trace.xy[-1] - trace.xy[at_12]
    along = 0.2 - math.pi / 2
    np.testing.assert_allclose(leg, 7.98 * np.array([math.sin(along), math.cos(along)]))


def test_heading_callable() -> None:
    trace = synthesize_walk(
        lambda t: 0.1 * t, 5.0, np.random.default_rng(0), gait=Gait(), sensors=QUIET
    )
    t_s = (trace.t_ms - T0_MS) / 1000.0
    np.testing.assert_allclose(np.unwrap(trace.heading), 0.1 * t_s, atol=1e-9)
    np.testing.assert_allclose(trace.gyro[:, 3], -0.1, atol=1e-6)  # flat: about z, clockwise


@pytest.mark.parametrize(
    "walking",
    [None, [(0.0, 8.0), (12.0, 20.0)]],
    ids=["stairs", "lift"],
)
def test_pressure_falls_by_0_12_hpa_a_metre_climbed(walking: list[tuple[float, float]]) -> None:
    trace = trace_of(sensors=Sensors(), walking=walking, height=UP_A_FLOOR)
    t_s = (trace.pressure[:, 0] - T0_MS) / 1000.0
    before, after = trace.pressure[t_s < 8.0, 1], trace.pressure[t_s >= 12.0, 1]
    assert 0.41 < before.mean() - after.mean() < 0.43  # 3.5 m x 0.12 hPa/m
    assert before.mean() == pytest.approx(1013.25, abs=0.01)
    assert before.std() == pytest.approx(0.02, rel=0.2)
    truth_s = (trace.t_ms - T0_MS) / 1000.0
    np.testing.assert_allclose(trace.height_m, np.interp(truth_s, [8.0, 12.0], [0.0, 3.5]))
    # the height is for the barometer alone: the rest reads as on the level
    flat = trace_of(sensors=Sensors(), walking=walking)
    for name in ("accel", "gyro", "magnetic", "rotation", "xy", "step_t_ms"):
        np.testing.assert_array_equal(getattr(trace, name), getattr(flat, name), err_msg=name)
    np.testing.assert_array_equal(flat.height_m, 0.0)
    assert flat.pressure[:, 1].mean() == pytest.approx(1013.25, abs=0.01)


def test_bias_and_weather_shift_the_pressure() -> None:
    still = trace_of(sensors=Sensors(), height=UP_A_FLOOR)
    t_h = (still.pressure[:, 0] - T0_MS) / 3_600_000.0
    biased = trace_of(sensors=Sensors(pressure_bias_hpa=0.5), height=UP_A_FLOOR)
    np.testing.assert_allclose(biased.pressure[:, 1] - still.pressure[:, 1], 0.5, atol=1e-9)
    drifting = trace_of(sensors=Sensors(weather_hpa_per_h=-0.9), height=UP_A_FLOOR)
    np.testing.assert_allclose(
        drifting.pressure[:, 1] - still.pressure[:, 1], -0.9 * t_h, rtol=0.0, atol=1e-9
    )
    for trace in (biased, drifting):
        np.testing.assert_array_equal(trace.pressure[:, 0], still.pressure[:, 0])


def test_blocks_hold_every_sample_once() -> None:
    trace = trace_of(
        sensors=Sensors(accel_offset_ms=3, magnetic_hz=30.0, gyro_hz=100.0, pressure_offset_ms=13),
        height=UP_A_FLOOR,
    )
    for block_ms in (1000.0, 2500.0, 333.3):
        cut = blocks(trace, block_ms)
        starts = [b.t_ms for b in cut]
        assert starts[0] == T0_MS
        assert np.all(np.diff(starts) > 0)
        for name in ("accel", "gyro", "magnetic", "rotation", "pressure"):
            parts = [getattr(b, name) for b in cut]
            np.testing.assert_array_equal(np.vstack(parts), getattr(trace, name))
            for b, part in zip(cut, parts, strict=True):
                assert np.all(part[:, 0] >= b.t_ms)
                assert np.all(part[:, 0] < b.t_ms + block_ms)
    event = blocks(trace)[3].event()
    assert event["type"] == "imu"
    assert event["t"] == T0_MS + 3000
    assert len(event["accel"]) == 50
    assert event["accel"][0][0] == T0_MS + 3003
    sampled = ("accel", "gyro", "magnetic", "pressure")
    assert all(type(row[0]) is int for name in sampled for row in event[name])
    assert len(event["rotation"][0]) == 5
    assert len(event["pressure"]) == 25
    assert event["pressure"][0] == [T0_MS + 3013, trace.pressure[75, 1]]
    for block in blocks(trace):
        ImuIn.model_validate(block.event())  # the wire takes every block


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"walking": [(5.0, 3.0)]}, "within"),
        ({"walking": [(0.0, 30.0)]}, "within"),
        ({"walking": [(0.0, 5.0), (4.0, 6.0)]}, "overlap"),
        ({"duration_s": 0.0}, "duration_s"),
        ({"heading": [(1.0, 0.0), (1.0, 1.0)]}, "knots"),
        ({"height": [(2.0, 0.0), (1.0, 3.0)]}, "height knots"),
        ({"height": [(0.0, math.nan)]}, "height_m"),
    ],
)
def test_arguments_are_checked(kwargs: dict[str, object], message: str) -> None:
    args: dict[str, object] = {"heading": L_TURN, "duration_s": 20.0, **kwargs}
    with pytest.raises(ValueError, match=message):
        synthesize_walk(rng=np.random.default_rng(0), **args)  # type: ignore[arg-type]


def test_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="cadence_hz"):
        Gait(cadence_hz=0.0)
    with pytest.raises(ValueError, match="step_length_m"):
        Gait(step_length_m=-1.0)
    with pytest.raises(ValueError, match="gyro_hz"):
        Sensors(gyro_hz=2000.0)
    with pytest.raises(ValueError, match="magnetic_offset_ms"):
        Sensors(magnetic_offset_ms=-1)
    with pytest.raises(ValueError, match="pressure_hz"):
        Sensors(pressure_hz=0.0)
    with pytest.raises(ValueError, match="pressure_offset_ms"):
        Sensors(pressure_offset_ms=-1)
    with pytest.raises(ValueError, match="block_ms"):
        blocks(trace_of(duration_s=1.0), 0.0)
