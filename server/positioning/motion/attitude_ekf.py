"""Attitude-determination EKF (``papers/002_*`` section 6.1, eq 9-17, Algorithm 1 steps 1-3).

Frames and units are those of the package docstring; the gyro drives the filter and the
accelerometer is aligned to it as ``sensor_streams`` describes.

The state is the Z-Y-X Euler angles ``D = [psi, theta, gamma]`` (eq 9): yaw psi about the
world up axis (counter-clockwise seen from above), pitch theta about the phone's y axis,
roll gamma about the phone's x axis, so that the direction cosine matrix of eq 16::

    T = Rz(psi) Ry(theta) Rx(gamma)

maps phone vectors to east-north-up vectors. The system model is the Euler-angle
kinematics with the body rates ``omega = [p, q, r]`` of the previous sample (eq 12)::

    psi_k   = psi_{k-1}   + (sin(gamma) q + cos(gamma) r) / cos(theta) dt
    theta_k = theta_{k-1} + (cos(gamma) q - sin(gamma) r) dt
    gamma_k = gamma_{k-1} + (p + (sin(gamma) q + cos(gamma) r) tan(theta)) dt

Eq 12 as printed labels the rates as ``omega_x = q``, ``omega_y = p``, ``omega_z = -r``
(a forward-right-down carrier frame), which does not match the DCM of eq 16; the standard
Z-Y-X kinematics above are the ones consistent with eq 16 and with Android's axes.
The measurement (eq 14-15) is the accelerometer in units of g, which for a phone at rest
is the up direction expressed in phone axes::

    A_k = T_k^T [0, 0, 1]^T + v_k = [-sin(theta), sin(gamma) cos(theta),
                                      cos(gamma) cos(theta)]^T + v_k

(``T^-1 = T^T``). The filter starts at ``D_0 = [pi/2, 0, 0]`` with ``P_0 = I`` (eq 10-11)
and uses ``Q_1 = I`` and ``R_1 = I`` per sample (eq 13, 17); all four are ``AttitudeParams``
defaults that may be overridden. The accelerometer cannot observe yaw, so psi is the
integrated gyroscope from ``D_0``; Cui's psi is counter-clockwise, and
``sensor_geometry.heading_from_yaw`` converts it to our heading.

Algebra. The prediction ``P^- = F P F^T + Q_1`` and the Joseph-form update are those of
``server.positioning.filters.kalman``, written out on the tuples of ``matrix3`` because numpy's
per-call cost dominates at 3×3. Over ILC 2.0 trace ``site2/F1/5dd365f944333f00067aa11a``
(5,133 gyro and 5,133 accelerometer samples, 102 s, one batch; best of 7 ``timeit``
runs) this filter takes 11-12 µs per gyro sample; the same filter on
``kalman.predict_ekf`` and ``kalman.update`` takes 73-90 µs (6-8x), its outputs equal
within 5e-14 rad. ``.venv/bin/python -m bench.attitude_ekf`` from the repository root
measures both (CPython 3.11.7, numpy 2.4.6, scipy 1.17.1, the machine of
``bench/performance.md``, shared with other jobs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from annotated_types import Gt
from numpy.typing import NDArray

from server.positioning.model.params import Params
from server.positioning.model.state_codec import shape
from server.positioning.motion.matrix3 import (
    Matrix3,
    add,
    diagonal,
    inverse,
    matrix3,
    mul,
    symmetric,
    transpose,
)
from server.positioning.motion.sensor_geometry import G, wrap_float
from server.positioning.motion.sensor_streams import (
    MAX_GAP_S,
    fresh,
    held_index,
    samples,
    with_carried,
)

FloatArray = NDArray[np.float64]

MIN_GRAVITY_G = 0.1  # an accelerometer sample weaker than this has no direction to use
MAX_ATTITUDE_VAR = 1e6  # beyond this the attitude filter has diverged and starts again

_MIN_COS_PITCH = 1e-3  # |cos(theta)| floor in eq 12: the Z-Y-X kinematics are singular at ±90°


Variances3 = Annotated[tuple[float, float, float], Gt(0)]  # three positive variances


@dataclass(frozen=True)
class AttitudeParams(Params):
    """Parameters of the attitude-determination EKF, Cui's values by default."""

    d0: tuple[float, float, float] = (0.5 * math.pi, 0.0, 0.0)  # [psi, theta, gamma], eq 10
    p0: Variances3 = (1.0, 1.0, 1.0)  # diag of P_0, rad², eq 11
    q: Variances3 = (1.0, 1.0, 1.0)  # diag of Q_1 per gyro sample, rad², eq 13
    r: Variances3 = (1.0, 1.0, 1.0)  # diag of R_1 per accel sample, g², eq 17


@dataclass(frozen=True)
class AttitudeState:
    """State of the attitude-determination EKF between batches.

    Attributes
    ----------
    D : ndarray, shape (3,)
        ``[psi, theta, gamma]``, rad (psi and gamma wrapped to (-pi, pi]).
    P : ndarray, shape (3, 3)
        Covariance of ``D``.
    last_t_ms : float
        Time of the last gyro sample processed; NaN before any.
    last_gyro : ndarray, shape (3,)
        Rates of that sample, rad/s (the ``u_{k-1}`` of the next prediction); NaN before any.
    last_accel : ndarray, shape (4,)
        Last accelerometer sample seen ``[t_ms, x, y, z]``; NaN before any.
    """

    D: FloatArray = field(metadata=shape(3))
    P: FloatArray = field(metadata=shape(3, 3))
    last_t_ms: float
    last_gyro: FloatArray = field(metadata=shape(3))
    last_accel: FloatArray = field(metadata=shape(4))


def initial_attitude(params: AttitudeParams) -> AttitudeState:
    """``D_0`` and ``P_0`` of eq 10-11 (Algorithm 1 step 1), before any sample."""
    return AttitudeState(
        D=np.array(params.d0, dtype=np.float64),
        P=np.diag(np.array(params.p0, dtype=np.float64)),
        last_t_ms=math.nan,
        last_gyro=np.full(3, np.nan),
        last_accel=np.full(4, np.nan),
    )


def _predict(
    D: list[float], P: Matrix3, omega: list[float], dt: float, Q: Matrix3
) -> tuple[list[float], Matrix3]:
    """Eq 12 and ``P^- = F P F^T + Q_1`` (Algorithm 1 step 2)."""
    psi, theta, gamma = D
    p, qr, r = omega
    sg, cg = math.sin(gamma), math.cos(gamma)
    ct = math.cos(theta)
    ct = math.copysign(max(abs(ct), _MIN_COS_PITCH), ct)
    tt = math.sin(theta) / ct
    u = sg * qr + cg * r  # rate about the phone's levelled z axis times cos(theta)
    v = cg * qr - sg * r
    D_pred = [
        wrap_float(psi + u / ct * dt),
        theta + v * dt,
        wrap_float(gamma + (p + u * tt) * dt),
    ]
    # F = df/dD; no rate depends on psi, so its first column is e_1
    F: Matrix3 = (
        1.0,
        u * tt / ct * dt,
        v / ct * dt,
        0.0,
        1.0,
        -u * dt,
        0.0,
        u / (ct * ct) * dt,
        1.0 + v * tt * dt,
    )
    FPFt = mul(mul(F, P), transpose(F))
    return D_pred, symmetric(add(FPFt, Q))


def _update(
    D: list[float], P: Matrix3, a_g: list[float], R: Matrix3
) -> tuple[list[float], Matrix3]:
    """Eq 15 with ``H = d(T^T e_3)/dD`` and the Joseph-form update (Algorithm 1 step 2)."""
    _, theta, gamma = D
    st, ct = math.sin(theta), math.cos(theta)
    sg, cg = math.sin(gamma), math.cos(gamma)
    y = (a_g[0] + st, a_g[1] - sg * ct, a_g[2] - cg * ct)
    H: Matrix3 = (0.0, -ct, 0.0, 0.0, -sg * st, cg * ct, 0.0, -cg * st, -sg * ct)
    PHt = mul(P, transpose(H))
    HPHt = mul(H, PHt)
    S: Matrix3 = (
        HPHt[0] + R[0],
        HPHt[1],
        HPHt[2],
        HPHt[3],
        HPHt[4] + R[4],
        HPHt[5],
        HPHt[6],
        HPHt[7],
        HPHt[8] + R[8],
    )  # R is diagonal
    K = mul(PHt, inverse(symmetric(S)))  # S is positive definite: R_1 > 0
    D_post = [
        wrap_float(D[0] + K[0] * y[0] + K[1] * y[1] + K[2] * y[2]),
        D[1] + K[3] * y[0] + K[4] * y[1] + K[5] * y[2],
        wrap_float(D[2] + K[6] * y[0] + K[7] * y[1] + K[8] * y[2]),
    ]
    KH = mul(K, H)
    I_KH: Matrix3 = (
        1.0 - KH[0],
        -KH[1],
        -KH[2],
        -KH[3],
        1.0 - KH[4],
        -KH[5],
        -KH[6],
        -KH[7],
        1.0 - KH[8],
    )
    KRKt = mul(mul(K, R), transpose(K))
    joseph = mul(mul(I_KH, P), transpose(I_KH))
    return D_post, symmetric(add(joseph, KRKt))


def attitude_ekf(
    state: AttitudeState, gyro: FloatArray, accel: FloatArray, params: AttitudeParams
) -> tuple[AttitudeState, FloatArray]:
    """Run the attitude-determination EKF (Algorithm 1 steps 2-3) over a batch.

    At each gyro sample ``k`` the filter predicts with eq 12 over
    ``dt = t_k - t_{k-1}`` with the rates of sample ``k - 1`` (``dt = 0`` for the first
    sample after ``initial_attitude``; ``Q_1`` is added at every sample), then, when an
    accelerometer sample arrived since the previous gyro sample, updates with the latest
    one divided by ``G`` (eq 15).

    Parameters
    ----------
    state : AttitudeState
        ``initial_attitude(params)`` or the state after the previous batch.
    gyro : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` rad/s, times increasing and after ``state.last_t_ms``.
    accel : ndarray, shape (m, 4)
        ``[t_ms, x, y, z]`` m/s²; may be empty.
    params : AttitudeParams

    Returns
    -------
    state : AttitudeState
    euler : ndarray, shape (n, 4)
        ``[t_ms, psi, theta, gamma]`` after each gyro sample, rad; psi is Cui's yaw
        (counter-clockwise about up), see ``sensor_geometry.heading_from_yaw``.
    """
    g = samples(gyro)
    a = with_carried(state.last_accel, samples(accel))
    t = g[:, 0]
    held_a = held_index(a[:, 0], t)
    is_fresh = fresh(a[:, 0], held_a, t, state.last_t_ms).tolist()
    held = held_a.tolist()
    a_g = (a[:, 1:] / G).tolist()

    D = [float(v) for v in state.D]
    P = matrix3(state.P.ravel().tolist())
    omega = [float(v) for v in state.last_gyro]
    t_prev = state.last_t_ms
    Q, R = diagonal(params.q), diagonal(params.r)
    out = np.empty((len(g), 4))
    for k, (t_k, wx, wy, wz) in enumerate(g.tolist()):
        dt = (t_k - t_prev) / 1000.0 if math.isfinite(t_prev) else 0.0
        if not 0.0 <= dt <= MAX_GAP_S:
            dt = 0.0  # a gap: nothing known about the turn across it
        try:
            D, P = _predict(D, P, omega if dt > 0.0 else [0.0, 0.0, 0.0], dt, Q)
            if is_fresh[k] and math.hypot(*a_g[held[k]]) >= MIN_GRAVITY_G:
                D, P = _update(D, P, a_g[held[k]], R)
        except (ZeroDivisionError, OverflowError):
            D = [math.nan]
        if not (all(map(math.isfinite, D)) and all(abs(v) < MAX_ATTITUDE_VAR for v in P)):
            # diverged on implausible samples: start again from the initial attitude
            D = [float(v) for v in params.d0]
            P = diagonal(params.p0)
        out[k] = (t_k, D[0], D[1], D[2])
        omega = [wx, wy, wz]
        t_prev = t_k

    new = AttitudeState(
        D=np.array(D, dtype=np.float64),
        P=np.array(P, dtype=np.float64).reshape(3, 3),
        last_t_ms=t_prev,
        last_gyro=np.array(omega, dtype=np.float64),
        last_accel=a[-1].copy() if len(a) else state.last_accel.copy(),
    )
    return new, out
