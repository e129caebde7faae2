"""Error statistics of position estimates against ground truth.

Every evaluation command reports through ``error_report`` so that the numbers of two
commands (or of two engines) mean the same thing.

Rows. Row ``i`` pairs an estimate with its truth. A row whose estimate is missing (NaN in
either coordinate of ``est_xy_m``: the engine had no fix yet) is counted in ``n_missing``
and takes no part in any statistic below; ``n_points`` counts the other rows, and every
share is a share of those ``n_points`` rows.

Horizontal error of row ``i``, the Euclidean distance in the building frame::

    e_i = || (x_i, y_i)_est - (x_i, y_i)_true ||

``mean_m`` is the mean of ``e_i``, ``rms_m = sqrt(mean(e_i^2))``, ``max_m`` the largest,
and ``p50_m`` ... ``p95_m`` the percentiles by numpy's default (``method="linear"``)
rule: the sorted errors ``e_(0) <= ... <= e_(n-1)`` are read at the fractional position
``q / 100 * (n - 1)`` with linear interpolation between neighbours.

Floor and building. ``floor_hit_rate`` is the share of rows whose estimated floor equals
the true one; ``building_hit_rate`` likewise when buildings are given.

EvAAL score. The EvAAL/IPIN rule for WiFi fingerprinting (the UJIIndoorLoc track of the
2015 EvAAL-ETRI competition, Torres-Sospedra et al.) adds fixed penalties for a wrong
floor and a wrong building to the horizontal error and averages::

    evaal_mean_m = mean( e_i + floor_penalty_m * [floor_i wrong]
                             + building_penalty_m * [building_i wrong] )

with 4 m and 50 m as defaults. A wrong floor costs one penalty however many floors it
is off. It is reported only when buildings are given (the score is defined for
multi-building data).

IPIN score. The IPIN competition's smartphone tracks (Track 3 of IPIN 2023) score a trial
by the 75th percentile of the horizontal error plus a fixed penalty per floor of
difference (15 m by default), over the evaluation points::

    ipin_score_m = P75( e_i + floor_penalty_m * |level_i est - level_i true| )

with the same percentile rule as above; floors are levels here (0 ground, negative
below), so two floors off cost two penalties. Missing estimates take no part, as above.

Calibration of the reported uncertainty. When each fix carries a 1-σ radius ``sigma_i``
(per-axis standard deviation, ``Fix.uncertainty_m``), ``within_1sigma`` and
``within_2sigma`` are the shares of rows with ``e_i <= sigma_i`` and ``e_i <= 2 sigma_i``.
For an isotropic 2-D Gaussian error with per-axis σ, ``e / σ`` follows a Rayleigh
distribution, so a calibrated uncertainty gives::

    P(e <= k σ) = 1 - exp(-k^2 / 2):   1 - e^{-1/2} ≈ 39.3 %  (k = 1),
                                        1 - e^{-2}   ≈ 86.5 %  (k = 2).

Shares well below these mean the engine is over-confident; well above, timid. Rows whose
``sigma_i`` is not finite take no part in these two shares.

When each fix carries the radii it says hold 68 % and 95 % of the errors
(``Fix.accuracy_68_m``, ``accuracy_95_m``; ``server.positioning.model.accuracy``),
``within_68`` and ``within_95`` are the shares of rows inside them (0.68 and 0.95 when
they are right), and ``error_correlation`` is Pearson's correlation between the 68 %
radius and the error over the rows (``papers/000_*`` Table III: how well a predicted
accuracy follows the actual error; 0 when it tells nothing).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

# P(e <= kσ) for an isotropic 2-D Gaussian: what a calibrated sigma gives
WITHIN_1SIGMA_IDEAL = 1.0 - math.exp(-0.5)
WITHIN_2SIGMA_IDEAL = 1.0 - math.exp(-2.0)

_PERCENTILES = (50.0, 75.0, 80.0, 90.0, 95.0)


@dataclass(frozen=True)
class ErrorReport:
    """Error statistics of one evaluation (see the module docstring for each definition).

    Attributes
    ----------
    n_points : int
        Rows with an estimate; the statistics are over these.
    n_missing : int
        Rows without an estimate (NaN in ``est_xy_m``).
    mean_m, rms_m, p50_m, p75_m, p80_m, p90_m, p95_m, max_m : float or None
        Horizontal error in metres; None when ``n_points`` is 0.
    floor_hit_rate : float or None
        Share of rows on the right floor; None when ``n_points`` is 0.
    building_hit_rate : float or None
        Share of rows in the right building; None without buildings or rows.
    evaal_mean_m : float or None
        Mean error with floor and building penalties; None without buildings or rows.
    within_1sigma, within_2sigma : float or None
        Share of errors within 1 σ and 2 σ of their fix; None without sigma or without a
        row with a finite sigma.
    within_68, within_95 : float or None
        Share of errors within the fix's 68 % and 95 % radius; None without them.
    error_correlation : float or None
        Correlation of the 68 % radius with the error; None without radii, with fewer
        than three rows or when either does not vary.
    """

    n_points: int
    n_missing: int
    mean_m: float | None
    rms_m: float | None
    p50_m: float | None
    p75_m: float | None
    p80_m: float | None
    p90_m: float | None
    p95_m: float | None
    max_m: float | None
    floor_hit_rate: float | None
    building_hit_rate: float | None
    evaal_mean_m: float | None
    within_1sigma: float | None
    within_2sigma: float | None
    within_68: float | None = None
    within_95: float | None = None
    error_correlation: float | None = None

    def to_dict(self) -> dict[str, int | float | None]:
        """The fields by name, as JSON-ready Python ints, floats and None."""
        return asdict(self)


def _rows(name: str, value: ArrayLike, n: int, dtype: type[np.generic]) -> NDArray[np.generic]:
    array = np.asarray(value, dtype=dtype)
    if array.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {array.shape}")
    return array


def _xy(name: str, value: ArrayLike) -> FloatArray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim == 1 and array.size == 0:
        array = array.reshape(0, 2)
    if array.ndim != 2 or array.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got {array.shape}")
    return array


def _share(hits: NDArray[np.bool_]) -> float | None:
    return float(np.mean(hits)) if hits.size else None


def error_report(
    est_xy_m: ArrayLike,
    true_xy_m: ArrayLike,
    est_floor: ArrayLike,
    true_floor: ArrayLike,
    *,
    sigma_m: ArrayLike | None = None,
    accuracy_68_m: ArrayLike | None = None,
    accuracy_95_m: ArrayLike | None = None,
    est_building: ArrayLike | None = None,
    true_building: ArrayLike | None = None,
    floor_penalty_m: float = 4.0,
    building_penalty_m: float = 50.0,
) -> ErrorReport:
    """Error statistics of estimates against the truth (definitions in the module docstring).

    Parameters
    ----------
    est_xy_m : array_like, shape (n, 2)
        Estimated positions in metres; a row with NaN is a missing estimate.
    true_xy_m : array_like, shape (n, 2)
        True positions in metres; must be finite.
    est_floor, true_floor : array_like, shape (n,), int
        Estimated and true floors (any integer labels; only equality matters).
    sigma_m : array_like, shape (n,), optional
        1-σ radius (per-axis standard deviation) of each estimate in metres.
    accuracy_68_m, accuracy_95_m : array_like, shape (n,), optional
        The radii each estimate says hold 68 % and 95 % of the errors, in metres.
    est_building, true_building : array_like, shape (n,), int, optional
        Estimated and true buildings; give both or neither.
    floor_penalty_m, building_penalty_m : float
        EvAAL penalties for a wrong floor and a wrong building.

    Returns
    -------
    ErrorReport
        With ``n_points`` 0 and None statistics when no row has an estimate.

    Raises
    ------
    ValueError
        On mismatched shapes, non-finite truth, or only one of the building arrays.
    """
    est = _xy("est_xy_m", est_xy_m)
    truth = _xy("true_xy_m", true_xy_m)
    n = est.shape[0]
    if truth.shape != est.shape:
        raise ValueError(f"true_xy_m must have shape {est.shape}, got {truth.shape}")
    if not np.all(np.isfinite(truth)):
        raise ValueError("true_xy_m must be finite")
    if (est_building is None) != (true_building is None):
        raise ValueError("give both est_building and true_building, or neither")

    found = ~np.isnan(est).any(axis=1)
    e = np.hypot(*(est[found] - truth[found]).T)
    floor_ok = (
        _rows("est_floor", est_floor, n, np.int64) == _rows("true_floor", true_floor, n, np.int64)
    )[found]
    n_points = int(e.size)
    has_rows = n_points > 0

    building_hit_rate: float | None = None
    evaal_mean_m: float | None = None
    if est_building is not None and true_building is not None:
        building_ok = (
            _rows("est_building", est_building, n, np.int64)
            == _rows("true_building", true_building, n, np.int64)
        )[found]
        building_hit_rate = _share(building_ok)
        if has_rows:
            scores = e + floor_penalty_m * ~floor_ok + building_penalty_m * ~building_ok
            evaal_mean_m = float(np.mean(scores))

    within_1sigma: float | None = None
    within_2sigma: float | None = None
    if sigma_m is not None:
        sigma = _rows("sigma_m", sigma_m, n, np.float64)[found]
        known = np.isfinite(sigma)
        within_1sigma = _share(e[known] <= sigma[known])
        within_2sigma = _share(e[known] <= 2.0 * sigma[known])

    within_68 = within_95 = correlation = None
    if accuracy_68_m is not None:
        r68 = _rows("accuracy_68_m", accuracy_68_m, n, np.float64)[found]
        known = np.isfinite(r68)
        within_68 = _share(e[known] <= r68[known])
        correlation = _correlation(r68[known], e[known])
    if accuracy_95_m is not None:
        r95 = _rows("accuracy_95_m", accuracy_95_m, n, np.float64)[found]
        known = np.isfinite(r95)
        within_95 = _share(e[known] <= r95[known])

    stats: list[float | None] = [None] * 8
    if has_rows:
        p50, p75, p80, p90, p95 = np.percentile(e, _PERCENTILES).tolist()
        mean, rms, largest = float(np.mean(e)), float(np.sqrt(np.mean(e**2))), float(np.max(e))
        stats = [mean, rms, p50, p75, p80, p90, p95, largest]
    mean_m, rms_m, p50_m, p75_m, p80_m, p90_m, p95_m, max_m = stats
    return ErrorReport(
        n_points=n_points,
        n_missing=int(n - n_points),
        mean_m=mean_m,
        rms_m=rms_m,
        p50_m=p50_m,
        p75_m=p75_m,
        p80_m=p80_m,
        p90_m=p90_m,
        p95_m=p95_m,
        max_m=max_m,
        floor_hit_rate=_share(floor_ok),
        building_hit_rate=building_hit_rate,
        evaal_mean_m=evaal_mean_m,
        within_1sigma=within_1sigma,
        within_2sigma=within_2sigma,
        within_68=within_68,
        within_95=within_95,
        error_correlation=correlation,
    )


def _correlation(a: FloatArray, b: FloatArray) -> float | None:
    if a.size < 3 or float(np.std(a)) == 0.0 or float(np.std(b)) == 0.0:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def ipin_score(
    est_xy_m: ArrayLike,
    true_xy_m: ArrayLike,
    est_level: ArrayLike,
    true_level: ArrayLike,
    *,
    floor_penalty_m: float = 15.0,
    q: float = 75.0,
) -> float | None:
    """The IPIN smartphone-track score (see the module docstring).

    Parameters
    ----------
    est_xy_m : array_like, shape (n, 2)
        Estimated positions in metres; a row with NaN is a missing estimate.
    true_xy_m : array_like, shape (n, 2)
        True positions in metres; must be finite.
    est_level, true_level : array_like, shape (n,), int
        Estimated and true floor levels.
    floor_penalty_m : float
        Metres added per floor of difference.
    q : float
        Percentile, in [0, 100].

    Returns
    -------
    float or None
        None when no row has an estimate.

    Raises
    ------
    ValueError
        On mismatched shapes or non-finite truth.
    """
    est = _xy("est_xy_m", est_xy_m)
    truth = _xy("true_xy_m", true_xy_m)
    n = est.shape[0]
    if truth.shape != est.shape:
        raise ValueError(f"true_xy_m must have shape {est.shape}, got {truth.shape}")
    if not np.all(np.isfinite(truth)):
        raise ValueError("true_xy_m must be finite")
    est_l = np.asarray(_rows("est_level", est_level, n, np.int64), dtype=np.int64)
    true_l = np.asarray(_rows("true_level", true_level, n, np.int64), dtype=np.int64)
    floors_off = np.abs(est_l - true_l)
    found = ~np.isnan(est).any(axis=1)
    if not found.any():
        return None
    e = np.hypot(*(est[found] - truth[found]).T) + floor_penalty_m * floors_off[found]
    return float(np.percentile(e, q))


def error_cdf(errors_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Empirical cumulative distribution of errors, for plots.

    Parameters
    ----------
    errors_m : array_like, shape (n,)
        Errors in metres; non-finite values (missing estimates) are dropped.

    Returns
    -------
    errors : ndarray, shape (m,), float64
        The finite errors in ascending order.
    share : ndarray, shape (m,), float64
        ``share[i] = (i + 1) / m``: the fraction of errors at most ``errors[i]``.
    """
    e = np.asarray(errors_m, dtype=np.float64).ravel()
    e = np.sort(e[np.isfinite(e)])
    share = np.arange(1, e.size + 1, dtype=np.float64) / max(e.size, 1)
    return e, share
