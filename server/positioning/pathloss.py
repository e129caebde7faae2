"""Emitter position and log-distance path-loss parameters from RSS at known places.

Model (``papers/003_*`` eq 8, ``papers/000_*`` eq 15)
----------------------------------------------------
An emitter (WiFi AP, BLE beacon) at ``p = (x, y)`` is heard at the known place
``u_j = (x_{u,j}, y_{u,j})`` (a reference point of the radio map, or a dead-reckoned
position) with::

    r_j = P0 - 10 gamma log10(d_j) + nu_j,      d_j = |p - u_j|

``P0`` the RSS at 1 m (dBm; ``r_SSO`` in ``papers/003_*``, ``beta_2`` in ``papers/000_*``),
``gamma`` the path-loss exponent (``n`` / ``beta_1``), ``nu_j`` the RSS noise (dB). For
the model ``d_j`` is floored at ``d_min = 1 m``, ``d_j = max(|p - u_j|, 1 m)``: ``P0`` is
defined at 1 m and the log-distance law says nothing nearer; without the floor the
predicted RSS spikes at every observation point, and those spikes trap the solver
(readings several dB too weak, as behind a wall, pulled the emitter onto one).

Estimation (``papers/003_*`` eq 9-10, ``papers/000_*`` eq 16-18)
--------------------------------------------------------------
The state ``theta = [x, y, P0, gamma]`` (this order throughout) minimises
``sum_j ((r_hat_j(theta) - r_j) / nu_j)^2`` by ``scipy.optimize.least_squares`` (trust
region; iterated Gauss-Newton where the papers write one linearised step). The design
matrix, row ``j`` (eq 16, columns reordered to ``theta``)::

    H_j = [ -10 gamma (x - x_{u,j}) / (d_j^2 ln 10),  -10 gamma (y - y_{u,j}) / (d_j^2 ln 10),
            1,  -10 log10 d_j ]          (position columns 0 where d_j is floored)

and the covariance at the solution is eq 18::

    P = (H^T R^-1 H)^-1,     R = diag(nu_j^2)

With ``rss_std_db`` given, ``nu`` is that (absolute) noise. Without it, unit weights are
used and ``P`` is scaled by the residual variance ``s^2 = sum_j rho(f_j^2) / (N - 4)``
(``rho`` the loss; for the plain squared loss the sum of squared residuals). With a
robust loss (``loss="soft_l1"`` etc.; the papers use plain least squares) ``H`` is
scipy's loss-weighted Jacobian, so ``P`` is the Gauss-Newton approximation of the robust
cost.

The start is the weighted centroid of the strongest quarter of the readings (weights in
linear power, ``10^((r_j - r_max)/10)``), then ``P0`` and ``gamma`` by linear least squares
with the emitter there. The cost has local minima (a noiseless model was missed by 3 m
from that start alone), so the solver also starts at the three strongest readings'
places and the run with the lowest cost is kept.

Where the papers differ or slip: ``papers/003_*`` writes ``d_{i,j}`` of eq 9 as the
distance implied by the RSS, ``10^((r_j - P0) / (10 gamma))``, but the derivative of the
model needs the geometric distance at the current estimate (as in ``papers/000_*`` eq 16),
which is used here; its eq 10 prints ``(D^T R^-1 D)^T`` where the inverse is meant. Its
choice of what to fit (IV-E2: more than 50 qualified RPs, RSS above -55 dBm,
``sigma_RSS <= 8 dBm``) belongs to the mapping pipeline, not here.

A fit is refused (``None``) when it is under-determined: fewer than 4 readings, readings
on (nearly) one line, where the emitter is only known up to its mirror image across the
line (the second singular value of the centred positions below ``min_spread_ratio`` of
the first), a singular design matrix, or a solver that does not converge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

FloatArray = NDArray[np.float64]
Loss = Literal["linear", "soft_l1", "huber", "cauchy", "arctan"]

MIN_OBSERVATIONS = 4  # four unknowns: x, y, P0, gamma
MIN_DISTANCE_M = 1.0  # d_min: the model is for d >= 1 m, where P0 is defined
STRONGEST_FRACTION = 0.25  # share of the readings whose centroid starts the solver
EXTRA_STARTS = 3  # further starts, at the strongest readings' places
MAX_CONDITION = 1e10  # a design matrix worse conditioned than this is singular
_LN10 = math.log(10.0)


@dataclass(frozen=True)
class EmitterFit:
    """An emitter's estimated position and path-loss parameters.

    Attributes
    ----------
    xy : ndarray, shape (2,)
        Position ``(x, y)`` (m).
    p0_dbm : float
        ``P0``, RSS at 1 m (dBm).
    exponent : float
        ``gamma``, the path-loss exponent.
    cov : ndarray, shape (4, 4)
        Covariance of ``[x, y, P0, gamma]`` (m², dB², ...), eq 18; ``inf`` when the noise
        is neither given nor estimable (exactly 4 readings and no ``rss_std_db``).
    residual_rms_db : float
        RMS of ``r_hat_j - r_j`` over the readings (dB).
    n : int
        Number of readings used.
    """

    xy: FloatArray
    p0_dbm: float
    exponent: float
    cov: FloatArray
    residual_rms_db: float
    n: int

    @property
    def std(self) -> FloatArray:
        """Standard deviations of ``[x, y, P0, gamma]``, shape (4,)."""
        return np.sqrt(np.diag(self.cov))

    @property
    def xy_std_m(self) -> FloatArray:
        """Standard deviations of ``x`` and ``y`` (m), shape (2,)."""
        return self.std[:2]


def _distance(emitter_xy: FloatArray, points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(p - u_j)``, shape (n, 2), and the floored distance ``d_j``, shape (n,)."""
    diff = emitter_xy - points
    return diff, np.maximum(np.sqrt(np.einsum("ij,ij->i", diff, diff)), MIN_DISTANCE_M)


def rss_at(fit: EmitterFit, xy: ArrayLike) -> FloatArray:
    """RSS the fitted model predicts at some places (eq 8 / eq 15).

    Parameters
    ----------
    fit : EmitterFit
    xy : array_like, shape (..., 2)
        Places (m).

    Returns
    -------
    ndarray, shape (...)
        Predicted RSS (dBm).
    """
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim == 0 or pts.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., 2), got {pts.shape}")
    _, d = _distance(fit.xy, pts.reshape(-1, 2))
    rss = fit.p0_dbm - 10.0 * fit.exponent * np.log10(d)
    return np.asarray(rss.reshape(pts.shape[:-1]), dtype=np.float64)


def _starts(points: FloatArray, rss: FloatArray) -> list[FloatArray]:
    """Where the solver starts: the weighted centroid of the strongest readings, then the
    places of the ``EXTRA_STARTS`` strongest readings themselves (the cost has local
    minima; the best of these runs is kept)."""
    k = max(3, math.ceil(STRONGEST_FRACTION * rss.size))
    strongest = np.argpartition(-rss, k - 1)[:k]
    w = 10.0 ** ((rss[strongest] - rss.max()) / 10.0)
    centroid = w @ points[strongest] / w.sum()
    loudest = np.argsort(-rss, kind="stable")[:EXTRA_STARTS]
    return [_start_at(centroid, points, rss)] + [_start_at(points[i], points, rss) for i in loudest]


def _start_at(xy: FloatArray, points: FloatArray, rss: FloatArray) -> FloatArray:
    """The emitter at ``xy``, with ``P0`` and ``gamma`` by linear least squares there."""
    _, d = _distance(xy, points)
    A = np.column_stack([np.ones_like(d), -10.0 * np.log10(d)])
    (p0, gamma), *_ = np.linalg.lstsq(A, rss, rcond=None)
    if not (np.isfinite(p0) and np.isfinite(gamma) and 1.0 <= gamma <= 6.0):
        gamma = float(np.clip(gamma, 1.0, 6.0)) if np.isfinite(gamma) else 2.0
        p0 = float(np.mean(rss + 10.0 * gamma * np.log10(d)))
    return np.array([xy[0], xy[1], p0, gamma])


def fit_emitter(
    xy: ArrayLike,
    rss_dbm: ArrayLike,
    *,
    rss_std_db: float | ArrayLike | None = None,
    loss: Loss = "linear",
    f_scale_db: float = 3.0,
    min_spread_ratio: float = 0.05,
) -> EmitterFit | None:
    """Least-squares emitter position, ``P0`` and path-loss exponent (see module docstring).

    Parameters
    ----------
    xy : array_like, shape (n, 2)
        Places where the emitter was heard (m).
    rss_dbm : array_like, shape (n,)
        RSS there (dBm); only readings that heard the emitter (no -100 fill values).
    rss_std_db : float or array_like of shape (n,), optional
        RSS noise ``nu`` (dB), giving the weights and the absolute covariance of eq 18.
        By default unit weights and the noise estimated from the residuals.
    loss : {"linear", "soft_l1", "huber", "cauchy", "arctan"}
        ``scipy.optimize.least_squares`` loss; "linear" is the papers' least squares.
    f_scale_db : float
        Residual (in units of ``nu``, i.e. dB for unit weights) where a robust loss starts
        to down-weight; unused with "linear".
    min_spread_ratio : float
        Readings whose centred positions have a second singular value below this share of
        the first are taken as collinear. Our choice: 0.05, a strip 40 m long and under
        ~2 m wide.

    Returns
    -------
    EmitterFit or None
        None when under-determined (see the module docstring).

    Raises
    ------
    ValueError
        For malformed input: shapes, non-finite values, non-positive noise or scale.
    """
    points = np.asarray(xy, dtype=np.float64)
    rss = np.asarray(rss_dbm, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"xy must have shape (n, 2), got {points.shape}")
    n = points.shape[0]
    if rss.shape != (n,):
        raise ValueError(f"rss_dbm must have shape ({n},), got {rss.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(rss))):
        raise ValueError("xy and rss_dbm must be finite")
    absolute = rss_std_db is not None
    nu = np.ones(n) if rss_std_db is None else np.asarray(rss_std_db, dtype=np.float64)
    if nu.shape not in ((), (n,)):
        raise ValueError(f"rss_std_db must be a number or have shape ({n},), got {nu.shape}")
    nu = np.broadcast_to(nu, (n,))
    if not (np.all(np.isfinite(nu)) and np.all(nu > 0)):
        raise ValueError("rss_std_db must be positive and finite")
    if not (math.isfinite(f_scale_db) and f_scale_db > 0):
        raise ValueError(f"f_scale_db must be positive, got {f_scale_db}")
    if not 0 <= min_spread_ratio < 1:
        raise ValueError(f"min_spread_ratio must be in [0, 1), got {min_spread_ratio}")

    if n < MIN_OBSERVATIONS:
        return None
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if not sv[0] > 0 or sv[1] <= min_spread_ratio * sv[0]:
        return None

    def residuals(theta: FloatArray) -> FloatArray:
        _, d = _distance(theta[:2], points)
        return np.asarray((theta[2] - 10.0 * theta[3] * np.log10(d) - rss) / nu)

    def jacobian(theta: FloatArray) -> FloatArray:  # eq 16
        diff, d = _distance(theta[:2], points)
        J = np.empty((n, 4))
        near = np.einsum("ij,ij->i", diff, diff) < MIN_DISTANCE_M**2  # on the floor: flat
        J[:, :2] = np.where(near[:, None], 0.0, (-10.0 * theta[3] / _LN10) * diff / (d**2)[:, None])
        J[:, 2] = 1.0
        J[:, 3] = -10.0 * np.log10(d)
        return np.asarray(J / nu[:, None])

    runs = [
        least_squares(residuals, x0, jac=jacobian, loss=loss, f_scale=f_scale_db)
        for x0 in _starts(points, rss)
    ]
    good = [r for r in runs if r.success and np.all(np.isfinite(r.x))]
    if not good:
        return None
    result = min(good, key=lambda r: float(r.cost))
    theta = np.asarray(result.x, dtype=np.float64)

    _, s, Vt = np.linalg.svd(np.asarray(result.jac, dtype=np.float64), full_matrices=False)
    if not s[-1] > s[0] / MAX_CONDITION:
        return None
    cov = (Vt.T / s**2) @ Vt  # eq 18, (H^T R^-1 H)^-1
    if not absolute:
        dof = n - MIN_OBSERVATIONS
        cov = cov * (2.0 * float(result.cost) / dof) if dof > 0 else np.full((4, 4), np.inf)
    cov = 0.5 * (cov + cov.T)
    raw = np.asarray(result.fun, dtype=np.float64) * nu
    xy_hat = theta[:2].copy()
    for arr in (xy_hat, cov):
        arr.setflags(write=False)
    return EmitterFit(
        xy=xy_hat,
        p0_dbm=float(theta[2]),
        exponent=float(theta[3]),
        cov=cov,
        residual_rms_db=float(np.sqrt(np.mean(raw**2))),
        n=n,
    )
