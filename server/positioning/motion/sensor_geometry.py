"""Sensor geometry in phone axes: the up direction, the rate about it, and headings.

Frames and units are those of the package docstring.

* ``gravity_direction``: unit up vectors from a low-pass of the accelerometer.
* ``vertical_rate``: the rate about the world vertical, ``w = omega . up``
  (counter-clockwise positive), the gyro heading change of ``papers/003_*`` section III.
* ``compass_heading``: the tilt-compensated magnetic heading of the top edge: in any frame
  ``east = (B x up) / |B x up|`` and ``north = up x east``, and the top edge (phone y) has
  components ``east[1]`` and ``north[1]`` along them.
* ``rotation_heading``: the heading from Android's rotation vector (a unit quaternion
  rotating phone axes to east-north-up).
* ``heading_from_yaw``: our heading from the counter-clockwise yaw psi of the Z-Y-X Euler
  angles of ``papers/002_*`` eq 16 (``attitude_ekf``): ``wrap(-psi)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters.kalman import wrap_angle
from server.positioning.motion.sensor_streams import lowpass, samples, vectors

FloatArray = NDArray[np.float64]

G = 9.80665  # standard gravity, m/s²


def wrap_float(angle: float) -> float:
    """``wrap_angle`` for one float (the same formula, without numpy's per-call cost);
    a non-finite angle comes back as it is."""
    if not math.isfinite(angle):
        return angle
    return angle - 2.0 * math.pi * math.ceil((angle - math.pi) / (2.0 * math.pi))


def unit(v: FloatArray) -> FloatArray:
    """Rows scaled to unit length; a zero row gives NaN (no direction) without a warning."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(v / np.linalg.norm(v, axis=-1, keepdims=True), dtype=np.float64)


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
    filtered, _ = lowpass(samples(accel), tau_s, np.full(3, np.nan), math.nan)
    return unit(filtered)


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
    return np.asarray(np.einsum("ij,ij->i", vectors(gyro), vectors(up)), dtype=np.float64)


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
    b = vectors(magnetic)
    u = vectors(up)
    east = unit(np.cross(b, u))
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
    r = samples(rotation, 5)
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
