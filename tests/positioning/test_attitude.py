"""Attitude EKF and gyro/compass heading fusion on synthetic phone sensor data.

The synthetic walker holds the phone in front, top edge raised about 15 deg, and walks
straight at 1.4 m/s: the body sways +-3 deg in heading at the 1 Hz stride frequency,
the phone rolls +-2 deg at 1 Hz and pitches +-2 deg at the 2 Hz step frequency, and the
hand bounces vertically (1.5 m/s², 2 Hz) and surges forward (0.6 m/s², 2 Hz). The gyro
(100 Hz) has 0.003 rad/s white noise and a constant bias (0.5 deg/s about the phone's
z axis); the accelerometer (100 Hz, 3 ms later) 0.05 m/s² of noise; the magnetometer
(50 Hz, 7 ms later) sees a 40 µT earth field with 50 deg inclination plus 0.3 µT of noise
and, over an optional stretch, a local field of +-20 µT per axis that varies over 2.5-4.5 m
of walking, faded in and out over one metre.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from server.positioning.attitude import (
    AttitudeParams,
    AttitudeState,
    G,
    HeadingParams,
    HeadingState,
    attitude_ekf,
    compass_heading,
    fuse_heading,
    gravity_direction,
    heading_from_yaw,
    initial_attitude,
    initial_heading,
    rotation_heading,
    vertical_rate,
)
from server.positioning.kalman import wrap_angle

FloatArray = NDArray[np.float64]

T0_MS = 1.7e12  # an epoch time in ms, as the phones send
EARTH_FIELD_UT = 40.0 * np.array([0.0, math.cos(math.radians(50.0)), -math.sin(math.radians(50.0))])
SPEED_M_S = 1.4


def rotation(psi: FloatArray, theta: FloatArray, gamma: FloatArray) -> FloatArray:
    """Phone-to-ENU rotation matrices ``Rz(psi) Ry(theta) Rx(gamma)``, shape (n, 3, 3)."""
    cp, sp = np.cos(psi), np.sin(psi)
    ct, s_t = np.cos(theta), np.sin(theta)
    cg, sg = np.cos(gamma), np.sin(gamma)
    return np.stack(
        [
            np.stack([cp * ct, cp * s_t * sg - sp * cg, cp * s_t * cg + sp * sg], axis=-1),
            np.stack([sp * ct, sp * s_t * sg + cp * cg, sp * s_t * cg - cp * sg], axis=-1),
            np.stack([-s_t, ct * sg, ct * cg], axis=-1),
        ],
        axis=-2,
    )


def body_rates(
    theta: FloatArray,
    gamma: FloatArray,
    d_psi: FloatArray,
    d_theta: FloatArray,
    d_gamma: FloatArray,
) -> FloatArray:
    """Phone-axis angular rates from Z-Y-X Euler angle rates, shape (n, 3)."""
    return np.column_stack(
        [
            d_gamma - np.sin(theta) * d_psi,
            np.cos(gamma) * d_theta + np.sin(gamma) * np.cos(theta) * d_psi,
            -np.sin(gamma) * d_theta + np.cos(gamma) * np.cos(theta) * d_psi,
        ]
    )


def to_phone(R: FloatArray, world: FloatArray) -> FloatArray:
    """ENU vectors ``(n, 3)`` (or one ``(3,)``) in phone axes."""
    phone: FloatArray = np.einsum("nji,nj->ni", R, np.broadcast_to(world, (R.shape[0], 3)))
    return phone


def samples(t_s: FloatArray, values: FloatArray) -> FloatArray:
    return np.column_stack([T0_MS + 1000.0 * t_s, values])


def top_edge_heading(R: FloatArray) -> FloatArray:
    """Heading of the phone's y axis projected on the horizontal, clockwise from north."""
    return wrap_angle(np.arctan2(R[:, 0, 1], R[:, 1, 1]))


@dataclass(frozen=True)
class Walk:
    gyro: FloatArray  # (n, 4)
    accel: FloatArray  # (n, 4)
    magnetic: FloatArray  # (n // 2, 4)
    heading_rad: FloatArray  # (n,) truth at the gyro times
    disturbed: NDArray[np.bool_]  # (n,) local field present at the gyro times


@dataclass(frozen=True)
class Motion:
    t_s: FloatArray
    R: FloatArray
    omega: FloatArray  # phone axes, rad/s
    accel: FloatArray  # specific force, phone axes, m/s²


def motion(t_s: FloatArray, heading0_deg: float, turn: tuple[float, float, float]) -> Motion:
    """Noise-free sensor readings of the walker at times ``t_s``.

    ``turn = (start_s, duration_s, angle_deg)``: a smooth turn (clockwise for a positive angle).
    """
    w1, w2 = 2.0 * np.pi, 4.0 * np.pi
    x = np.clip((t_s - turn[0]) / turn[1], 0.0, 1.0)
    heading = (
        math.radians(heading0_deg)
        + math.radians(turn[2]) * (3.0 * x**2 - 2.0 * x**3)
        + math.radians(3.0) * np.sin(w1 * t_s)
    )
    d_heading = math.radians(turn[2]) * 6.0 * x * (1.0 - x) / turn[1] + math.radians(
        3.0
    ) * w1 * np.cos(w1 * t_s)
    psi, d_psi = -heading, -d_heading
    theta = math.radians(2.0) * np.sin(w2 * t_s + 0.3)
    d_theta = math.radians(2.0) * w2 * np.cos(w2 * t_s + 0.3)
    gamma = math.radians(15.0) + math.radians(2.0) * np.sin(w1 * t_s + 1.0)
    d_gamma = math.radians(2.0) * w1 * np.cos(w1 * t_s + 1.0)
    R = rotation(psi, theta, gamma)
    forward = np.column_stack([np.sin(heading), np.cos(heading), np.zeros_like(t_s)])
    right = np.column_stack([np.cos(heading), -np.sin(heading), np.zeros_like(t_s)])
    accel_world = (
        forward * (0.6 * np.sin(w2 * t_s + 1.0))[:, None]
        + right * (0.3 * np.sin(w1 * t_s))[:, None]
        + np.column_stack([np.zeros((len(t_s), 2)), G + 1.5 * np.sin(w2 * t_s)])
    )
    return Motion(
        t_s=t_s,
        R=R,
        omega=body_rates(theta, gamma, d_psi, d_theta, d_gamma),
        accel=to_phone(R, accel_world),
    )


def local_field(t_s: FloatArray, start_s: float, end_s: float) -> FloatArray:
    """The disturbing field in ENU, µT, shape (n, 3): zero outside [start_s, end_s]."""
    s = SPEED_M_S * t_s
    fade_s = 1.0 / SPEED_M_S
    ramp = np.clip(np.minimum(t_s - start_s, end_s - t_s) / fade_s, 0.0, 1.0)
    weight = np.sin(0.5 * np.pi * ramp) ** 2
    field = 20.0 * np.column_stack(
        [
            np.sin(2.0 * np.pi * s / 2.5 + 0.5),
            np.cos(2.0 * np.pi * s / 3.5),
            np.sin(2.0 * np.pi * s / 4.5 + 1.0),
        ]
    )
    disturbance: FloatArray = field * weight[:, None]
    return disturbance


@cache
def walk(
    duration_s: float = 60.0,
    heading0_deg: float = 30.0,
    disturbed_s: tuple[float, float] | None = (25.0, 35.0),
    seed: int = 7,
    turn: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> Walk:
    rng = np.random.default_rng(seed)
    n = round(100.0 * duration_s)
    t_gyro = np.arange(n) / 100.0
    t_accel = t_gyro + 0.003
    t_mag = np.arange(n // 2) / 50.0 + 0.007
    bias = np.radians([0.05, -0.05, 0.5])

    at_gyro = motion(t_gyro, heading0_deg, turn)
    gyro = at_gyro.omega + bias + rng.normal(0.0, 0.003, (n, 3))
    accel = motion(t_accel, heading0_deg, turn).accel + rng.normal(0.0, 0.05, (n, 3))
    at_mag = motion(t_mag, heading0_deg, turn)
    field = np.broadcast_to(EARTH_FIELD_UT, (len(t_mag), 3)).copy()
    disturbed = np.zeros(n, dtype=bool)
    if disturbed_s is not None:
        field += local_field(t_mag, *disturbed_s)
        disturbed = (t_gyro >= disturbed_s[0]) & (t_gyro <= disturbed_s[1])
    magnetic = to_phone(at_mag.R, field) + rng.normal(0.0, 0.3, (len(t_mag), 3))
    return Walk(
        gyro=samples(t_gyro, gyro),
        accel=samples(t_accel, accel),
        magnetic=samples(t_mag, magnetic),
        heading_rad=top_edge_heading(at_gyro.R),
        disturbed=disturbed,
    )


def angle_error_deg(a: FloatArray | float, b: FloatArray | float) -> FloatArray:
    return np.abs(np.degrees(wrap_angle(np.asarray(a) - np.asarray(b))))


# --- heading fusion ---------------------------------------------------------------------


def test_fused_heading_survives_gyro_bias_and_a_disturbed_stretch() -> None:
    data = walk()
    params = HeadingParams()
    _, fused = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)
    _, gyro_only = fuse_heading(
        initial_heading(params), data.gyro, data.accel, np.zeros((0, 4)), params
    )
    truth = data.heading_rad

    assert fused.shape == (len(data.gyro), 3)
    np.testing.assert_array_equal(fused[:, 0], data.gyro[:, 0])
    assert angle_error_deg(fused[-1, 1], truth[-1]) < 2.0
    assert np.max(angle_error_deg(fused[-500:, 1], truth[-500:])) < 2.0
    # integrating the gyro alone from the true start drifts: the bias about the vertical
    # (0.47 deg/s, 28 deg in 60 s) less the walking accelerations leaking into the up vector
    drifted = truth[0] + gyro_only[-1, 1] - gyro_only[0, 1]
    assert angle_error_deg(drifted, truth[-1]) > 10.0


def test_disturbed_stretch_is_not_quasi_static() -> None:
    data = walk()
    params = HeadingParams()
    _, fused = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)
    qsmf = fused[:, 2] == 1.0
    t_s = (fused[:, 0] - T0_MS) / 1000.0
    clean = ~data.disturbed & (t_s > 2.0)

    assert np.isin(fused[:, 2], [0.0, 1.0]).all()
    assert qsmf[data.disturbed].mean() < 0.1
    assert qsmf[clean].mean() > 0.8


def test_fused_heading_follows_a_turn_and_the_sway() -> None:
    data = walk(duration_s=30.0, heading0_deg=-120.0, disturbed_s=None, turn=(10.0, 3.0, 90.0))
    params = HeadingParams()
    _, fused = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)
    assert np.max(angle_error_deg(fused[500:, 1], data.heading_rad[500:])) < 2.0


def test_gyro_only_heading_starts_at_zero_and_is_never_quasi_static() -> None:
    data = walk(duration_s=5.0, disturbed_s=None)
    params = HeadingParams()
    state, out = fuse_heading(
        initial_heading(params), data.gyro, data.accel, np.empty((0, 4)), params
    )
    assert out[0, 1] == 0.0
    assert not state.initialized
    assert (out[:, 2] == 0.0).all()


# --- frames: compass, rotation vector, yaw ------------------------------------------------


CARDINALS_DEG = [0.0, 90.0, 180.0, -90.0]
TILTS_DEG = [(0.0, 0.0), (30.0, 0.0), (0.0, 30.0), (-30.0, 0.0), (0.0, -30.0)]


@pytest.mark.parametrize("heading_deg", CARDINALS_DEG)
@pytest.mark.parametrize(("pitch_deg", "roll_deg"), TILTS_DEG)
def test_headings_for_a_phone_pointing_north_east_south_west(
    heading_deg: float, pitch_deg: float, roll_deg: float
) -> None:
    psi = -math.radians(heading_deg)
    R = rotation(np.array([psi]), np.radians([pitch_deg]), np.radians([roll_deg]))
    up = to_phone(R, np.array([0.0, 0.0, 1.0]))
    field = to_phone(R, EARTH_FIELD_UT)
    expected = math.radians(heading_deg)

    assert angle_error_deg(compass_heading(samples(np.zeros(1), field), up), expected)[0] < 1e-9
    q = Rotation.from_matrix(R[0]).as_quat()  # [x, y, z, w]
    assert angle_error_deg(rotation_heading(np.array([[T0_MS, *q]]))[0, 1], expected) < 1e-9
    unknown_w = np.array([[T0_MS, *(q * np.sign(q[3]))[:3], np.nan]])
    assert angle_error_deg(rotation_heading(unknown_w)[0, 1], expected) < 1e-4
    assert angle_error_deg(heading_from_yaw(np.array([psi]))[0], expected) < 1e-9
    # a flat phone pointing north reads heading 0; gravity and the field in phone axes
    np.testing.assert_allclose(gravity_direction(samples(np.zeros(1), G * up)), up)


def test_compass_heading_of_a_flat_phone_by_hand() -> None:
    # flat, top edge east: phone x points south, y east; the field points north and down
    field = np.array([[T0_MS, -25.7, 0.0, -30.6]])
    up = np.array([[0.0, 0.0, 1.0]])
    assert compass_heading(field, up)[0] == pytest.approx(math.pi / 2)
    # rotation vector of a flat phone turned 90 deg clockwise: -90 deg about up
    s = math.sin(math.radians(-45.0))
    assert rotation_heading(np.array([[T0_MS, 0.0, 0.0, s, math.cos(math.radians(-45.0))]]))[
        0, 1
    ] == pytest.approx(math.pi / 2)


def test_vertical_rate_is_the_rate_about_up() -> None:
    R = rotation(np.array([0.4]), np.radians([20.0]), np.radians([-10.0]))
    up = to_phone(R, np.array([0.0, 0.0, 1.0]))
    east = to_phone(R, np.array([1.0, 0.0, 0.0]))
    gyro = samples(np.zeros(1), 0.3 * up + 0.2 * east)
    assert vertical_rate(gyro, up)[0] == pytest.approx(0.3)


# --- attitude-determination EKF -----------------------------------------------------------


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
    return samples(t_s, gyro), samples(t_s + 0.004, accel)


def test_cui_defaults() -> None:
    params = AttitudeParams()
    assert params.d0 == (0.5 * math.pi, 0.0, 0.0)
    assert params.p0 == params.q == params.r == (1.0, 1.0, 1.0)
    state = initial_attitude(params)
    np.testing.assert_array_equal(state.D, [0.5 * math.pi, 0.0, 0.0])
    np.testing.assert_array_equal(state.P, np.eye(3))
    assert math.isnan(state.last_t_ms)
    with pytest.raises(ValueError, match="r must be"):
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


# --- incremental batches ---------------------------------------------------------------------


def split_at(x: FloatArray, t_ms: float) -> tuple[FloatArray, FloatArray]:
    return x[x[:, 0] < t_ms], x[x[:, 0] >= t_ms]


@cache
def short_walk() -> Walk:
    return walk(duration_s=4.0, disturbed_s=(1.5, 2.5), seed=3)


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
            AttitudeState.from_arrays(state.to_arrays()), g_now, a_now, params
        )
        parts.append(out)
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=0.0, atol=1e-9)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=3))
def test_fuse_heading_is_incremental(fractions: list[float]) -> None:
    data = short_walk()
    params = HeadingParams()
    t_min, t_max = data.gyro[0, 0], data.gyro[-1, 0] + 1.0
    cuts = sorted(t_min + f * (t_max - t_min) for f in fractions)
    _, whole = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)

    state = initial_heading(params)
    parts = []
    gyro, accel, magnetic = data.gyro, data.accel, data.magnetic
    for cut in [*cuts, math.inf]:
        g_now, gyro = split_at(gyro, cut)
        a_now, accel = split_at(accel, cut)
        m_now, magnetic = split_at(magnetic, cut)
        state, out = fuse_heading(
            HeadingState.from_arrays(state.to_arrays()), g_now, a_now, m_now, params
        )
        parts.append(out)
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=0.0, atol=1e-9)


def test_states_round_trip_through_arrays() -> None:
    data = short_walk()
    h_params = HeadingParams()
    h_state, _ = fuse_heading(
        initial_heading(h_params), data.gyro, data.accel, data.magnetic, h_params
    )
    a_params = AttitudeParams()
    a_state, _ = attitude_ekf(initial_attitude(a_params), data.gyro, data.accel, a_params)
    for state in (h_state, initial_heading(h_params), a_state, initial_attitude(a_params)):
        arrays = state.to_arrays()
        again = type(state).from_arrays(arrays).to_arrays()
        assert arrays.keys() == again.keys()
        for key, value in arrays.items():
            assert value.dtype == again[key].dtype
            np.testing.assert_array_equal(value, again[key])
    assert 0 < len(h_state.window) <= h_params.window_entries + 2
    with pytest.raises(ValueError, match="shapes"):
        AttitudeState.from_arrays({**a_state.to_arrays(), "P": np.eye(2)})
    with pytest.raises(ValueError, match="shapes"):
        HeadingState.from_arrays({**h_state.to_arrays(), "gravity": np.zeros(2)})


def test_heading_params_are_validated() -> None:
    with pytest.raises(ValueError, match="window_s"):
        HeadingParams(window_s=0.0)
    assert dataclasses.replace(HeadingParams(), q_bias=1e-6).q_bias == 1e-6


def test_compass_heading_without_a_horizontal_field_is_nan() -> None:
    up = np.array([[0.0, 0.0, 1.0]])
    assert np.isnan(compass_heading(np.array([[T0_MS, 0.0, 0.0, -40.0]]), up)).all()
