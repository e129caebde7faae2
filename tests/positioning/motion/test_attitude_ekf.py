"""Attitude-determination EKF (``papers/002_*`` eq 9-17) on synthetic phone sensor data.

Static tilted phones, a turn about the vertical, batches cut anywhere, and the filter's
hand-written 3×3 algebra against the same filter on ``server.positioning.filters.kalman``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.model import state_codec
from server.positioning.motion.attitude_ekf import (
    AttitudeParams,
    AttitudeState,
    attitude_ekf,
    initial_attitude,
)
from server.positioning.motion.sensor_geometry import G, heading_from_yaw
from tests.support.attitude_reference import generic_attitude_ekf
from tests.support.synthetic_phone import (
    angle_error_deg,
    rotation,
    short_walk,
    split_at,
    to_phone,
    walk,
)
from tests.support.synthetic_phone import samples as phone_samples

FloatArray = NDArray[np.float64]


def static_phone(
    pitch_deg: float, roll_deg: float, duration_s: float, yaw_rate: float = 0.0, seed: int = 1
) -> tuple[FloatArray, FloatArray]:
    """Gyro and accelerometer of a phone at fixed tilt turning at ``yaw_rate`` about up."""
    rng = np.random.default_rng(seed)
    n = round(100.0 * duration_s)
    t_s = np.arange(n) / 100.0
    theta = np.full(n, math.radians(pitch_deg))
    gamma = np.full(n, math.radians(roll_deg))
    R = rotation(yaw_rate * t_s, theta, gamma)
    up = to_phone(R, np.array([0.0, 0.0, 1.0]))
    gyro = yaw_rate * up + rng.normal(0.0, 0.001, (n, 3))
    accel = G * up + rng.normal(0.0, 0.02, (n, 3))
    return phone_samples(t_s, gyro), phone_samples(t_s + 0.004, accel)


def test_cui_defaults() -> None:
    params = AttitudeParams()
    assert params.d0 == (0.5 * math.pi, 0.0, 0.0)
    assert params.p0 == params.q == params.r == (1.0, 1.0, 1.0)
    state = initial_attitude(params)
    np.testing.assert_array_equal(state.D, [0.5 * math.pi, 0.0, 0.0])
    np.testing.assert_array_equal(state.P, np.eye(3))
    assert math.isnan(state.last_t_ms)
    with pytest.raises(ValueError, match="r: each value must be greater than 0"):
        AttitudeParams(r=(1.0, 0.0, 1.0))


def test_static_tilted_phone_converges_to_its_tilt() -> None:
    gyro, accel = static_phone(pitch_deg=20.0, roll_deg=-10.0, duration_s=5.0)
    params = AttitudeParams()
    state, euler = attitude_ekf(initial_attitude(params), gyro, accel, params)
    assert euler.shape == (len(gyro), 4)
    np.testing.assert_array_equal(euler[:, 0], gyro[:, 0])
    np.testing.assert_allclose(np.degrees(euler[-100:, 2]).mean(), 20.0, atol=0.3)
    np.testing.assert_allclose(np.degrees(euler[-100:, 3]).mean(), -10.0, atol=0.3)
    # nothing turns the phone: the yaw stays at D_0
    assert angle_error_deg(euler[-1, 1], 0.5 * math.pi) < 0.5
    np.testing.assert_allclose(state.P, state.P.T)
    assert np.all(np.linalg.eigvalsh(state.P) > 0)


def test_yaw_follows_a_turn_about_the_vertical() -> None:
    yaw_rate = math.radians(30.0)
    gyro, accel = static_phone(pitch_deg=20.0, roll_deg=-10.0, duration_s=3.0, yaw_rate=yaw_rate)
    params = AttitudeParams(d0=(0.0, math.radians(20.0), math.radians(-10.0)))
    _, euler = attitude_ekf(initial_attitude(params), gyro, accel, params)
    turned = np.unwrap(euler[:, 1])
    elapsed_s = (euler[-1, 0] - euler[0, 0]) / 1000.0
    assert math.degrees(turned[-1] - turned[0]) == pytest.approx(
        math.degrees(yaw_rate * elapsed_s), abs=1.0
    )
    # counter-clockwise yaw is a heading turning anticlockwise
    heading = heading_from_yaw(euler[:, 1])
    assert angle_error_deg(heading[-1], heading[0] - yaw_rate * elapsed_s) < 1.0


def test_attitude_ekf_without_accelerometer_integrates_the_gyro() -> None:
    gyro, _ = static_phone(pitch_deg=0.0, roll_deg=0.0, duration_s=1.0, yaw_rate=0.5)
    params = AttitudeParams(d0=(0.0, 0.0, 0.0))
    _, euler = attitude_ekf(initial_attitude(params), gyro, np.empty((0, 4)), params)
    assert euler[-1, 1] == pytest.approx(0.5 * 0.99, abs=0.01)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=3))
def test_attitude_ekf_is_incremental(fractions: list[float]) -> None:
    data = short_walk()
    params = AttitudeParams()
    t_min, t_max = data.gyro[0, 0], data.gyro[-1, 0] + 1.0
    cuts = sorted(t_min + f * (t_max - t_min) for f in fractions)
    _, whole = attitude_ekf(initial_attitude(params), data.gyro, data.accel, params)

    state = initial_attitude(params)
    parts = []
    gyro, accel = data.gyro, data.accel
    for cut in [*cuts, math.inf]:
        g_now, gyro = split_at(gyro, cut)
        a_now, accel = split_at(accel, cut)
        state, out = attitude_ekf(
            state_codec.from_arrays(AttitudeState, state_codec.to_arrays(state)),
            g_now,
            a_now,
            params,
        )
        parts.append(out)
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=0.0, atol=1e-9)


def test_attitude_state_round_trips_through_arrays() -> None:
    data = short_walk()
    a_params = AttitudeParams()
    a_state, _ = attitude_ekf(initial_attitude(a_params), data.gyro, data.accel, a_params)
    for state in (a_state, initial_attitude(a_params)):
        arrays = state_codec.to_arrays(state)
        again = state_codec.to_arrays(state_codec.from_arrays(type(state), arrays))
        assert arrays.keys() == again.keys()
        for key, value in arrays.items():
            assert value.dtype == again[key].dtype
            np.testing.assert_array_equal(value, again[key])
    with pytest.raises(ValueError, match="P must have shape"):
        state_codec.from_arrays(AttitudeState, {**state_codec.to_arrays(a_state), "P": np.eye(2)})


# --- the hand-written algebra ---------------------------------------------------------------


def test_hand_written_algebra_equals_the_generic_ekf() -> None:
    turning = walk(duration_s=20.0, disturbed_s=None, turn=(5.0, 3.0, 90.0))
    tilted = static_phone(pitch_deg=20.0, roll_deg=-10.0, duration_s=5.0, yaw_rate=0.3)
    params = AttitudeParams()
    for gyro, accel in ((turning.gyro, turning.accel), tilted):
        state, ours = attitude_ekf(initial_attitude(params), gyro, accel, params)
        reference, theirs = generic_attitude_ekf(initial_attitude(params), gyro, accel, params)
        np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(state.P, reference.P, rtol=0.0, atol=1e-15)
        np.testing.assert_array_equal(state.last_accel, reference.last_accel)
