"""The attitude EKF written on ``server.positioning.filters.kalman`` (``predict_ekf`` and
``update``: numpy, Cholesky) in place of ``matrix3``: the reference the hand-written 3×3
algebra of ``server.positioning.motion.attitude_ekf`` is tested
(``tests/positioning/motion/test_attitude_ekf.py``) and timed (``bench/attitude_ekf.py``)
against."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters import kalman
from server.positioning.motion.attitude_ekf import (
    MAX_ATTITUDE_VAR,
    MIN_GRAVITY_G,
    AttitudeParams,
    AttitudeState,
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


def generic_attitude_ekf(
    state: AttitudeState, gyro: FloatArray, accel: FloatArray, params: AttitudeParams
) -> tuple[AttitudeState, FloatArray]:
    """``attitude_ekf`` with ``kalman.predict_ekf`` and ``kalman.update`` (numpy, Cholesky)
    in place of ``matrix3``, the scalar parts the same: the reference the hand-written
    algebra is tested and timed against (``bench/attitude_ekf.py``)."""
    g = samples(gyro)
    a = with_carried(state.last_accel, samples(accel))
    t = g[:, 0]
    held = held_index(a[:, 0], t).tolist()
    is_fresh = fresh(a[:, 0], held_index(a[:, 0], t), t, state.last_t_ms).tolist()
    a_g = (a[:, 1:] / G).tolist()
    Q, R = np.diag(params.q), np.diag(params.r)
    D, P = state.D.copy(), state.P.copy()
    omega, t_prev = state.last_gyro.tolist(), state.last_t_ms
    out = np.empty((len(g), 4))
    for k, (t_k, *rates) in enumerate(g.tolist()):
        dt = (t_k - t_prev) / 1000.0 if math.isfinite(t_prev) else 0.0
        dt = dt if 0.0 <= dt <= MAX_GAP_S else 0.0
        p, q, r = omega if dt > 0.0 else (0.0, 0.0, 0.0)
        psi, theta, gamma = D.tolist()
        ct = math.copysign(max(abs(math.cos(theta)), 1e-3), math.cos(theta))
        tt = math.sin(theta) / ct
        u = math.sin(gamma) * q + math.cos(gamma) * r
        v = math.cos(gamma) * q - math.sin(gamma) * r
        F = [
            [1.0, u * tt / ct * dt, v / ct * dt],
            [0.0, 1.0, -u * dt],
            [0.0, u / (ct * ct) * dt, 1.0 + v * tt * dt],
        ]
        x_pred = [
            wrap_float(psi + u / ct * dt),
            theta + v * dt,
            wrap_float(gamma + (p + u * tt) * dt),
        ]
        D, P = kalman.predict_ekf(x_pred, P, F, Q)
        if is_fresh[k] and math.hypot(*a_g[held[k]]) >= MIN_GRAVITY_G:
            _, theta, gamma = D.tolist()
            st_, ct_ = math.sin(theta), math.cos(theta)
            sg, cg = math.sin(gamma), math.cos(gamma)
            h = np.array([-st_, sg * ct_, cg * ct_])
            H = [[0.0, -ct_, 0.0], [0.0, -sg * st_, cg * ct_], [0.0, -cg * st_, -sg * ct_]]

            def residual(z: FloatArray, _: FloatArray, h: FloatArray = h) -> FloatArray:
                return z - h  # eq 15: the measurement model is not linear

            post = kalman.update(D, P, a_g[held[k]], H, R, residual=residual)
            D, P = post.x, post.P
            D[0], D[2] = wrap_float(float(D[0])), wrap_float(float(D[2]))
        assert np.all(np.abs(P) < MAX_ATTITUDE_VAR)  # the walks here never diverge
        out[k] = (t_k, *D.tolist())
        omega, t_prev = rates, t_k
    last_accel = a[-1].copy() if len(a) else state.last_accel.copy()
    return AttitudeState(D, P, t_prev, np.array(omega), last_accel), out
