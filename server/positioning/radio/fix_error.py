"""How far a radio fix is from the truth, as a function of its evidence.

The spread of the neighbours (``papers/003_*`` eq 17) says how tight the K nearest
reference points are, not how far the phone is: on ILC site2 WKNN fixes had a median
spread-derived σ of 1.3 m against a median error of 5.5 m. What does predict the error is
the evidence: the kind of scan and how many map emitters it matched (one or two BLE
beacons are not a 100-AP WiFi scan). This module holds that relation as a table,

    σ(kind, n) = per-axis standard deviation of the position error of a fix from a scan
                 of ``kind`` that matched ``n`` map emitters, n in bins ``edges``,

learned from the training data itself (``mapping.fix_calibration``: radio fixes of
held-out training paths against maps built from the other paths) and used as the fix
covariance ``σ² I`` by every engine.

σ per bin is taken from the 39.3 % quantile of the radial errors ``r``: for a 2-D
isotropic Gaussian with per-axis σ, ``P(r <= σ) = 1 - exp(-1/2) = 0.393``. A quantile
rather than the mean square keeps the rare fix on the wrong side of the building (which
the filters' innovation gates are there to refuse) from inflating every fix's σ. The
table is made non-increasing in ``n`` (isotonic regression weighted by the bin counts):
more matched emitters never mean a worse fix.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import isotonic_regression

EDGES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)
"""Lower edges of the bins of matched emitters (the last bin is open)."""

SIGMA_QUANTILE = 1.0 - math.exp(-0.5)  # 0.393: P(r <= σ) for a 2-D isotropic Gaussian

MIN_BIN_COUNT = 20  # fewer fixes than this: the bin borrows from its neighbours


def default_sigma_m(n_matched: int) -> float:
    """σ when no table was learned for a map: ``a + b / sqrt(n)`` (see ``DEFAULT``)."""
    return DEFAULT_SIGMA_FLOOR_M + DEFAULT_SIGMA_SCALE_M / math.sqrt(max(n_matched, 1))


# for maps built without walks to learn from (surveys through the API): falls with the
# evidence as the learned tables do. ILC site2's table (its 334 training paths) has 8 m
# for WiFi scans of 24 or more emitters and 11.6-13.6 m for BLE scans, this model
# 5.5-6.4 m and 10.9-16 m; learning a table from a survey is still to do
DEFAULT_SIGMA_FLOOR_M = 4.0
DEFAULT_SIGMA_SCALE_M = 12.0

# the 68 % error radius of a map's radio fixes when none were learned: between the two
# development venues' learned values (ILC site2 17.8 m, the IPIN logs 17-26 m per
# left-out trial; UJIIndoorLoc's training spots 8.4 m)
DEFAULT_ERROR_68_M = 18.0


@dataclass(frozen=True)
class FixErrorModel:
    """Per-axis 1-σ error of a radio fix by scan kind and matched-emitter bin.

    Attributes
    ----------
    edges : tuple of int
        Lower edges of the bins of matched emitters, increasing, the first 1.
    sigma_m : Mapping of str to tuple of float
        Per kind (``"wifi"``, ``"ble"``), σ in metres per bin. A kind not listed uses
        ``default_sigma_m``.
    counts : Mapping of str to tuple of int
        Fixes behind each bin (0 for a bin filled from its neighbours or the default).
    error_68_m : float
        The radius holding 68 % of the errors of all the fixes learned from (any kind,
        any bin): the size of this map's radio errors, in which the engines' reported
        radii are measured (``accuracy``). ``DEFAULT_ERROR_68_M`` without a table.
    """

    edges: tuple[int, ...] = EDGES
    sigma_m: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    counts: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    error_68_m: float = DEFAULT_ERROR_68_M

    def sigma(self, kind: str, n_matched: int) -> float:
        """σ in metres of a fix of ``kind`` that matched ``n_matched`` emitters."""
        table = self.sigma_m.get(kind)
        if table is None:
            return default_sigma_m(n_matched)
        b = max(int(np.searchsorted(self.edges, max(n_matched, 1), side="right")) - 1, 0)
        return table[b]

    def variance(self, kind: str, n_matched: int) -> float:
        """σ² in m² (the per-axis variance of the fix)."""
        return self.sigma(kind, n_matched) ** 2


DEFAULT = FixErrorModel()
"""No learned table: every kind uses ``default_sigma_m``."""


def fit(
    kinds: Sequence[str],
    n_matched: ArrayLike,
    errors_m: ArrayLike,
    edges: tuple[int, ...] = EDGES,
    min_count: int = MIN_BIN_COUNT,
) -> FixErrorModel:
    """Learn the table from fixes whose true error is known.

    Parameters
    ----------
    kinds : sequence of str, length n
        Scan kind of each fix.
    n_matched : array_like, shape (n,), int
        Matched emitters of each fix.
    errors_m : array_like, shape (n,)
        Horizontal distance of each fix from the truth; non-finite entries are ignored.
    edges : tuple of int
        Bin lower edges.
    min_count : int
        A bin with fewer fixes is filled by the isotonic fit of its neighbours (and, when a
        kind has fewer fixes than this in all, the kind keeps the default).

    Returns
    -------
    FixErrorModel
    """
    n = np.asarray(n_matched, dtype=np.int64)
    err = np.asarray(errors_m, dtype=np.float64)
    kind_arr = np.asarray(list(kinds), dtype=object)
    sigma: dict[str, tuple[float, ...]] = {}
    counts: dict[str, tuple[int, ...]] = {}
    for kind in sorted(set(kind_arr.tolist())):
        sel = (kind_arr == kind) & np.isfinite(err)
        if np.count_nonzero(sel) < min_count:
            continue
        b = np.searchsorted(edges, np.maximum(n[sel], 1), side="right") - 1
        per_bin = np.full(len(edges), np.nan)
        weight = np.zeros(len(edges))
        for i in range(len(edges)):
            e = err[sel][b == i]
            if e.size:
                per_bin[i] = float(np.quantile(e, SIGMA_QUANTILE))
                weight[i] = e.size
        have = weight >= min_count
        if not have.any():
            have = weight > 0
        x = np.flatnonzero(have)
        fitted = isotonic_regression(per_bin[x], weights=weight[x], increasing=False).x
        # bins without enough fixes take the fitted value of the nearest bin with them
        nearest = x[np.abs(np.arange(len(edges))[:, None] - x[None, :]).argmin(axis=1)]
        table = fitted[np.searchsorted(x, nearest)]
        # fewer emitters than any bin with fixes: never more confident than the default
        below = np.arange(len(edges)) < x[0]
        table[below] = np.maximum(
            table[below], [default_sigma_m(e) for e in np.array(edges)[below]]
        )
        sigma[kind] = tuple(float(v) for v in table)
        counts[kind] = tuple(int(c) for c in weight)
    known = err[np.isfinite(err)]
    error_68 = float(np.quantile(known, 0.68)) if known.size >= min_count else DEFAULT_ERROR_68_M
    return FixErrorModel(edges, MappingProxyType(sigma), MappingProxyType(counts), error_68)
