"""Generic (extended) Kalman filter steps as pure functions.

Prediction, linear model ``x_k = F x_{k-1} + w``, ``w ~ N(0, Q)``::

    x^- = F x,    P^- = F P F^T + Q

For an extended Kalman filter the caller propagates the mean through its own nonlinear
model ``f`` and passes the Jacobian ``F = df/dx`` at the previous estimate
(``predict_ekf``); the covariance step is the same. This is the form of the
position-tracking EKF of ``papers/002_*`` (Algorithm 1, eq 18-25) and of
``papers/003_*`` eq 15-16.

Update with a measurement ``z = H x + v``, ``v ~ N(0, R)``::

    y = z - H x^-                      (innovation; a caller-supplied residual may wrap angles)
    S = H P^- H^T + R
    K = P^- H^T S^-1                   (via a Cholesky factor of S, never an inverse)
    x^+ = x^- + K y
    P^+ = (I - K H) P^- (I - K H)^T + K R K^T      (Joseph form)
    d^2 = y^T S^-1 y                   (squared Mahalanobis distance, for gating)

The Joseph form keeps ``P`` symmetric positive semi-definite under rounding where the
short form ``(I - K H) P`` does not; the result is also symmetrised explicitly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import cho_factor, cho_solve

FloatArray = NDArray[np.float64]
Residual = Callable[[FloatArray, FloatArray], FloatArray]


@dataclass(frozen=True)
class Update:
    """Result of a measurement update.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Posterior mean.
    P : ndarray, shape (n, n)
        Posterior covariance (Joseph form, symmetric).
    y : ndarray, shape (m,)
        Innovation ``z - H x`` (or the caller's residual of it).
    S : ndarray, shape (m, m)
        Innovation covariance ``H P H^T + R``.
    mahalanobis2 : float
        ``y^T S^-1 y``; chi-square with ``m`` degrees of freedom when the model holds.
    """

    x: FloatArray
    P: FloatArray
    y: FloatArray
    S: FloatArray
    mahalanobis2: float


def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Wrap angles in radians to the interval (-pi, pi].

    Parameters
    ----------
    angle : array_like
        Any shape.

    Returns
    -------
    ndarray
        Same shape, float64.
    """
    a = np.asarray(angle, dtype=np.float64)
    return a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))


def wrap_angle_float(angle: float) -> float:
    """``wrap_angle`` of one finite angle in Python floats: the same operations without
    numpy's few µs per call on a scalar; a non-finite angle goes through ``wrap_angle``."""
    if not math.isfinite(angle):
        return float(wrap_angle(angle))
    turns = (angle - math.pi) / (2.0 * math.pi)
    # np.ceil as a float: math.ceil's integer converts back exactly, the sign puts back
    # the -0.0 of a ceiling in (-1, 0]
    return angle - 2.0 * math.pi * math.copysign(math.ceil(turns), turns)


def _symmetric(P: FloatArray) -> FloatArray:
    return 0.5 * (P + P.T)


def predict_ekf(
    x_pred: ArrayLike, P: ArrayLike, F: ArrayLike, Q: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """EKF prediction: the caller's propagated mean and ``F P F^T + Q``.

    Parameters
    ----------
    x_pred : array_like, shape (n,)
        ``f(x)``, the previous mean pushed through the (nonlinear) model.
    P : array_like, shape (n, n)
        Previous covariance.
    F : array_like, shape (n, n)
        Jacobian of ``f`` at the previous mean.
    Q : array_like, shape (n, n)
        Process noise covariance.

    Returns
    -------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    """
    F_ = np.asarray(F, dtype=np.float64)
    P_ = np.asarray(P, dtype=np.float64)
    P_pred = F_ @ P_ @ F_.T + np.asarray(Q, dtype=np.float64)
    return np.array(x_pred, dtype=np.float64), _symmetric(P_pred)


def predict(
    x: ArrayLike, P: ArrayLike, F: ArrayLike, Q: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Linear Kalman prediction ``(F x, F P F^T + Q)``.

    Parameters
    ----------
    x : array_like, shape (n,)
    P : array_like, shape (n, n)
    F : array_like, shape (n, n)
        State transition matrix.
    Q : array_like, shape (n, n)
        Process noise covariance.

    Returns
    -------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    """
    F_ = np.asarray(F, dtype=np.float64)
    return predict_ekf(F_ @ np.asarray(x, dtype=np.float64), P, F_, Q)


def update(
    x: ArrayLike,
    P: ArrayLike,
    z: ArrayLike,
    H: ArrayLike,
    R: ArrayLike,
    residual: Residual | None = None,
) -> Update:
    """Kalman measurement update in Joseph form.

    Parameters
    ----------
    x : array_like, shape (n,)
        Prior mean.
    P : array_like, shape (n, n)
        Prior covariance.
    z : array_like, shape (m,)
        Measurement.
    H : array_like, shape (m, n)
        Measurement matrix (the Jacobian of the measurement model for an EKF).
    R : array_like, shape (m, m)
        Measurement noise covariance.
    residual : callable, optional
        ``residual(z, z_pred) -> y`` of shape (m,); ``z - z_pred`` when None. Use it to
        wrap angle components (see ``wrap_angle``).

    Returns
    -------
    Update
        Posterior, innovation, its covariance and the squared Mahalanobis distance.

    Raises
    ------
    numpy.linalg.LinAlgError
        When ``S`` is not positive definite.
    """
    x_ = np.asarray(x, dtype=np.float64)
    P_ = np.asarray(P, dtype=np.float64)
    z_ = np.atleast_1d(np.asarray(z, dtype=np.float64))
    H_ = np.atleast_2d(np.asarray(H, dtype=np.float64))
    R_ = np.atleast_2d(np.asarray(R, dtype=np.float64))
    z_pred = H_ @ x_
    y = np.asarray(residual(z_, z_pred) if residual else z_ - z_pred, dtype=np.float64)
    PHt = P_ @ H_.T
    S = _symmetric(H_ @ PHt + R_)
    factor = cho_factor(S, lower=True)
    K = cho_solve(factor, PHt.T).T  # K^T = S^-1 H P, S and P symmetric
    I_KH = np.eye(x_.shape[0]) - K @ H_
    P_post = I_KH @ P_ @ I_KH.T + K @ R_ @ K.T
    return Update(
        x=x_ + K @ y,
        P=_symmetric(P_post),
        y=y,
        S=S,
        mahalanobis2=float(y @ cho_solve(factor, y)),
    )
