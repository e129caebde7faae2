"""Phone attitude and heading from gyroscope, accelerometer and magnetometer samples.

Frames and units. Phone axes are Android's (x to the right edge, y to the top edge, z out
of the screen); the world frame is east-north-up. The accelerometer gives specific force
in m/s² with gravity included (a phone lying flat screen up reads about ``[0, 0, +g]``),
the gyroscope rad/s right-handed about each phone axis, the magnetometer µT. A *heading*
is in radians, clockwise from north, wrapped to (-pi, pi]; unless said otherwise it is the
heading of the phone's top edge (y axis) projected on the horizontal plane. Samples are
``(n, 4)`` arrays ``[t_ms, x, y, z]`` with strictly increasing ``t_ms``.

Attitude-determination EKF (``papers/002_*`` section 6.1, eq 9-17, Algorithm 1 steps 1-3).
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
integrated gyroscope from ``D_0``; Cui's psi is counter-clockwise, and ``heading_from_yaw``
converts it to our heading.

Heading fusion (``papers/003_*`` section III: "weighted fusion" of the gyro relative
heading, reliable in the short term, and the absolute compass heading, trusted during
quasi-static magnetic field (QSMF) periods). We realise it as a Kalman filter on
``x = [h, b]``, heading h (clockwise from magnetic north) and gyro bias b about the
vertical (rad/s, counter-clockwise positive like the measured vertical rate ``w``)::

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

Alignment. The accelerometer and magnetometer are held (zero-order hold: the latest sample
at or before the gyro sample time) rather than interpolated, because interpolation needs
the next sample and so could not give the same output for one batch and for two. A
measurement updates a filter once, at the first gyro sample at or after it. The last
sample of each stream is carried in the state, so that splitting all streams at a common
time gives the same output as one batch.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from server.positioning.kalman import wrap_angle

FloatArray = NDArray[np.float64]

G = 9.80665  # standard gravity, m/s²
MAX_GAP_S = 1.0  # a longer gap between gyro samples is not integrated across
MIN_GRAVITY_G = 0.1  # an accelerometer sample weaker than this has no direction to use
MAX_ATTITUDE_VAR = 1e6  # beyond this the attitude filter has diverged and starts again

_MIN_COS_PITCH = 1e-3  # |cos(theta)| floor in eq 12: the Z-Y-X kinematics are singular at ±90°
_Matrix3 = tuple[float, float, float, float, float, float, float, float, float]


def _wrap(angle: float) -> float:
    """``wrap_angle`` for one float (the same formula, without numpy's per-call cost);
    a non-finite angle comes back as it is."""
    if not math.isfinite(angle):
        return angle
    return angle - 2.0 * math.pi * math.ceil((angle - math.pi) / (2.0 * math.pi))


def _samples(x: FloatArray, width: int = 4) -> FloatArray:
    return np.asarray(x, dtype=np.float64).reshape(-1, width)


def _vectors(x: FloatArray) -> FloatArray:
    """The last three columns: ``(n, 3)`` vectors from ``(n, 4)`` samples or ``(n, 3)``."""
    a = np.asarray(x, dtype=np.float64)
    return a.reshape(-1, a.shape[-1] if a.ndim > 1 else 3)[:, -3:]


def _unit(v: FloatArray) -> FloatArray:
    """Rows scaled to unit length; a zero row gives NaN (no direction) without a warning."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(v / np.linalg.norm(v, axis=-1, keepdims=True), dtype=np.float64)


def _held_index(sample_t_ms: FloatArray, t_ms: FloatArray) -> NDArray[np.intp]:
    """Index of the latest sample at or before each time, -1 when there is none."""
    return np.searchsorted(sample_t_ms, t_ms, side="right") - 1


def _fresh(
    sample_t_ms: FloatArray, index: NDArray[np.intp], t_ms: FloatArray, last_t_ms: float
) -> NDArray[np.bool_]:
    """Whether the held sample is new at each time: later than the previous time."""
    start = last_t_ms if math.isfinite(last_t_ms) else -np.inf
    previous = np.concatenate([[start], t_ms])[:-1]
    held_t = sample_t_ms[np.maximum(index, 0)] if len(sample_t_ms) else np.zeros(len(t_ms))
    return np.asarray((index >= 0) & (held_t > previous), dtype=np.bool_)


def _with_carried(carried: FloatArray, samples: FloatArray) -> FloatArray:
    """Prepend the carried last sample of the previous batch when there is one."""
    return np.vstack([carried[None, :], samples]) if math.isfinite(carried[0]) else samples


def _lowpass(
    accel: FloatArray, tau_s: float, y0: FloatArray, t0_ms: float
) -> tuple[FloatArray, FloatArray]:
    """First-order low-pass ``y += (1 - exp(-dt / tau)) (x - y)`` at the sample times.

    Returns the filtered vectors ``(n, 3)`` and the last one ``(3,)`` (``y0`` when ``n`` is 0).
    A NaN ``t0_ms`` starts the filter at the first sample.
    """
    out = np.empty((len(accel), 3))
    y = [float(v) for v in y0]
    t_prev = t0_ms
    for i, (t, ax, ay, az) in enumerate(accel.tolist()):
        if math.isfinite(t_prev):
            a = 1.0 - math.exp(-(t - t_prev) / (1000.0 * tau_s))
            y = [y[0] + a * (ax - y[0]), y[1] + a * (ay - y[1]), y[2] + a * (az - y[2])]
        else:
            y = [ax, ay, az]
        out[i] = y
        t_prev = t
    return out, np.array(y, dtype=np.float64)


def gravity_direction(accel: FloatArray, tau_s: float = 0.5) -> FloatArray:
    """Unit up vectors in phone axes from a first-order low-pass of the accelerometer.

    Not incremental: the filter starts at the first sample. The smoothing factor of each
    sample is ``1 - exp(-dt / tau_s)``, so irregular sample times are handled.

    Parameters
    ----------
    accel : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` specific force, m/s².
    tau_s : float
        Time constant of the low-pass, s.

    Returns
    -------
    ndarray, shape (n, 3)
        Unit vectors pointing up (against gravity) in phone axes.
    """
    a = _samples(accel)
    filtered, _ = _lowpass(a, tau_s, np.full(3, np.nan), math.nan)
    return _unit(filtered)


def vertical_rate(gyro: FloatArray, up: FloatArray) -> FloatArray:
    """Angular rate about the world vertical, counter-clockwise positive: ``omega . up``.

    Parameters
    ----------
    gyro : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` angular rate, rad/s (or ``(n, 3)`` rates).
    up : ndarray, shape (n, 3)
        Unit up vectors in phone axes at the gyro sample times.

    Returns
    -------
    ndarray, shape (n,)
        rad/s; a positive rate decreases the heading.
    """
    return np.asarray(np.einsum("ij,ij->i", _vectors(gyro), _vectors(up)), dtype=np.float64)


def compass_heading(magnetic: FloatArray, up: FloatArray) -> FloatArray:
    """Tilt-compensated magnetic heading of the phone's top edge.

    In any frame ``east = (B x up) / |B x up|`` (for ``B`` pointing north and down,
    ``B x up`` points east) and ``north = up x east``. The phone's y axis has components
    ``east[1]`` and ``north[1]`` along them, so ``heading = atan2(east[1], north[1])``. It
    is undefined when the top edge points straight up or down, and NaN when B is parallel
    to up.

    Parameters
    ----------
    magnetic : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` magnetic field, µT (or ``(n, 3)`` vectors).
    up : ndarray, shape (n, 3)
        Unit up vectors in phone axes at the same times.

    Returns
    -------
    ndarray, shape (n,)
        Heading clockwise from magnetic north, rad, in (-pi, pi].
    """
    b = _vectors(magnetic)
    u = _vectors(up)
    east = _unit(np.cross(b, u))
    north = np.cross(u, east)
    return wrap_angle(np.arctan2(east[:, 1], north[:, 1]))


def rotation_heading(rotation: FloatArray) -> FloatArray:
    """Heading of the phone's top edge from Android rotation-vector samples.

    The unit quaternion ``(x, y, z, w)`` rotates phone axes to east-north-up, so the phone's
    y axis in the world is the second column of its rotation matrix,
    ``[2 (x y - w z), 1 - 2 (x^2 + z^2), 2 (y z + w x)]``, and the heading is the
    ``atan2`` of its east and north components.

    Parameters
    ----------
    rotation : ndarray, shape (n, 5)
        ``[t_ms, x, y, z, w]``; a NaN ``w`` is ``sqrt(max(0, 1 - x^2 - y^2 - z^2))``. The
        quaternion is normalised.

    Returns
    -------
    ndarray, shape (n, 2)
        ``[t_ms, heading_rad]``, heading clockwise from north in (-pi, pi].
    """
    r = _samples(rotation, 5)
    x, y, z, w = r[:, 1], r[:, 2], r[:, 3], r[:, 4]
    w = np.where(np.isnan(w), np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y - z * z)), w)
    norm2 = x * x + y * y + z * z + w * w
    east = 2.0 * (x * y - w * z) / norm2
    north = 1.0 - 2.0 * (x * x + z * z) / norm2
    return np.column_stack([r[:, 0], wrap_angle(np.arctan2(east, north))])


def heading_from_yaw(psi: FloatArray) -> FloatArray:
    """Our heading from the yaw of ``attitude_ekf``: ``wrap(-psi)``.

    With ``T = Rz(psi)`` (the phone levelled by removing pitch and roll) the top edge
    points along ``[-sin(psi), cos(psi), 0]`` in east-north-up, whose heading is ``-psi``.
    It equals the heading of the top edge projected on the horizontal plane whenever pitch
    is zero or roll is zero (with ``|roll| < 90°``), and differs from it by second-order
    terms when both are small.

    Parameters
    ----------
    psi : array_like
        Yaw, rad, counter-clockwise about up from the eq 16 frame; any shape.

    Returns
    -------
    ndarray
        Same shape, clockwise from north, in (-pi, pi].
    """
    return wrap_angle(-np.asarray(psi, dtype=np.float64))


# --- attitude-determination EKF (papers/002_* section 6.1) ---------------------------------


@dataclass(frozen=True)
class AttitudeParams:
    """Parameters of the attitude-determination EKF, Cui's values by default."""

    d0: tuple[float, float, float] = (0.5 * math.pi, 0.0, 0.0)  # [psi, theta, gamma], eq 10
    p0: tuple[float, float, float] = (1.0, 1.0, 1.0)  # diag of P_0, rad², eq 11
    q: tuple[float, float, float] = (1.0, 1.0, 1.0)  # diag of Q_1 per gyro sample, rad², eq 13
    r: tuple[float, float, float] = (1.0, 1.0, 1.0)  # diag of R_1 per accel sample, g², eq 17

    def __post_init__(self) -> None:
        if len(self.d0) != 3 or not all(math.isfinite(v) for v in self.d0):
            raise ValueError(f"d0 must be three finite angles, got {self.d0}")
        for name in ("p0", "q", "r"):
            values = getattr(self, name)
            if len(values) != 3 or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"{name} must be three positive finite variances, got {values}")


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

    D: FloatArray
    P: FloatArray
    last_t_ms: float
    last_gyro: FloatArray
    last_accel: FloatArray

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat float64 arrays (scalars as 0-d arrays); ``from_arrays`` inverts exactly."""
        return {
            "D": np.array(self.D, dtype=np.float64),
            "P": np.array(self.P, dtype=np.float64),
            "last_t_ms": np.array(self.last_t_ms, dtype=np.float64),
            "last_gyro": np.array(self.last_gyro, dtype=np.float64),
            "last_accel": np.array(self.last_accel, dtype=np.float64),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> AttitudeState:
        """Rebuild a state from ``to_arrays`` output.

        Raises
        ------
        KeyError
            When an array is missing.
        ValueError
            When an array has the wrong shape.
        """
        state = cls(
            D=np.array(arrays["D"], dtype=np.float64),
            P=np.array(arrays["P"], dtype=np.float64),
            last_t_ms=float(arrays["last_t_ms"]),
            last_gyro=np.array(arrays["last_gyro"], dtype=np.float64),
            last_accel=np.array(arrays["last_accel"], dtype=np.float64),
        )
        shapes = (state.D.shape, state.P.shape, state.last_gyro.shape, state.last_accel.shape)
        if shapes != ((3,), (3, 3), (3,), (4,)):
            raise ValueError(f"attitude state has shapes {shapes}")
        return state


def initial_attitude(params: AttitudeParams) -> AttitudeState:
    """``D_0`` and ``P_0`` of eq 10-11 (Algorithm 1 step 1), before any sample."""
    return AttitudeState(
        D=np.array(params.d0, dtype=np.float64),
        P=np.diag(np.array(params.p0, dtype=np.float64)),
        last_t_ms=math.nan,
        last_gyro=np.full(3, np.nan),
        last_accel=np.full(4, np.nan),
    )


def _mul(A: _Matrix3, B: _Matrix3) -> _Matrix3:
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = A
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = B
    return (
        a0 * b0 + a1 * b3 + a2 * b6,
        a0 * b1 + a1 * b4 + a2 * b7,
        a0 * b2 + a1 * b5 + a2 * b8,
        a3 * b0 + a4 * b3 + a5 * b6,
        a3 * b1 + a4 * b4 + a5 * b7,
        a3 * b2 + a4 * b5 + a5 * b8,
        a6 * b0 + a7 * b3 + a8 * b6,
        a6 * b1 + a7 * b4 + a8 * b7,
        a6 * b2 + a7 * b5 + a8 * b8,
    )


def _matrix3(values: list[float]) -> _Matrix3:
    v = values
    return (v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])


def _add(A: _Matrix3, B: _Matrix3) -> _Matrix3:
    return _matrix3([a + b for a, b in zip(A, B, strict=True)])


def _transpose(A: _Matrix3) -> _Matrix3:
    return (A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8])


def _symmetric(A: _Matrix3) -> _Matrix3:
    a1, a2, a5 = 0.5 * (A[1] + A[3]), 0.5 * (A[2] + A[6]), 0.5 * (A[5] + A[7])
    return (A[0], a1, a2, a1, A[4], a5, a2, a5, A[8])


def _inverse(A: _Matrix3) -> _Matrix3:
    """Inverse by cofactors (``S`` is symmetric positive definite, ``R_1`` > 0)."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = A
    c0, c3, c6 = a4 * a8 - a5 * a7, a5 * a6 - a3 * a8, a3 * a7 - a4 * a6
    det = a0 * c0 + a1 * c3 + a2 * c6
    return (
        c0 / det,
        (a2 * a7 - a1 * a8) / det,
        (a1 * a5 - a2 * a4) / det,
        c3 / det,
        (a0 * a8 - a2 * a6) / det,
        (a2 * a3 - a0 * a5) / det,
        c6 / det,
        (a1 * a6 - a0 * a7) / det,
        (a0 * a4 - a1 * a3) / det,
    )


def _attitude_predict(
    D: list[float], P: _Matrix3, omega: list[float], dt: float, q: tuple[float, float, float]
) -> tuple[list[float], _Matrix3]:
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
        _wrap(psi + u / ct * dt),
        theta + v * dt,
        _wrap(gamma + (p + u * tt) * dt),
    ]
    # F = df/dD; no rate depends on psi, so its first column is e_1
    F: _Matrix3 = (
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
    FPFt = _mul(_mul(F, P), _transpose(F))
    Q: _Matrix3 = (q[0], 0.0, 0.0, 0.0, q[1], 0.0, 0.0, 0.0, q[2])
    return D_pred, _symmetric(_add(FPFt, Q))


def _attitude_update(
    D: list[float], P: _Matrix3, a_g: list[float], r: tuple[float, float, float]
) -> tuple[list[float], _Matrix3]:
    """Eq 15 with ``H = d(T^T e_3)/dD`` and the Joseph-form update (Algorithm 1 step 2)."""
    _, theta, gamma = D
    st, ct = math.sin(theta), math.cos(theta)
    sg, cg = math.sin(gamma), math.cos(gamma)
    y = (a_g[0] + st, a_g[1] - sg * ct, a_g[2] - cg * ct)
    H: _Matrix3 = (0.0, -ct, 0.0, 0.0, -sg * st, cg * ct, 0.0, -cg * st, -sg * ct)
    PHt = _mul(P, _transpose(H))
    HPHt = _mul(H, PHt)
    S: _Matrix3 = (
        HPHt[0] + r[0],
        HPHt[1],
        HPHt[2],
        HPHt[3],
        HPHt[4] + r[1],
        HPHt[5],
        HPHt[6],
        HPHt[7],
        HPHt[8] + r[2],
    )
    K = _mul(PHt, _inverse(_symmetric(S)))
    D_post = [
        _wrap(D[0] + K[0] * y[0] + K[1] * y[1] + K[2] * y[2]),
        D[1] + K[3] * y[0] + K[4] * y[1] + K[5] * y[2],
        _wrap(D[2] + K[6] * y[0] + K[7] * y[1] + K[8] * y[2]),
    ]
    KH = _mul(K, H)
    I_KH: _Matrix3 = (
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
    KRKt = _mul(_mul(K, (r[0], 0.0, 0.0, 0.0, r[1], 0.0, 0.0, 0.0, r[2])), _transpose(K))
    joseph = _mul(_mul(I_KH, P), _transpose(I_KH))
    return D_post, _symmetric(_add(joseph, KRKt))


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
        (counter-clockwise about up), see ``heading_from_yaw``.
    """
    g = _samples(gyro)
    a = _with_carried(state.last_accel, _samples(accel))
    t = g[:, 0]
    held_a = _held_index(a[:, 0], t)
    fresh = _fresh(a[:, 0], held_a, t, state.last_t_ms).tolist()
    held = held_a.tolist()
    a_g = (a[:, 1:] / G).tolist()

    D = [float(v) for v in state.D]
    P = _matrix3(state.P.ravel().tolist())
    omega = [float(v) for v in state.last_gyro]
    t_prev = state.last_t_ms
    out = np.empty((len(g), 4))
    for k, (t_k, wx, wy, wz) in enumerate(g.tolist()):
        dt = (t_k - t_prev) / 1000.0 if math.isfinite(t_prev) else 0.0
        if not 0.0 <= dt <= MAX_GAP_S:
            dt = 0.0  # a gap: nothing known about the turn across it
        try:
            D, P = _attitude_predict(D, P, omega if dt > 0.0 else [0.0, 0.0, 0.0], dt, params.q)
            if fresh[k] and math.hypot(*a_g[held[k]]) >= MIN_GRAVITY_G:
                D, P = _attitude_update(D, P, a_g[held[k]], params.r)
        except (ZeroDivisionError, OverflowError):
            D = [math.nan]
        if not (all(map(math.isfinite, D)) and all(abs(v) < MAX_ATTITUDE_VAR for v in P)):
            # diverged on implausible samples: start again from the initial attitude
            D = [float(v) for v in params.d0]
            P = _matrix3(np.diag(params.p0).ravel().tolist())
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


# --- heading fusion (papers/003_* section III) ----------------------------------------------


@dataclass(frozen=True)
class HeadingParams:
    """Parameters of the gyro/compass heading filter.

    The defaults assume a phone gyro with a bias of up to about 1 deg/s and a magnetometer
    at about 50 Hz with 0.3-0.6 µT of noise.
    """

    window_s: float = 1.0  # QSMF sliding window, s
    # std of |B| over the window below which the field is quasi-static, µT: about twice the
    # noise of phone magnetometers (0.3-0.6 µT rms), while indoor disturbances change |B|
    # by several µT over a metre, i.e. within a second of walking
    qsmf_magnitude_std_ut: float = 1.0
    # compass and gyro heading changes over the window agree within this, rad: a compass
    # sample is good to about 1 deg, and a gyro bias of 1 deg/s adds 1 deg a window
    qsmf_agreement_rad: float = math.radians(5.0)
    # heading random walk, rad²/s: gyro white noise plus the error of projecting the rates
    # on a low-passed vertical while the phone sways; (0.2 deg)² per s
    q_heading: float = math.radians(0.2) ** 2
    q_bias: float = 1e-8  # gyro bias random walk, rad²/s³ (its std grows 0.04 deg/s a minute)
    # compass heading variance per magnetometer sample, rad²: larger than the noise of one
    # sample because tilt errors and small disturbances are correlated over many samples;
    # with q_heading it sets a ~3 s time constant for the compass pull at 50 Hz
    r_compass_rad2: float = math.radians(5.0) ** 2
    p0_heading_rad2: float = math.radians(20.0) ** 2  # at the first compass heading
    p0_bias_rad2_s2: float = math.radians(1.0) ** 2  # initial gyro bias variance, (rad/s)²
    # low-pass time constant for the up vector, s. Walking accelerations leak into the
    # low-passed up vector at the step frequency, and their product with the phone's sway
    # rates integrates to a heading drift roughly proportional to 1 / tau (on the
    # synthetic walk of the tests 7.5 deg/min at 0.5 s, 3.9 at 1 s, 2.0 at 2 s) which the
    # bias state must absorb; a longer tau lags behind changes of how the phone is held
    gravity_tau_s: float = 1.0
    window_entries: int = 50  # samples kept per window (ring buffer spacing window_s / this)

    def __post_init__(self) -> None:
        if self.window_entries < 2:
            raise ValueError(f"window_entries must be at least 2, got {self.window_entries}")
        positive = {
            "window_s": self.window_s,
            "qsmf_magnitude_std_ut": self.qsmf_magnitude_std_ut,
            "qsmf_agreement_rad": self.qsmf_agreement_rad,
            "q_heading": self.q_heading,
            "q_bias": self.q_bias,
            "r_compass_rad2": self.r_compass_rad2,
            "p0_heading_rad2": self.p0_heading_rad2,
            "p0_bias_rad2_s2": self.p0_bias_rad2_s2,
            "gravity_tau_s": self.gravity_tau_s,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")


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
    P: FloatArray
    last_t_ms: float
    last_rate: float
    gravity: FloatArray
    gravity_t_ms: float
    last_magnetic: FloatArray
    gyro_heading: float
    window: FloatArray
    qsmf: bool
    initialized: bool

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat numeric arrays (scalars as 0-d arrays); ``from_arrays`` inverts exactly."""
        return {
            "heading": np.array(self.heading, dtype=np.float64),
            "bias": np.array(self.bias, dtype=np.float64),
            "P": np.array(self.P, dtype=np.float64),
            "last_t_ms": np.array(self.last_t_ms, dtype=np.float64),
            "last_rate": np.array(self.last_rate, dtype=np.float64),
            "gravity": np.array(self.gravity, dtype=np.float64),
            "gravity_t_ms": np.array(self.gravity_t_ms, dtype=np.float64),
            "last_magnetic": np.array(self.last_magnetic, dtype=np.float64),
            "gyro_heading": np.array(self.gyro_heading, dtype=np.float64),
            "window": np.array(self.window, dtype=np.float64).reshape(-1, 4),
            "qsmf": np.array(self.qsmf, dtype=np.int8),
            "initialized": np.array(self.initialized, dtype=np.int8),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> HeadingState:
        """Rebuild a state from ``to_arrays`` output.

        Raises
        ------
        KeyError
            When an array is missing.
        ValueError
            When an array has the wrong shape.
        """
        state = cls(
            heading=float(arrays["heading"]),
            bias=float(arrays["bias"]),
            P=np.array(arrays["P"], dtype=np.float64),
            last_t_ms=float(arrays["last_t_ms"]),
            last_rate=float(arrays["last_rate"]),
            gravity=np.array(arrays["gravity"], dtype=np.float64),
            gravity_t_ms=float(arrays["gravity_t_ms"]),
            last_magnetic=np.array(arrays["last_magnetic"], dtype=np.float64),
            gyro_heading=float(arrays["gyro_heading"]),
            window=np.array(arrays["window"], dtype=np.float64).reshape(-1, 4),
            qsmf=bool(arrays["qsmf"]),
            initialized=bool(arrays["initialized"]),
        )
        shapes = (state.P.shape, state.gravity.shape, state.last_magnetic.shape)
        if shapes != ((2, 2), (3,), (4,)):
            raise ValueError(f"heading state has shapes {shapes}")
        return state


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
    filtered, gravity = _lowpass(accel, tau_s, state.gravity, state.gravity_t_ms)
    times = accel[:, 0]
    if math.isfinite(state.gravity_t_ms):
        filtered = np.vstack([state.gravity[None, :], filtered])
        times = np.concatenate([[state.gravity_t_ms], times])
    up = np.tile([0.0, 0.0, 1.0], (len(t_ms), 1))
    held = _held_index(times, t_ms)
    known = held >= 0
    up[known] = _unit(filtered[held[known]])
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
        d_compass = _wrap(compass - compass_0)
        d_gyro = _wrap(gyro_heading - gyro_0)
        agreement = abs(_wrap(d_compass - d_gyro))
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
    g = _samples(gyro)
    a = _samples(accel)
    m = _with_carried(state.last_magnetic, _samples(magnetic))
    t = g[:, 0]
    up, gravity, gravity_t_ms = _up_at(state, a, t, params.gravity_tau_s)
    rates = vertical_rate(g, up).tolist()
    held = _held_index(m[:, 0], t)
    fresh = _fresh(m[:, 0], held, t, state.last_t_ms)
    compass_arr = np.full(len(t), np.nan)
    magnitude_arr = np.full(len(t), np.nan)
    field_t_arr = np.full(len(t), np.nan)
    if len(m):
        field = m[held[fresh], 1:]
        compass_arr[fresh] = compass_heading(field, up[fresh])
        magnitude_arr[fresh] = np.linalg.norm(field, axis=1)
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
            h = _wrap(h - turn)
            gh = _wrap(gh - turn)
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
                y = _wrap(c - h)
                h = _wrap(h + k_h * y)
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
