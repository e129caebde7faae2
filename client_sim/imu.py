"""Synthetic raw phone IMU of a walk: accelerometer, gyroscope, magnetometer, rotation
vector and barometer of a phone held in front of a pedestrian, with the truth they come
from.

Frames and units are the wire's: phone axes are Android's (x to the right edge, y to the
top edge, z out of the screen), the world is east-north-up, a heading is in radians
clockwise from north, the accelerometer gives specific force in m/s² with gravity
included, the gyroscope rad/s right-handed about the phone axes, the magnetometer µT and
the barometer hPa.

Motion. The pedestrian follows a *course* ``h(t)`` (a function, or knots joined by
smoothsteps so that the turn rate is continuous) and walks during given intervals, each
cut to a whole number of steps at ``cadence_hz``. The gait phase is::

    phi(t) = 2 pi f w(t)            w(t): seconds walked before t

so it advances by ``2 pi`` per step and stands still (at a multiple of ``2 pi``) between
the intervals. Step ``k`` of an interval starting at ``s`` is one cycle of the vertical
bounce: its peak is at ``s + (k + 1/4) / f`` and its valley at ``s + (k + 3/4) / f``. The
*true step time* ``step_t_ms`` is the valley, which completes the peak-valley pair (the
step detector of ``papers/003_*`` reports this instant; a peak detector such as
``papers/002_*`` reports ``peak_t_ms``, half a cycle earlier).

The phone is held screen up with its top edge along the course. Its attitude is the Z-Y-X
Euler product (the convention of the server's attitude EKF, ``papers/002_*`` eq 16)::

    R = Rz(psi) Ry(theta) Rx(gamma),    psi = -(h + sway_h sin(phi / 2))
    theta = tilt_y + sway_y sin(phi),   gamma = tilt_x + sway_x sin(phi / 2)

``R`` maps phone vectors to ENU; ``gamma > 0`` raises the top edge, ``theta > 0`` lowers
the right edge; the heading sways once per stride (two steps). The sensors read::

    accel    = R^T (g up + b sin(phi) up + s cos(phi) [walking] fwd + l sin(phi / 2) right
                    + tremor) + noise
    gyro     = omega + bias + noise,    omega: body rates, R(t - e)^T R(t + e) = exp(2 e [omega]x)
    magnetic = R^T (B + disturbance(t, xy)) + noise
    rotation = the unit quaternion of R, [x, y, z, w] with w >= 0

where ``fwd`` and ``right`` follow the course, the tremor is one sinusoid per world axis at
a random frequency in 8-12 Hz (physiological hand tremor), and the noises are white and
Gaussian. Positions integrate ``step_length_m * cadence_hz`` along the course while walking.

Height. The phone's height ``z(t)`` above where it starts is given apart from the course,
as knots joined by straight lines (0 throughout by default): a staircase is a walking
interval while ``z`` climbs, a lift ride a standing one. Only the barometer sees it; it
reads the standard atmosphere plus the phone's own offset, a linear weather drift and
white noise::

    pressure = p0 (1 - 2.25577e-5 z) ** 5.25588 + bias + w t / 3600 + noise

with ``p0`` the pressure at height 0 at the start (``ground_hpa``), ``z`` in m, ``t`` in s
and the weather drift ``w`` in hPa/h. Near sea level it falls by about 0.12 hPa per metre
climbed.

Pure: the same arguments and generator state give the same trace. Each sensor is sampled
at its own rate from its own offset, at whole milliseconds (``t0_ms + offset + round(1000 k
/ rate)``), as phones send them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

G = 9.80665  # standard gravity, m/s²
T0_MS = 1_700_000_000_000

HeadingProfile = Callable[[FloatArray], FloatArray] | ArrayLike
"""A course: a vectorised function of time in seconds since the start, or knots
``(k, 2)`` ``[t_s, heading_rad]`` with increasing times (smoothstep between knots,
constant outside them; the heading turns the way the numbers go, so unwrap them)."""

Disturbance = Callable[[FloatArray, FloatArray], FloatArray]
"""Local magnetic field ``(t_s (n,), xy_m (n, 2)) -> (n, 3)`` µT in east-north-up."""

_DIFF_S = 1e-4  # half-width of the central difference giving the body rates
_LAPSE_PER_M = 2.25577e-5  # standard atmosphere: temperature lapse over sea-level temperature
_BARO_EXPONENT = 5.25588  # g M / (R L)


@dataclass(frozen=True)
class Gait:
    """How the pedestrian walks and holds the phone (module docstring for the symbols)."""

    cadence_hz: float = 1.8  # steps per second, f
    step_length_m: float = 0.7
    bounce_ms2: float = 2.5  # b: vertical, one cycle per step
    surge_ms2: float = 0.5  # s: forward, one cycle per step, a quarter cycle ahead
    lateral_ms2: float = 0.2  # l: sideways, one cycle per stride
    heading_sway_rad: float = 0.0  # sway_h: phone heading, one cycle per stride
    tilt_x_rad: float = 0.0  # gamma: about the phone's x axis, > 0 raises the top edge
    tilt_y_rad: float = 0.0  # theta: about the phone's y axis, > 0 lowers the right edge
    sway_x_rad: float = 0.0  # sway_x: of gamma, one cycle per stride
    sway_y_rad: float = 0.0  # sway_y: of theta, one cycle per step
    tremor_ms2: float = 0.0  # amplitude of the hand tremor per world axis

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cadence_hz) and self.cadence_hz > 0):
            raise ValueError(f"cadence_hz must be positive, got {self.cadence_hz}")
        if not (math.isfinite(self.step_length_m) and self.step_length_m >= 0):
            raise ValueError(f"step_length_m must not be negative, got {self.step_length_m}")


@dataclass(frozen=True)
class Sensors:
    """Rates, clock offsets, errors of the phone's sensors and the earth field."""

    accel_hz: float = 50.0
    gyro_hz: float = 50.0
    magnetic_hz: float = 50.0
    rotation_hz: float = 50.0
    accel_offset_ms: int = 0  # first sample after the start of the walk
    gyro_offset_ms: int = 0
    magnetic_offset_ms: int = 0
    rotation_offset_ms: int = 0
    accel_noise_ms2: float = 0.05  # per axis
    gyro_noise_rads: float = 0.003  # per axis
    gyro_bias_rads: tuple[float, float, float] = (0.0, 0.0, 0.0)  # phone axes
    magnetic_noise_ut: float = 0.3  # per axis
    field_ut: tuple[float, float, float] = (0.0, 20.0, -40.0)  # ENU: north and down
    pressure_hz: float = 25.0
    pressure_offset_ms: int = 0
    pressure_noise_hpa: float = 0.02  # white, per sample
    pressure_bias_hpa: float = 0.0  # this phone's offset: phones side by side differ ~0.5 hPa
    ground_hpa: float = 1013.25  # p0: at height 0 when the walk starts
    weather_hpa_per_h: float = 0.0  # linear drift over the walk; weather moves up to ~1 hPa/h

    def __post_init__(self) -> None:
        for name in ("accel", "gyro", "magnetic", "rotation", "pressure"):
            rate = getattr(self, f"{name}_hz")
            if not 0 < rate <= 1000:
                raise ValueError(f"{name}_hz must be in (0, 1000], got {rate}")
            if getattr(self, f"{name}_offset_ms") < 0:
                raise ValueError(f"{name}_offset_ms must not be negative")


@dataclass(frozen=True, eq=False)
class ImuTrace:
    """Raw samples of a synthetic walk and its truth.

    Attributes
    ----------
    accel, gyro, magnetic : ndarray, shape (n_sensor, 4)
        ``[t_ms, x, y, z]`` in phone axes, times whole milliseconds, strictly increasing.
    rotation : ndarray, shape (n_rotation, 5)
        ``[t_ms, x, y, z, w]`` phone-to-ENU unit quaternion, ``w >= 0``.
    pressure : ndarray, shape (n_pressure, 2)
        ``[t_ms, hPa]`` barometer.
    t_ms : ndarray, shape (n,), int64
        Times of the truth: the gyro sample times.
    heading : ndarray, shape (n,)
        Heading of the phone's top edge projected on the horizontal, rad, in (-pi, pi].
    xy : ndarray, shape (n, 2)
        Position east and north of the start, m.
    height_m : ndarray, shape (n,)
        Height above the start, m.
    step_t_ms, peak_t_ms : ndarray, shape (k,), int64
        Valley (true step time) and peak of each step's bounce cycle.
    t0_ms : int
        Phone clock at the start of the walk.
    """

    accel: FloatArray
    gyro: FloatArray
    magnetic: FloatArray
    rotation: FloatArray
    t_ms: IntArray
    heading: FloatArray
    xy: FloatArray
    step_t_ms: IntArray
    peak_t_ms: IntArray
    t0_ms: int
    pressure: FloatArray
    height_m: FloatArray

    @property
    def n_steps(self) -> int:
        return int(self.step_t_ms.size)


@dataclass(frozen=True, eq=False)
class Block:
    """The samples of each sensor in ``[t_ms, t_ms + block_ms)``."""

    t_ms: int
    accel: FloatArray
    gyro: FloatArray
    magnetic: FloatArray
    rotation: FloatArray
    pressure: FloatArray

    def event(self) -> dict[str, Any]:
        """The block as a wire ``imu`` event (rows ``[t, ...]`` with integer times)."""

        def rows(samples: FloatArray) -> list[list[float | int]]:
            return [[int(r[0]), *r[1:]] for r in samples.tolist()]

        return {
            "type": "imu",
            "t": self.t_ms,
            "accel": rows(self.accel),
            "gyro": rows(self.gyro),
            "magnetic": rows(self.magnetic),
            "rotation": rows(self.rotation),
            "pressure": rows(self.pressure),
        }


def _knots(values: ArrayLike, name: str) -> tuple[FloatArray, FloatArray]:
    """Times and values of knots ``(k, 2)``, checked."""
    knots = np.asarray(values, dtype=np.float64).reshape(-1, 2)
    t_k, v_k = knots[:, 0], knots[:, 1]
    if t_k.size == 0 or np.any(np.diff(t_k) <= 0):
        raise ValueError(f"{name} knots need at least one row and increasing times")
    return t_k, v_k


def _course(heading: HeadingProfile) -> Callable[[FloatArray], FloatArray]:
    if callable(heading):
        return heading
    t_k, h_k = _knots(heading, "heading")
    if t_k.size == 1:
        return lambda t: np.full(np.shape(t), h_k[0])

    def smoothstep(t: FloatArray) -> FloatArray:
        i = np.clip(np.searchsorted(t_k, t, side="right") - 1, 0, t_k.size - 2)
        x = np.clip((t - t_k[i]) / (t_k[i + 1] - t_k[i]), 0.0, 1.0)
        return np.asarray(h_k[i] + (h_k[i + 1] - h_k[i]) * x * x * (3.0 - 2.0 * x))

    return smoothstep


@dataclass(frozen=True)
class _Walking:
    """Walking intervals cut to whole steps: ``start`` and ``end`` (m,), seconds."""

    start: FloatArray
    end: FloatArray
    cadence_hz: float

    def walked_s(self, t: FloatArray) -> FloatArray:
        spans = np.clip(t[:, None] - self.start[None, :], 0.0, (self.end - self.start)[None, :])
        return np.asarray(spans.sum(axis=1), dtype=np.float64)

    def phase(self, t: FloatArray) -> FloatArray:
        return 2.0 * math.pi * self.cadence_hz * self.walked_s(t)

    def moving(self, t: FloatArray) -> FloatArray:
        inside = (t[:, None] >= self.start[None, :]) & (t[:, None] < self.end[None, :])
        return np.asarray(inside.any(axis=1), dtype=np.float64)

    def cycle_times(self, fraction: float) -> FloatArray:
        """Time of ``fraction`` of each step's cycle, seconds."""
        period = 1.0 / self.cadence_hz
        n = np.rint((self.end - self.start) * self.cadence_hz).astype(np.int64)
        cycles = [
            s + (np.arange(k) + fraction) * period for s, k in zip(self.start, n, strict=True)
        ]
        return np.concatenate([np.empty(0), *cycles])


def _walking(
    intervals: Sequence[tuple[float, float]] | None, duration_s: float, cadence_hz: float
) -> _Walking:
    spans = np.asarray(intervals if intervals is not None else [(0.0, duration_s)], np.float64)
    spans = spans.reshape(-1, 2)
    start, end = spans[:, 0], spans[:, 1]
    if np.any(start < 0) or np.any(end > duration_s) or np.any(end < start):
        raise ValueError("walking intervals must lie within [0, duration_s]")
    if np.any(start[1:] < end[:-1]):
        raise ValueError("walking intervals must be in time order and not overlap")
    n_steps = np.floor((end - start) * cadence_hz + 1e-9)
    return _Walking(start, start + n_steps / cadence_hz, cadence_hz)


def _sample_times(rate_hz: float, offset_ms: int, duration_s: float) -> IntArray:
    k = np.arange(math.ceil(duration_s * rate_hz) + 1)
    t = offset_ms + np.rint(1000.0 * k / rate_hz).astype(np.int64)
    return np.asarray(t[t < 1000.0 * duration_s], dtype=np.int64)


def synthesize_walk(
    heading: HeadingProfile,
    duration_s: float,
    rng: np.random.Generator,
    *,
    walking: Sequence[tuple[float, float]] | None = None,
    gait: Gait | None = None,
    sensors: Sensors | None = None,
    disturbance: Disturbance | None = None,
    t0_ms: int = T0_MS,
    height: ArrayLike | None = None,
) -> ImuTrace:
    """Raw IMU samples of a phone carried along ``heading`` for ``duration_s``.

    Parameters
    ----------
    heading : callable or array_like, shape (k, 2)
        The course (``HeadingProfile``), rad clockwise from north.
    duration_s : float
        Length of the trace; samples at ``0 <= t < duration_s``.
    rng : numpy.random.Generator
        Tremor and sensor noise.
    walking : sequence of (start_s, end_s), optional
        When the pedestrian walks (each interval cut to whole steps); the whole trace by
        default, ``[]`` for standing still (turning on the spot if the course turns).
    gait : Gait, optional
    sensors : Sensors, optional
    disturbance : callable, optional
        A local field added to the earth field (``Disturbance``).
    t0_ms : int
        Phone clock at the start, ms since the epoch.
    height : array_like, shape (k, 2), optional
        Knots ``[t_s, height_m]`` with increasing times: the height above the start,
        straight between knots and constant outside them; 0 throughout by default.

    Returns
    -------
    ImuTrace
    """
    gait = gait if gait is not None else Gait()
    sensors = sensors if sensors is not None else Sensors()
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    course = _course(heading)
    walk = _walking(walking, duration_s, gait.cadence_hz)
    t_z, z_k = _knots(height if height is not None else [(0.0, 0.0)], "height")
    if not np.all(np.isfinite(z_k) & (z_k < 1.0 / _LAPSE_PER_M)):
        raise ValueError("height_m must be finite and below 44 km")

    def attitude(t: FloatArray) -> Rotation:
        phi = walk.phase(t)
        psi = -(course(t) + gait.heading_sway_rad * np.sin(0.5 * phi))
        theta = gait.tilt_y_rad + gait.sway_y_rad * np.sin(phi)
        gamma = gait.tilt_x_rad + gait.sway_x_rad * np.sin(0.5 * phi)
        return Rotation.from_euler("ZYX", np.column_stack([psi, theta, gamma]))

    # positions on a fine grid: distance walked in each interval along its mid course
    grid = np.linspace(0.0, duration_s, max(2, math.ceil(duration_s * 200.0) + 1))
    walked_m = gait.step_length_m * gait.cadence_hz * walk.walked_s(grid)
    mid = course(0.5 * (grid[1:] + grid[:-1]))
    moves = np.diff(walked_m)[:, None] * np.column_stack([np.sin(mid), np.cos(mid)])
    grid_xy = np.vstack([np.zeros((1, 2)), np.cumsum(moves, axis=0)])

    def position(t: FloatArray) -> FloatArray:
        return np.column_stack([np.interp(t, grid, grid_xy[:, i]) for i in range(2)])

    freq = rng.uniform(8.0, 12.0, 3)
    phase0 = rng.uniform(0.0, 2.0 * math.pi, 3)

    def times(name: str) -> tuple[IntArray, FloatArray]:
        rate, offset = getattr(sensors, f"{name}_hz"), getattr(sensors, f"{name}_offset_ms")
        t_ms = _sample_times(rate, offset, duration_s)
        return t0_ms + t_ms, t_ms / 1000.0

    # gyro: body rates by a central difference of the attitude
    gyro_ms, t = times("gyro")
    R = attitude(t)
    omega = (attitude(t - _DIFF_S).inv() * attitude(t + _DIFF_S)).as_rotvec() / (2.0 * _DIFF_S)
    gyro = omega + np.asarray(sensors.gyro_bias_rads)
    gyro += rng.normal(0.0, sensors.gyro_noise_rads, gyro.shape)
    y_axis = R.apply([0.0, 1.0, 0.0])
    true_heading = np.arctan2(y_axis[:, 0], y_axis[:, 1])

    accel_ms, t = times("accel")
    phi = walk.phase(t)
    h = course(t)
    forward = np.column_stack([np.sin(h), np.cos(h), np.zeros_like(h)])
    right = np.column_stack([np.cos(h), -np.sin(h), np.zeros_like(h)])
    force = (
        np.column_stack([np.zeros((t.size, 2)), G + gait.bounce_ms2 * np.sin(phi)])
        + (gait.surge_ms2 * np.cos(phi) * walk.moving(t))[:, None] * forward
        + (gait.lateral_ms2 * np.sin(0.5 * phi))[:, None] * right
        + gait.tremor_ms2 * np.sin(2.0 * math.pi * freq * t[:, None] + phase0)
    )
    accel = attitude(t).apply(force, inverse=True)
    accel += rng.normal(0.0, sensors.accel_noise_ms2, accel.shape)

    magnetic_ms, t = times("magnetic")
    field = np.tile(np.asarray(sensors.field_ut, dtype=np.float64), (t.size, 1))
    if disturbance is not None:
        field = field + disturbance(t, position(t))
    magnetic = attitude(t).apply(field, inverse=True)
    magnetic += rng.normal(0.0, sensors.magnetic_noise_ut, magnetic.shape)

    rotation_ms, t = times("rotation")
    quat = attitude(t).as_quat(canonical=True)

    # drawn last: the other sensors keep the noise they had before there was a barometer
    pressure_ms, t = times("pressure")
    air = sensors.ground_hpa * (1.0 - _LAPSE_PER_M * np.interp(t, t_z, z_k)) ** _BARO_EXPONENT
    pressure = air + sensors.pressure_bias_hpa + sensors.weather_hpa_per_h * t / 3600.0
    pressure += rng.normal(0.0, sensors.pressure_noise_hpa, pressure.shape)

    def stamped(t_ms: IntArray, values: FloatArray) -> FloatArray:
        return np.column_stack([t_ms.astype(np.float64), values])

    def clock(t_s: FloatArray) -> IntArray:
        return t0_ms + np.rint(1000.0 * t_s).astype(np.int64)

    return ImuTrace(
        accel=stamped(accel_ms, accel),
        gyro=stamped(gyro_ms, gyro),
        magnetic=stamped(magnetic_ms, magnetic),
        rotation=stamped(rotation_ms, quat),
        t_ms=gyro_ms,
        heading=true_heading,
        xy=position((gyro_ms - t0_ms) / 1000.0),
        step_t_ms=clock(walk.cycle_times(0.75)),
        peak_t_ms=clock(walk.cycle_times(0.25)),
        t0_ms=t0_ms,
        pressure=stamped(pressure_ms, pressure),
        height_m=np.interp((gyro_ms - t0_ms) / 1000.0, t_z, z_k),
    )


def blocks(trace: ImuTrace, block_ms: float = 1000.0) -> list[Block]:
    """The trace cut into consecutive blocks of ``block_ms`` from its start (edges rounded
    up to whole milliseconds), each sample in exactly one block; blocks without any
    sample are left out."""
    if not block_ms > 0:
        raise ValueError(f"block_ms must be positive, got {block_ms}")
    sensors = (trace.accel, trace.gyro, trace.magnetic, trace.rotation, trace.pressure)
    last = max((float(s[-1, 0]) for s in sensors if s.shape[0]), default=float(trace.t0_ms))
    n = math.floor((last - trace.t0_ms) / block_ms) + 1
    edges = trace.t0_ms + np.ceil(np.arange(n + 1) * block_ms)
    cuts = [np.searchsorted(s[:, 0], edges) for s in sensors]
    out = []
    for k in range(n):
        parts = [s[c[k] : c[k + 1]] for s, c in zip(sensors, cuts, strict=True)]
        if any(p.shape[0] for p in parts):
            out.append(Block(int(edges[k]), *parts))
    return out
