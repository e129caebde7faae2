"""Fingerprinting accuracy indicators (FAI): the error of a fingerprint fix predicted from
the scan, the emitters' geometry and the database (``papers/000_*`` Li et al., section
III-A/B, eq 10-27).

Gaussian-likelihood fingerprinting (eq 10-12). Each reference point ``i`` keeps, per
emitter ``j``, the mean ``mu_ij`` and variance ``sigma_ij^2`` of its readings; a scan ``q``
is as likely at ``i`` as ::

    zeta(q | l_i) = prod_j N(q_j; mu_ij, sigma_ij^2)                        (10-11)

over the map's columns of the scan's kind, an emitter not heard reading ``MISSING_DBM``
on either side as in the WKNN signal distance (``sigma_ij`` at least ``min_sd_db``: a
reference point heard once has no spread of its own); the fix is the likelihood-weighted mean of the
``kappa`` most likely points (eq 12). ``log_likelihoods`` computes the logarithms (their
products underflow otherwise).

The three indicators, each a predicted error in metres:

* **SS** (signal strength, eq 13-14): strong readings come from near emitters, whose
  fixes are better. Each heard emitter's log-distance model (``path_loss.EmitterFit``:
  ``r = P0 - 10 gamma log10 d``, eq 15-18) gives the distance the reading implies,
  ``d_j = 10^((P0_j - r_j) / (10 gamma_j))``; eq 14 scores a reading by ``1 / d_j`` and
  eq 13 averages the scores. Read literally, ``alpha_ss`` times the mean score would
  *grow* as the emitters come nearer, the opposite of what the paper says the indicator
  measures, so the indicator here is ``alpha_ss`` over the mean score: the harmonic mean
  of the implied distances, scaled (``signal_strength``).
* **SD** (geometry, eq 19-22): the dilution of precision of ranging to the heard
  emitters' fitted positions from the fix, ``H_j = (u - w_j) / |u - w_j|``,
  ``M = (H^T H)^-1``, ``SD = alpha_sd sqrt(M_11 + M_22)`` (``geometry``). Emitters on
  one side, or too few, give a large value; with fewer than two, or a singular ``H^T H``,
  it is infinite.
* **WD** (database, eq 23-24): a reference point's DSF is the mean geographical distance
  to the ``kappa_d`` reference points of its floor whose features are most like its own,
  by the likelihood of their means under its Gaussian model (eq 23 prints the likelihoods; the
  text and the reference it extends define the DSF as the mean distance, which is what
  predicts an error in metres). The WD of a fix is the likelihood-weighted mean of the DSF
  of the ``kappa`` points it used (``spreads``, ``weighted_spread``).

Each indicator takes the reference points' own location uncertainty ``sigma_sm`` (eq 9;
0 for surveyed points) in quadrature (eq 25, ``with_location_uncertainty``), and they
combine as ``MC = rho_ss SS + rho_sd SD + rho_wd WD`` (eq 26) or ``MCM = max(SS, SD, WD)``
(eq 27, ``combine``). Paper values (section IV-C): ``alpha_ss = 0.2`` (WiFi), ``alpha_sd =
5`` (WiFi; the paper names it ``sigma_sd``), ``rho = (0.2, 0.3, 0.5)``, ``kappa = kappa_d =
5``, a constant 6 m for the CT strategy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray

from server.positioning.model.params import NonNegative, Params, Positive
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap, ScanVector

FloatArray = NDArray[np.float64]

Strategy = Literal["ct", "ss", "sd", "wd", "mc", "mcm"]
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


@dataclass(frozen=True)
class FaiParams(Params):
    """Parameters of the indicators (``papers/000_*`` section IV-C values)."""

    strategy: Strategy = "mcm"
    ct_m: Positive = 6.0  # the constant accuracy of the CT strategy (WiFi)
    alpha_ss: Positive = 0.2  # eq 13
    alpha_sd: Positive = 5.0  # eq 22
    rho_ss: NonNegative = 0.2  # eq 26
    rho_sd: NonNegative = 0.3
    rho_wd: NonNegative = 0.5
    kappa: Annotated[int, Ge(1), Le(100)] = 5  # eq 12 and 24
    kappa_d: Annotated[int, Ge(1), Le(100)] = 5  # eq 23
    min_sd_db: Positive = 4.0  # the least RSS spread of a reference point, eq 11
    # magnetic profiles (``profile_matching``; section IV-C: CT 5 m, alpha_ss^m 50)
    strategy_mag: Strategy = "mcm"
    ct_mag_m: Positive = 5.0
    alpha_ss_mag: Positive = 50.0  # eq 13 with gradients in µT
    mag_steps: Annotated[int, Ge(0), Le(50)] = 10  # steps per profile (0: no magnetic fixes)
    mag_circle: Positive = 3.0  # search radius in the wireless fix's predicted errors
    max_mag_radius_m: Annotated[float, Ge(1), Le(100)] = 50.0  # and at most this
    mag_spacing_m: Annotated[float, Ge(0.25), Le(5)] = 0.5  # between candidate ends (a map cell)


@dataclass(frozen=True)
class FaiMaps:
    """What the indicators read of a radio map (``mapping.fai_maps.build_fai_maps``).

    Attributes
    ----------
    emitter_xy : ndarray, shape (n_em, 2)
        Fitted position of each map column's emitter (eq 15-18); NaN where it was not
        fitted.
    p0_dbm, exponent : ndarray, shape (n_em,)
        Its path-loss model (``P0`` at 1 m, ``gamma``); NaN where not fitted.
    dsf_m : ndarray, shape (n_rp,)
        DSF of each reference point (eq 23, ``spreads``); NaN where it has none.
    """

    emitter_xy: FloatArray
    p0_dbm: FloatArray
    exponent: FloatArray
    dsf_m: FloatArray


@dataclass(frozen=True)
class Indicators:
    """The three indicators of one fix and their combinations, in metres."""

    ss: float
    sd: float
    wd: float
    mc: float
    mcm: float

    def pick(self, strategy: Strategy, ct_m: float) -> float:
        """The predicted error by ``strategy`` (``ct``: the constant ``ct_m``)."""
        if strategy == "ct":
            return ct_m
        return float(getattr(self, strategy))


def _sd(
    radio: RadioMap, rows: NDArray[np.intp], cols: NDArray[np.intp], min_sd_db: float
) -> FloatArray:
    """``sigma_ij`` of eq 11: the points' RSS spread, at least ``min_sd_db`` (an emitter a
    point did not hear has no spread of its own there)."""
    var = radio.var_db2[np.ix_(rows, cols)].astype(np.float64)
    return np.sqrt(np.maximum(var, min_sd_db**2))


def log_likelihoods(
    radio: RadioMap, scan: ScanVector, candidates: NDArray[np.bool_], min_sd_db: float
) -> FloatArray:
    """``log zeta(q | l_i)`` of each candidate reference point (eq 11) over the columns of
    the scan's kind, an emitter not heard reading ``MISSING_DBM`` on either side, as the
    WKNN signal distance counts it (``fingerprints``); ``-inf`` for a point that is not a
    candidate or shares no heard emitter with the scan."""
    out = np.full(radio.rp_xy.shape[0], -np.inf)
    rows = np.flatnonzero(candidates)
    heard = scan.mask & (scan.rssi_dbm > MISSING_DBM)
    if rows.size == 0 or not heard.any():
        return out
    cols = np.flatnonzero(scan.mask)
    mean = radio.mean_dbm[np.ix_(rows, cols)].astype(np.float64)
    sd = _sd(radio, rows, cols, min_sd_db)
    z = (scan.rssi_dbm[cols].astype(np.float64) - mean) / sd
    ll = (-0.5 * z**2 - np.log(sd) - _LOG_SQRT_2PI).sum(axis=1)
    shared = (mean[:, heard[cols]] > MISSING_DBM).any(axis=1)
    out[rows] = np.where(shared, ll, -np.inf)
    return out


@dataclass(frozen=True)
class LikelihoodFix:
    """Eq 12: the fix, the points it used (most likely first) and their weights."""

    x_m: float
    y_m: float
    points: NDArray[np.int64]
    weights: FloatArray


def likelihood_fix(log_zeta: FloatArray, rp_xy: FloatArray, kappa: int) -> LikelihoodFix | None:
    """The likelihood-weighted mean of the ``kappa`` most likely points (eq 12); None when
    no point is likely at all."""
    finite = np.flatnonzero(np.isfinite(log_zeta))
    if finite.size == 0:
        return None
    top = finite[np.argsort(-log_zeta[finite], kind="stable")[:kappa]]
    w = np.exp(log_zeta[top] - log_zeta[top].max())
    w /= w.sum()
    xy = w @ rp_xy[top].astype(np.float64)
    return LikelihoodFix(float(xy[0]), float(xy[1]), top.astype(np.int64), w)


def signal_strength(
    rssi_dbm: Sequence[float], p0_dbm: Sequence[float], exponent: Sequence[float], alpha: float
) -> float:
    """SS (eq 13-14, see the module docstring): ``alpha`` times the harmonic mean of the
    distances the readings imply; infinite without a reading."""
    if not rssi_dbm:
        return math.inf
    r, p0, g = (np.asarray(v, dtype=np.float64) for v in (rssi_dbm, p0_dbm, exponent))
    scores = 10.0 ** ((r - p0) / (10.0 * g))  # eq 14: 1 / d_j
    return float(alpha / scores.mean())


def geometry(device_xy: Sequence[float], emitter_xy: FloatArray, alpha: float) -> float:
    """SD (eq 19-22): ``alpha`` times the horizontal DOP of ranging from ``device_xy`` to
    the emitters at ``emitter_xy`` (shape (n, 2)); infinite when it is undetermined."""
    w = np.asarray(emitter_xy, dtype=np.float64).reshape(-1, 2)
    diff = np.asarray(device_xy, dtype=np.float64) - w
    d = np.hypot(diff[:, 0], diff[:, 1])
    keep = d > 1e-9
    if np.count_nonzero(keep) < 2:
        return math.inf
    H = diff[keep] / d[keep, None]  # eq 19
    normal = H.T @ H
    if np.linalg.cond(normal) > 1e12:
        return math.inf
    M = np.linalg.inv(normal)  # eq 21
    return float(alpha * math.sqrt(M[0, 0] + M[1, 1]))  # eq 22


def spreads(radio: RadioMap, kappa_d: int, min_sd_db: float) -> FloatArray:
    """DSF of every reference point (eq 23, see the module docstring): the mean distance
    to the ``kappa_d`` other points of its floor whose means are most likely under its
    model, over the emitters heard on the floor (NaN for a point alone on its floor).

    The log-likelihood of point ``k``'s means under point ``i``'s model is, but for a
    term of ``i`` alone, ``-1/2 sum_j a_ij (m_kj - m_ij)^2`` with ``a_ij = 1 / sigma_ij^2``;
    expanded, its ``k``-dependent part is two matrix products per floor."""
    n = radio.rp_xy.shape[0]
    out = np.full(n, np.nan)
    xy = radio.rp_xy.astype(np.float64)
    for floor in np.unique(radio.rp_floor):
        rows = np.flatnonzero(radio.rp_floor == floor)
        if rows.size < 2:
            continue
        heard = (radio.mean_dbm[rows] > MISSING_DBM).any(axis=0)
        cols = np.flatnonzero(heard)
        m = radio.mean_dbm[np.ix_(rows, cols)].astype(np.float64)
        a = 1.0 / _sd(radio, rows, cols, min_sd_db) ** 2
        # cost[i, k] = sum_j a_ij m_kj^2 - 2 a_ij m_ij m_kj  (lower: more alike)
        cost = a @ (m**2).T - 2.0 * (a * m) @ m.T
        np.fill_diagonal(cost, np.inf)
        take = min(kappa_d, rows.size - 1)
        near = np.argpartition(cost, take - 1, axis=1)[:, :take]
        d = np.hypot(*(xy[rows[near]] - xy[rows][:, None, :]).transpose(2, 0, 1))
        out[rows] = d.mean(axis=1)
    return out


def weighted_spread(dsf: FloatArray, points: NDArray[np.int64], weights: FloatArray) -> float:
    """WD (eq 24): the weighted mean DSF of the points a fix used (those with a DSF);
    NaN when none has one."""
    values = dsf[points]
    known = np.isfinite(values)
    if not known.any():
        return math.nan
    w = weights[known]
    return float(w @ values[known] / w.sum())


def with_location_uncertainty(value_m: float, sigma_sm_m: float) -> float:
    """Eq 25: an indicator with the reference points' own location uncertainty."""
    return math.hypot(value_m, sigma_sm_m)


def indicators(
    fai_maps: FaiMaps,
    scan: ScanVector,
    fix_xy: Sequence[float],
    points: NDArray[np.int64],
    weights: FloatArray,
    params: FaiParams,
    sigma_sm_m: float = 0.0,
) -> Indicators:
    """SS, SD and WD of a fix at ``fix_xy`` made of the reference ``points`` with
    ``weights`` from ``scan`` (eq 13-25), and their combinations (eq 26-27). Emitters
    without a fitted model take no part in SS and SD."""
    heard = np.flatnonzero(scan.mask & (scan.rssi_dbm > MISSING_DBM))
    fitted = heard[np.isfinite(fai_maps.exponent[heard]) & (fai_maps.exponent[heard] > 0)]
    ss = signal_strength(
        scan.rssi_dbm[fitted].astype(np.float64).tolist(),
        fai_maps.p0_dbm[fitted].tolist(),
        fai_maps.exponent[fitted].tolist(),
        params.alpha_ss,
    )
    sd = geometry(fix_xy, fai_maps.emitter_xy[fitted], params.alpha_sd)
    wd = weighted_spread(fai_maps.dsf_m, points, weights)
    ss, sd, wd = (with_location_uncertainty(v, sigma_sm_m) for v in (ss, sd, wd))
    return combine(ss, sd, wd, params)


def combine(ss: float, sd: float, wd: float, params: FaiParams) -> Indicators:
    """MC (eq 26) and MCM (eq 27) of the three indicators. An indicator that could not
    be computed (NaN or infinite) takes no part: MC renormalises the remaining
    coefficients, MCM takes the largest finite one (NaN when none is finite)."""
    values = np.array([ss, sd, wd])
    rho = np.array([params.rho_ss, params.rho_sd, params.rho_wd])
    finite = np.isfinite(values)
    if not finite.any():
        return Indicators(ss, sd, wd, math.nan, math.nan)
    weight = rho[finite].sum()
    mc = float(rho[finite] @ values[finite] / weight) if weight > 0 else math.nan
    return Indicators(ss, sd, wd, mc, float(values[finite].max()))
