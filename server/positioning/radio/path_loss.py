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

Starts (our addition, not in the papers)
---------------------------------------
The cost has local minima: a trust-region run from one place can stop metres from the
truth even on noiseless readings. So the solver runs from several starts and keeps the
run with the lowest cost; adding a start can only lower the cost found.

The first start is a linearisation that is exact for noiseless readings beyond 1 m. With
``gamma`` fixed, the model says ``d_j^2 = K s_j``, with ``s_j = 10^((r_max - r_j)/(5 gamma))``
and ``K = 10^((P0 - r_max)/(5 gamma))``. Writing ``d_j^2 = |p|^2 - 2 u_j . p + |u_j|^2``
(places centred on their mean) turns each reading into a linear equation in
``(x, y, c, K)``, with ``c = |p|^2`` taken as a fourth unknown::

    -2 u_j . p + c - K s_j = -|u_j|^2                                      (L1)

An RSS error ``delta_j`` moves row ``j`` by about ``d_j^2 ln 10 / (5 gamma) delta_j``. Since
``d_j^2`` is proportional to ``s_j``, the rows are divided by ``s_j nu_j`` (weighted least
squares), and the residual of each row is turned back into dB by dividing it by
``K ln 10 / (5 gamma)``. The sum of these squares, the misfit, can be compared across
``gamma``, and it is 0 at the true ``gamma`` when there is no noise. (L1) is solved on a
grid over ``gamma`` (``GAMMA_GRID_STEP`` over ``GAMMA_RANGE``). Each of the deepest
``GAMMA_VALLEYS`` valleys of the misfit is then searched on finer grids (``GAMMA_PASSES``,
each ten times finer). The position with the lowest misfit gets ``P0`` and ``gamma`` by
linear least squares there. The misfit is used rather than the cost itself because the
cost, followed along ``gamma``, jumps wherever the position passes within 1 m of a reading:
its valley around the truth can be narrower than a grid step.

A reading within 1 m of the emitter (flat, ``r_j = P0``) breaks (L1). That reading is then
the strongest, and the emitter lies within 1 m of it, where one of the other starts is.
The other starts are the weighted centroid of the strongest quarter of the readings
(weights in linear power, ``10^((r_j - r_max)/10)``) and the places of the three
strongest readings, each with ``P0`` and ``gamma`` found by linear least squares there.
With noise, no start is sure to reach the global minimum, and each of these is sometimes
the only one that finds the lowest cost (seen with outliers or few readings), so all of
them stay.

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
GAMMA_RANGE = (1.0, 6.0)  # the path-loss exponents a start may take
GAMMA_GRID_STEP = 0.1  # the linearised start's first grid over gamma, on GAMMA_RANGE
GAMMA_VALLEYS = 3  # valleys of that grid searched further
GAMMA_ZOOM_POINTS = 21  # each further grid spans the previous one's neighbours: 10 times finer
GAMMA_PASSES = 2  # further grids per valley: 0.1 down to 1e-3
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


def _starts(points: FloatArray, rss: FloatArray, nu: FloatArray) -> list[FloatArray]:
    """Where the solver starts (module docstring): the linearised start when it exists,
    the weighted centroid of the strongest readings, then the places of the
    ``EXTRA_STARTS`` strongest readings themselves."""
    k = max(3, math.ceil(STRONGEST_FRACTION * rss.size))
    strongest = np.argpartition(-rss, k - 1)[:k]
    w = 10.0 ** ((rss[strongest] - rss.max()) / 10.0)
    centroid = w @ points[strongest] / w.sum()
    loudest = np.argsort(-rss, kind="stable")[:EXTRA_STARTS]
    starts = [_start_at(centroid, points, rss)] + [
        _start_at(points[i], points, rss) for i in loudest
    ]
    linear = _linearised_start(points, rss, nu)
    return starts if linear is None else [linear, *starts]


def _start_at(xy: FloatArray, points: FloatArray, rss: FloatArray) -> FloatArray:
    """The emitter at ``xy``, with ``P0`` and ``gamma`` by linear least squares there."""
    _, d = _distance(xy, points)
    A = np.column_stack([np.ones_like(d), -10.0 * np.log10(d)])
    (p0, gamma), *_ = np.linalg.lstsq(A, rss, rcond=None)
    lo, hi = GAMMA_RANGE
    if not (np.isfinite(p0) and np.isfinite(gamma) and lo <= gamma <= hi):
        gamma = float(np.clip(gamma, lo, hi)) if np.isfinite(gamma) else 2.0
        p0 = float(np.mean(rss + 10.0 * gamma * np.log10(d)))
    return np.array([xy[0], xy[1], p0, gamma])


def _profiled(
    candidates: FloatArray, points: FloatArray, rss: FloatArray, nu: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The weighted cost at each candidate position with ``P0`` and ``gamma`` solved there
    by linear least squares.

    Parameters
    ----------
    candidates : ndarray, shape (m, 2)
    points : ndarray, shape (n, 2)
    rss, nu : ndarray, shape (n,)

    Returns
    -------
    cost, p0, gamma : ndarray, shape (m,)
        ``sum_j ((P0 - 10 gamma log10 d_j - r_j) / nu_j)^2`` at its minimum over ``P0`` and
        ``gamma``, and that ``P0`` and ``gamma`` (``gamma`` 0 where all ``d_j`` are equal).
    """
    diff = candidates[:, None, :] - points[None, :, :]
    L = -10.0 * np.log10(np.maximum(np.sqrt(np.einsum("mnk,mnk->mn", diff, diff)), 1.0))
    w = 1.0 / nu**2
    L_mean = L @ w / w.sum()
    r_mean = float(rss @ w / w.sum())
    Lc, rc = L - L_mean[:, None], rss - r_mean
    s_LL, s_Lr, s_rr = (Lc * Lc) @ w, (Lc * rc) @ w, float((rc * rc) @ w)
    gamma = np.divide(s_Lr, s_LL, out=np.zeros_like(s_Lr), where=s_LL > 0)
    return np.maximum(s_rr - gamma * s_Lr, 0.0), r_mean - gamma * L_mean, gamma


def _linearised(
    gammas: FloatArray, points: FloatArray, rss: FloatArray, nu: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The linearised model (module docstring) solved for each ``gamma``.

    Parameters
    ----------
    gammas : ndarray, shape (g,)
    points : ndarray, shape (n, 2)
    rss, nu : ndarray, shape (n,)

    Returns
    -------
    xy : ndarray, shape (g, 2)
        The emitter position.
    misfit : ndarray, shape (g,)
        The weighted sum of squared row residuals, each turned into dB by the row's
        sensitivity ``K ln 10 / (5 gamma)`` (so comparable across ``gamma``); ``inf`` where
        ``K <= 0``.
    """
    centre = points.mean(axis=0)
    u = points - centre
    a = np.column_stack([-2.0 * u, np.ones(len(u))])  # row j's (x, y, c) coefficients, (n, 3)
    c = np.einsum("ij,ij->i", u, u)  # |u_j|^2
    s = 10.0 ** ((rss.max() - rss)[None, :] / (5.0 * gammas[:, None]))  # (g, n)
    # normal equations of the rows divided by s_j nu_j, summed as (g, n) @ (n, k) products
    q, t = 1.0 / (s * nu) ** 2, 1.0 / (s * nu**2)
    AtA = np.empty((gammas.size, 4, 4))
    AtA[:, :3, :3] = (q @ np.einsum("ni,nk->nik", a, a).reshape(-1, 9)).reshape(-1, 3, 3)
    AtA[:, :3, 3] = AtA[:, 3, :3] = -(t @ a)
    AtA[:, 3, 3] = np.sum(1.0 / nu**2)
    Atb = np.column_stack([-(q @ (c[:, None] * a)), t @ c])
    scale = np.sqrt(np.einsum("gkk->gk", AtA))  # unit diagonal before the (g, 4, 4) solve
    AtA = AtA / scale[:, :, None] / scale[:, None, :]
    sol = np.einsum("gkl,gl->gk", np.linalg.pinv(AtA, hermitian=True), Atb / scale) / scale
    K = sol[:, 3]
    rows = (sol[:, :3] @ a.T - s * K[:, None] + c) / (s * nu)  # (g, n)
    db = K * _LN10 / (5.0 * gammas)
    misfit = np.where(K > 0, np.einsum("gn,gn->g", rows, rows) / db**2, np.inf)
    return np.asarray(sol[:, :2] + centre, dtype=np.float64), np.asarray(misfit, dtype=np.float64)


def _linearised_start(points: FloatArray, rss: FloatArray, nu: FloatArray) -> FloatArray | None:
    """The linearised start ``[x, y, P0, gamma]`` (module docstring), or None when it
    comes out non-finite. The misfit over ``gamma`` can have more than one valley, of
    nearly equal depth on a coarse grid, so each of the deepest ``GAMMA_VALLEYS`` valleys
    of the first grid is searched ``GAMMA_PASSES`` times, each grid between the neighbours
    of the previous one's best."""

    def scored(gammas: FloatArray) -> tuple[FloatArray, FloatArray]:
        xy, misfit = _linearised(gammas, points, rss, nu)
        return xy, np.where(np.isfinite(misfit) & np.all(np.isfinite(xy), axis=1), misfit, np.inf)

    lo, hi = GAMMA_RANGE
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        grid = np.linspace(lo, hi, round((hi - lo) / GAMMA_GRID_STEP) + 1)
        xy, misfit = scored(grid)
        padded = np.concatenate([[np.inf], misfit, [np.inf]])
        valleys = np.flatnonzero(
            (misfit <= padded[:-2]) & (misfit <= padded[2:]) & np.isfinite(misfit)
        )
        if valleys.size == 0:
            return None
        valleys = valleys[np.argsort(misfit[valleys], kind="stable")[:GAMMA_VALLEYS]]
        step = np.full(valleys.size, GAMMA_GRID_STEP)
        centre = grid[valleys]
        for _ in range(GAMMA_PASSES):
            offsets = np.linspace(-1.0, 1.0, GAMMA_ZOOM_POINTS)
            gammas = np.clip(centre[:, None] + step[:, None] * offsets, lo, hi)  # (v, k)
            xy, misfit = scored(gammas.ravel())
            best = np.argmin(misfit.reshape(gammas.shape), axis=1)
            centre = gammas[np.arange(valleys.size), best]
            step = step * 2.0 / (GAMMA_ZOOM_POINTS - 1)
    i = int(np.argmin(misfit))
    if not np.isfinite(misfit[i]):
        return None
    _, p0, gamma = _profiled(xy[i : i + 1], points, rss, nu)
    theta = np.array([xy[i, 0], xy[i, 1], p0[0], gamma[0]])
    return theta if np.all(np.isfinite(theta)) else None


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
        for x0 in _starts(points, rss, nu)
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
