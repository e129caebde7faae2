"""A synthetic phone for the sensor tests: exact rotations, and a walker's sensor samples.

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

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters.kalman import wrap_angle
from server.positioning.motion.sensor_geometry import G

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


def split_at(x: FloatArray, t_ms: float) -> tuple[FloatArray, FloatArray]:
    return x[x[:, 0] < t_ms], x[x[:, 0] >= t_ms]


@cache
def short_walk() -> Walk:
    return walk(duration_s=4.0, disturbed_s=(1.5, 2.5), seed=3)
