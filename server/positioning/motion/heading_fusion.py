"""Gyro and compass heading fusion (``papers/003_*`` section III).

Frames and units are those of the package docstring; the gyro drives the filter and the
accelerometer and magnetometer are aligned to it as ``sensor_streams`` describes.

Mansour et al. fuse by "weighted fusion" the gyro relative heading, reliable in the short
term, and the absolute compass heading, trusted during quasi-static magnetic field (QSMF)
periods. We realise it as a Kalman filter on ``x = [h, b]``, heading h (clockwise from
magnetic north) and gyro bias b about the vertical (rad/s, counter-clockwise positive like
the measured vertical rate ``w``)::

    h_k = h_{k-1} - (w_bar - b_{k-1}) dt,    b_k = b_{k-1}
    F = [[1, dt], [0, 1]],    Q = diag(q_heading, q_bias) dt

where ``w_bar`` is the mean of the vertical rates ``w = omega . u`` of the two samples and
``u`` the unit up vector in phone axes from a first-order low-pass of the accelerometer.
Each new magnetometer sample gives the tilt-compensated compass heading ``c`` and the field
magnitude ``|B|``. It updates the filter (``z = c``, ``H = [1, 0]``, innovation wrapped)
only during QSMF: over the last ``window_s`` the standard deviation of ``|B|`` is below
``qsmf_magnitude_std_ut`` *and* the compass heading changed by the same amount as the
bias-corrected gyro heading, within ``qsmf_agreement_rad``. The first test admits a
stationary field, the second a field whose direction is the earth's. Outside QSMF the
heading follows the gyro with the estimated bias removed; the compass therefore weighs in
according to the availability of QSMF periods and the agreement (correlation) of the two
sources, and the bias it teaches the filter carries the gyro through disturbed stretches.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from annotated_types import Ge, Gt, Le
from numpy.typing import NDArray

from server.positioning.model.params import Params, Positive
from server.positioning.model.state_codec import shape
from server.positioning.motion.sensor_geometry import (
    compass_heading,
    unit,
    vertical_rate,
    wrap_float,
)
from server.positioning.motion.sensor_streams import (
    MAX_GAP_S,
    fresh,
    held_index,
    lowpass,
    samples,
    with_carried,
)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class HeadingParams(Params):
    """Parameters of the gyro/compass heading filter.

    The defaults assume a phone gyro with a bias of up to about 1 deg/s and a magnetometer
    at about 50 Hz with 0.3-0.6 µT of noise.
    """

    window_s: Annotated[float, Gt(0), Le(10)] = 1.0  # QSMF sliding window, s
    # std of |B| over the window below which the field is quasi-static, µT: about twice the
    # noise of phone magnetometers (0.3-0.6 µT rms), while indoor disturbances change |B|
    # by several µT over a metre, i.e. within a second of walking
    qsmf_magnitude_std_ut: Positive = 1.0
    # compass and gyro heading changes over the window agree within this, rad: a compass
    # sample is good to about 1 deg, and a gyro bias of 1 deg/s adds 1 deg a window
    qsmf_agreement_rad: Positive = math.radians(5.0)
    # heading random walk, rad²/s: gyro white noise plus the error of projecting the rates
    # on a low-passed vertical while the phone sways; (0.2 deg)² per s
    q_heading: Positive = math.radians(0.2) ** 2
    q_bias: Positive = 1e-8  # gyro bias random walk, rad²/s³ (its std grows 0.04 deg/s a minute)
    # compass heading variance per magnetometer sample, rad²: larger than the noise of one
    # sample because tilt errors and small disturbances are correlated over many samples;
    # with q_heading it sets a ~3 s time constant for the compass pull at 50 Hz
    r_compass_rad2: Positive = math.radians(5.0) ** 2
    p0_heading_rad2: Positive = math.radians(20.0) ** 2  # at the first compass heading
    p0_bias_rad2_s2: Positive = math.radians(1.0) ** 2  # initial gyro bias variance, (rad/s)²
    # low-pass time constant for the up vector, s. Walking accelerations leak into the
    # low-passed up vector at the step frequency, and their product with the phone's sway
    # rates integrates to a heading drift roughly proportional to 1 / tau (on the
    # synthetic walk of the tests 7.5 deg/min at 0.5 s, 3.9 at 1 s, 2.0 at 2 s) which the
    # bias state must absorb; a longer tau lags behind changes of how the phone is held
    gravity_tau_s: Positive = 1.0
    # samples kept per window (ring buffer spacing window_s / this)
    window_entries: Annotated[int, Ge(2), Le(1000)] = 50


@dataclass(frozen=True)
class HeadingState:
    """State of the heading filter between batches.

    Attributes
    ----------
    heading : float
        Heading, rad, clockwise from magnetic north (relative to the start while
        ``initialized`` is False).
    bias : float
        Gyro bias about the vertical, rad/s, counter-clockwise positive.
    P : ndarray, shape (2, 2)
        Covariance of ``[heading, bias]``.
    last_t_ms : float
        Time of the last gyro sample; NaN before any.
    last_rate : float
        Vertical rate of that sample, rad/s; NaN before any.
    gravity : ndarray, shape (3,)
        Low-passed accelerometer, m/s², phone axes; NaN before any sample.
    gravity_t_ms : float
        Time of the last accelerometer sample; NaN before any.
    last_magnetic : ndarray, shape (4,)
        Last magnetometer sample seen ``[t_ms, x, y, z]``; NaN before any.
    gyro_heading : float
        Bias-corrected gyro integral, rad, wrapped: the gyro side of the QSMF agreement test.
    window : ndarray, shape (m, 4)
        Ring buffer ``[t_ms, |B| µT, compass rad, gyro_heading rad]`` covering the last
        ``window_s`` (``m <= window_entries + 2``), oldest first.
    qsmf : bool
        Whether the last magnetometer sample was in a QSMF period.
    initialized : bool
        False until the first compass heading.
    """

    heading: float
    bias: float
    P: FloatArray = field(metadata=shape(2, 2))
    last_t_ms: float
    last_rate: float
    gravity: FloatArray = field(metadata=shape(3))
    gravity_t_ms: float
    last_magnetic: FloatArray = field(metadata=shape(4))
    gyro_heading: float
    window: FloatArray = field(metadata=shape(-1, 4))
    qsmf: bool
    initialized: bool


def initial_heading(params: HeadingParams) -> HeadingState:
    """An uninitialised heading filter: heading 0, zero bias, before any sample."""
    return HeadingState(
        heading=0.0,
        bias=0.0,
        P=np.diag([params.p0_heading_rad2, params.p0_bias_rad2_s2]),
        last_t_ms=math.nan,
        last_rate=math.nan,
        gravity=np.full(3, np.nan),
        gravity_t_ms=math.nan,
        last_magnetic=np.full(4, np.nan),
        gyro_heading=0.0,
        window=np.zeros((0, 4)),
        qsmf=False,
        initialized=False,
    )


def _up_at(
    state: HeadingState, accel: FloatArray, t_ms: FloatArray, tau_s: float
) -> tuple[FloatArray, FloatArray, float]:
    """Unit up vectors at the gyro times (held low-pass values; phone z before any sample).

    Returns the up vectors ``(n, 3)``, the new low-pass value ``(3,)`` and its time.
    """
    filtered, gravity = lowpass(accel, tau_s, state.gravity, state.gravity_t_ms)
    times = accel[:, 0]
    if math.isfinite(state.gravity_t_ms):
        filtered = np.vstack([state.gravity[None, :], filtered])
        times = np.concatenate([[state.gravity_t_ms], times])
    up = np.tile([0.0, 0.0, 1.0], (len(t_ms), 1))
    held = held_index(times, t_ms)
    known = held >= 0
    up[known] = unit(filtered[held[known]])
    gravity_t_ms = float(accel[-1, 0]) if len(accel) else state.gravity_t_ms
    return up, gravity, gravity_t_ms


def _quasi_static(
    window: deque[tuple[float, float, float, float]],
    t_ms: float,
    magnitude_ut: float,
    compass: float,
    gyro_heading: float,
    params: HeadingParams,
) -> bool:
    """QSMF test at a magnetometer sample; prunes ``window`` and appends the sample to it."""
    window_ms = 1000.0 * params.window_s
    if window and t_ms - window[-1][0] > window_ms:
        window.clear()  # a gap in the magnetometer stream: start a new window
    while len(window) >= 2 and t_ms - window[1][0] >= window_ms:
        window.popleft()  # keep one sample at or before the start of the window
    qsmf = False
    if window and t_ms - window[0][0] >= window_ms:
        magnitudes = [e[1] for e in window]
        magnitudes.append(magnitude_ut)
        mean = sum(magnitudes) / len(magnitudes)
        var = sum((m - mean) ** 2 for m in magnitudes) / len(magnitudes)
        _, _, compass_0, gyro_0 = window[0]
        d_compass = wrap_float(compass - compass_0)
        d_gyro = wrap_float(gyro_heading - gyro_0)
        agreement = abs(wrap_float(d_compass - d_gyro))
        qsmf = (
            math.sqrt(var) < params.qsmf_magnitude_std_ut and agreement < params.qsmf_agreement_rad
        )
    if not window or t_ms - window[-1][0] >= window_ms / params.window_entries:
        window.append((t_ms, magnitude_ut, compass, gyro_heading))
    return qsmf


def fuse_heading(
    state: HeadingState,
    gyro: FloatArray,
    accel: FloatArray,
    magnetic: FloatArray,
    params: HeadingParams,
) -> tuple[HeadingState, FloatArray]:
    """Fuse gyro and compass headings (``papers/003_*`` section III) over a batch.

    Parameters
    ----------
    state : HeadingState
        ``initial_heading(params)`` or the state after the previous batch.
    gyro : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` rad/s, times increasing and after ``state.last_t_ms``.
    accel : ndarray, shape (m, 4)
        ``[t_ms, x, y, z]`` m/s²; may be empty (the phone is then taken as lying flat
        until the first sample).
    magnetic : ndarray, shape (l, 4)
        ``[t_ms, x, y, z]`` µT; may be empty (the heading then follows the gyro, from 0
        while the filter has not seen a compass heading).
    params : HeadingParams

    Returns
    -------
    state : HeadingState
    heading : ndarray, shape (n, 3)
        ``[t_ms, heading_rad, qsmf]`` after each gyro sample: heading clockwise from
        magnetic north in (-pi, pi], and 1.0 while the field is quasi-static (0.0
        otherwise, and when no magnetometer sample came within ``window_s``).
    """
    g = samples(gyro)
    a = samples(accel)
    m = with_carried(state.last_magnetic, samples(magnetic))
    t = g[:, 0]
    up, gravity, gravity_t_ms = _up_at(state, a, t, params.gravity_tau_s)
    rates = vertical_rate(g, up).tolist()
    held = held_index(m[:, 0], t)
    is_fresh = fresh(m[:, 0], held, t, state.last_t_ms)
    compass_arr = np.full(len(t), np.nan)
    magnitude_arr = np.full(len(t), np.nan)
    field_t_arr = np.full(len(t), np.nan)
    if len(m):
        field = m[held[is_fresh], 1:]
        compass_arr[is_fresh] = compass_heading(field, up[is_fresh])
        magnitude_arr[is_fresh] = np.linalg.norm(field, axis=1)
        field_t_arr[held >= 0] = m[held[held >= 0], 0]
    compass, magnitude, field_t = compass_arr.tolist(), magnitude_arr.tolist(), field_t_arr.tolist()

    h, b, gh = state.heading, state.bias, state.gyro_heading
    p_hh, p_hb, p_bb = float(state.P[0, 0]), float(state.P[0, 1]), float(state.P[1, 1])
    t_prev, w_prev = state.last_t_ms, state.last_rate
    qsmf, initialized = state.qsmf, state.initialized
    window: deque[tuple[float, float, float, float]] = deque(
        (float(e[0]), float(e[1]), float(e[2]), float(e[3])) for e in state.window
    )
    r = params.r_compass_rad2
    out = np.empty((len(g), 3))
    for k, t_k in enumerate(t.tolist()):
        w = rates[k] if math.isfinite(rates[k]) else 0.0  # no vertical: no known turn
        if math.isfinite(t_prev) and 0.0 <= t_k - t_prev <= 1000.0 * MAX_GAP_S:
            dt = (t_k - t_prev) / 1000.0
            turn = (0.5 * (w_prev + w) - b) * dt  # counter-clockwise, bias removed
            h = wrap_float(h - turn)
            gh = wrap_float(gh - turn)
            # P = F P F^T + Q dt with F = [[1, dt], [0, 1]]
            p_hh = p_hh + 2.0 * dt * p_hb + dt * dt * p_bb + params.q_heading * dt
            p_hb = p_hb + dt * p_bb
            p_bb = p_bb + params.q_bias * dt
        c = compass[k]
        if not math.isnan(c):
            if not initialized:
                h, p_hh, p_hb, initialized = c, params.p0_heading_rad2, 0.0, True
                window.clear()
            qsmf = _quasi_static(window, t_k, magnitude[k], c, gh, params)
            if qsmf:
                # z = h + v, H = [1, 0]; Joseph form reduces to these for a scalar update
                s = p_hh + r
                k_h, k_b = p_hh / s, p_hb / s
                y = wrap_float(c - h)
                h = wrap_float(h + k_h * y)
                b = b + k_b * y
                p_hh, p_hb, p_bb = (
                    (1.0 - k_h) ** 2 * p_hh + k_h * k_h * r,
                    (1.0 - k_h) * (p_hb - k_b * p_hh) + k_h * k_b * r,
                    p_bb - 2.0 * k_b * p_hb + k_b * k_b * p_hh + k_b * k_b * r,
                )
        elif qsmf and not t_k - field_t[k] <= 1000.0 * params.window_s:
            qsmf = False  # no magnetometer sample for a whole window
        out[k] = (t_k, h, 1.0 if qsmf else 0.0)
        t_prev, w_prev = t_k, w

    new = HeadingState(
        heading=h,
        bias=b,
        P=np.array([[p_hh, p_hb], [p_hb, p_bb]]),
        last_t_ms=t_prev,
        last_rate=w_prev,
        gravity=gravity,
        gravity_t_ms=gravity_t_ms,
        last_magnetic=m[-1].copy() if len(m) else state.last_magnetic.copy(),
        gyro_heading=gh,
        window=np.array(list(window), dtype=np.float64).reshape(-1, 4),
        qsmf=qsmf,
        initialized=initialized,
    )
    return new, out
