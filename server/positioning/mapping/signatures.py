"""Signature quality check and fixed-AP identification (``papers/003_*`` IV-D, IV-E1).

Both steps work on radio readings as flat arrays, one row per reading: the grid cell the
reading fell in after alignment and gridding (IV-C), the emitter, the RSS, and for
fixed APs the time and aligned position. Outputs say what was dropped and why, for the
map quality report.

Signature data selection (IV-D)
-------------------------------
Per grid cell, in the paper's order:

1. weak readings: ``r < -90 dBm`` are dropped ("the WiFi APs with weak RSS (e.g., less
   than -90 dBm) were excluded");
2. few readings: a cell x AP with fewer than ``min_readings`` remaining readings is
   dropped ("APs with few signatures (e.g., less than a certain threshold) were
   discarded"). The paper gives no number; we use 4, the fewest readings for which the
   quartiles of step 4 are distinct order statistics;
3. few APs: a cell with fewer than 6 APs left is dropped (as recommended by the paper's
   ref. [11]: fingerprinting degrades below 6 APs per RP);
4. outliers: in each remaining cell x AP, readings outside
   ``[Q1 - 1.5 IQR, Q3 + 1.5 IQR]``, ``IQR = Q3 - Q1``, are dropped; ``Q1``, ``Q3`` are the
   25th and 75th percentiles with linear interpolation between order statistics (numpy's
   default): for ``n`` sorted values ``v_0 <= ... <= v_{n-1}`` and ``h = (n - 1) q``,
   ``Q(q) = v_⌊h⌋ + (h - ⌊h⌋)(v_⌊h⌋+1 - v_⌊h⌋)``.

Step 4 removes single readings, never a whole cell x AP (the median is always inside the
fence), so it cannot change the AP count of step 3. ``iqr_inliers`` is the fence alone,
for the magnetic field (the paper applies it to "AP and MF data").

Fixed APs (IV-E1)
-----------------
An AP is *fixed* (installed on this floor and not moving) when, in order:

1. it was heard on more than three distinct days (``n_days >= 4``); a day is
   ``⌊(t_ms + day_offset_ms) / 86 400 000⌋`` (``day_offset_ms`` is the site's UTC offset);
2. it was heard stronger than ``-55 dBm`` at least once ("RSS greater than -55 dBm [...]
   to ensure that the AP was within the target floor");
3. its strong readings (``r > cluster_dbm`` with an aligned position) are at least
   ``min_cluster_readings`` (3, ours: one or two points cannot show a cluster) and
   cluster in an area below 100 m².

The paper "clustered" the strong-signature locations and took "the cluster area"
without saying how. Here the area of the positions ``p_i`` (``i = 1..m``) is::

    c = 1/m sum p_i,    A = 2π · 1/m sum |p_i - c|² = 2π (σ_x² + σ_y²)

the area of the disc that has the same second moment (a disc of radius ``ρ`` filled
uniformly has ``σ_x² + σ_y² = ρ²/2``, so ``A = π ρ²`` exactly). Unlike a convex hull or a
covariance ellipse, it does not vanish when the positions lie on a line, which is how an
AP carried along a corridor shows up (a segment of length ``L`` gives ``A = π L² / 6``:
100 m² at ``L = 13.8 m``), and one stray position moves it by its squared distance over
``m`` instead of redrawing a hull. ``cluster_dbm`` defaults to the -55 dBm of IV-E1; the
paper's experiment (VI-D1) located signatures "stronger than -65 dBm" instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

DAY_MS = 86_400_000

QC_REASONS = ("kept", "weak", "few_readings", "few_aps", "outlier")
KEPT, WEAK, FEW_READINGS, FEW_APS, OUTLIER = range(5)


def _ints(name: str, value: ArrayLike, n: int | None = None) -> IntArray:
    arr = np.asarray(value)
    if arr.ndim != 1 or (n is not None and arr.size != n):
        shape = f"({n},)" if n is not None else "(n,)"
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must hold integers, got dtype {arr.dtype}")
    return arr.astype(np.int64)


def _floats(name: str, value: ArrayLike, n: int) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _group_quartiles(inverse: IntArray, values: FloatArray, n_groups: int) -> FloatArray:
    """Q1 and Q3 per group, shape (n_groups, 2); every group must be non-empty."""
    order = np.lexsort((values, inverse))
    v = values[order]
    count = np.bincount(inverse, minlength=n_groups)
    first = (np.cumsum(count) - count)[:, None]
    h = (count - 1)[:, None] * np.array([0.25, 0.75])[None, :]
    lo = np.floor(h).astype(np.int64)
    hi = np.minimum(lo + 1, (count - 1)[:, None])
    a, b, frac = v[first + lo], v[first + hi], h - lo
    # numpy's own lerp (from the nearer end), so fences match np.percentile to the bit
    return np.asarray(np.where(frac >= 0.5, b - (b - a) * (1 - frac), a + (b - a) * frac))


def iqr_inliers(group: ArrayLike, values: ArrayLike, k: float = 1.5) -> BoolArray:
    """True for values inside their group's fence ``[Q1 - k IQR, Q3 + k IQR]`` (IV-D).

    Parameters
    ----------
    group : array_like, shape (n,), int
        Group label of each value (e.g. a cell x AP index).
    values : array_like, shape (n,)
        RSS in dBm or field magnitude in µT; finite.
    k : float
        Fence width in IQRs; 1.5 in the paper.

    Returns
    -------
    ndarray, shape (n,), bool
    """
    g = _ints("group", group)
    v = _floats("values", values, g.size)
    if not (math.isfinite(k) and k >= 0):
        raise ValueError(f"k must be finite and >= 0, got {k}")
    if g.size == 0:
        return np.zeros(0, dtype=np.bool_)
    labels, inverse = np.unique(g, return_inverse=True)
    inverse = inverse.reshape(-1)
    q = _group_quartiles(inverse, v, labels.size)
    iqr = q[:, 1] - q[:, 0]
    low = (q[:, 0] - k * iqr)[inverse]
    high = (q[:, 1] + k * iqr)[inverse]
    return np.asarray((v >= low) & (v <= high))


@dataclass(frozen=True)
class SignatureQC:
    """Outcome of the signature check, per reading and per cell.

    Attributes
    ----------
    reason : ndarray, shape (n,), int8
        Index into ``QC_REASONS``: ``KEPT`` or why the reading was dropped (the first
        step that dropped it).
    cells : ndarray, shape (n_cells,), int64
        The distinct cells of the input, sorted.
    cell_n_aps : ndarray, shape (n_cells,), int64
        APs per cell after steps 1-2.
    cell_kept : ndarray, shape (n_cells,), bool
        Cells that survive (``cell_n_aps >= min_aps``).
    """

    reason: NDArray[np.int8]
    cells: IntArray
    cell_n_aps: IntArray
    cell_kept: BoolArray

    @property
    def keep(self) -> BoolArray:
        """Readings that pass, shape (n,)."""
        return np.asarray(self.reason == KEPT)

    @property
    def counts(self) -> dict[str, int]:
        """Readings per outcome, keyed by ``QC_REASONS``."""
        n = np.bincount(self.reason, minlength=len(QC_REASONS))
        return {name: int(c) for name, c in zip(QC_REASONS, n, strict=True)}


def check_signatures(
    cell: ArrayLike,
    emitter: ArrayLike,
    rssi_dbm: ArrayLike,
    *,
    min_rssi_dbm: float = -90.0,  # IV-D (1)
    min_readings: int = 4,  # IV-D (2): "a certain threshold"; ours
    min_aps: int = 6,  # IV-D (3)
    iqr_k: float = 1.5,  # IV-D (4)
) -> SignatureQC:
    """Signature data selection of IV-D (module docstring).

    Parameters
    ----------
    cell : array_like, shape (n,), int
        Grid cell of each reading.
    emitter : array_like, shape (n,), int
        Emitter (AP) index of each reading.
    rssi_dbm : array_like, shape (n,)
        RSS in dBm, finite.
    min_rssi_dbm : float
        Readings below this are weak.
    min_readings : int
        Fewest readings a cell x AP needs.
    min_aps : int
        Fewest APs a cell needs.
    iqr_k : float
        Outlier fence width in IQRs.

    Returns
    -------
    SignatureQC
    """
    c = _ints("cell", cell)
    e = _ints("emitter", emitter, c.size)
    r = _floats("rssi_dbm", rssi_dbm, c.size)
    if min_readings < 1 or min_aps < 1:
        raise ValueError("min_readings and min_aps must be at least 1")
    reason = np.full(c.size, KEPT, dtype=np.int8)
    cells, cell_of = np.unique(c, return_inverse=True)
    cell_of = cell_of.reshape(-1)

    weak = r < min_rssi_dbm
    reason[weak] = WEAK
    alive = np.flatnonzero(~weak)

    # cell x AP groups of the readings left
    pairs, inverse = np.unique(
        np.column_stack([cell_of[alive], e[alive]]).reshape(-1, 2), axis=0, return_inverse=True
    )
    group = np.full(c.size, -1, dtype=np.int64)
    group[alive] = inverse.reshape(-1)
    group_size = np.bincount(group[alive], minlength=pairs.shape[0])
    few = group_size[group[alive]] < min_readings
    reason[alive[few]] = FEW_READINGS
    big = group_size >= min_readings

    cell_n_aps = np.bincount(pairs[big, 0], minlength=cells.size).astype(np.int64)
    cell_kept = cell_n_aps >= min_aps
    alive = alive[~few]
    poor = ~cell_kept[cell_of[alive]]
    reason[alive[poor]] = FEW_APS
    alive = alive[~poor]

    inside = iqr_inliers(group[alive], r[alive], iqr_k)
    reason[alive[~inside]] = OUTLIER
    return SignatureQC(
        reason=reason, cells=cells.astype(np.int64), cell_n_aps=cell_n_aps, cell_kept=cell_kept
    )


# ---------------------------------------------------------------- fixed APs (IV-E1)

FIXED_AP_REASONS = ("fixed", "not_heard", "few_days", "weak", "few_strong_positions", "spread")
FIXED, NOT_HEARD, FEW_DAYS, NOT_STRONG, FEW_STRONG_POSITIONS, SPREAD = range(6)


@dataclass(frozen=True)
class FixedApParams:
    """Fixed-AP rules of ``papers/003_*`` IV-E1."""

    min_days: int = 4  # IV-E1: "more than three days"
    strong_dbm: float = -55.0  # IV-E1: "RSS greater than -55 dBm"
    cluster_dbm: float = -55.0  # strong signatures to locate (VI-D1 used -65 dBm)
    max_area_m2: float = 100.0  # IV-E1: "cluster area within 100 m²"
    min_cluster_readings: int = 3  # ours
    day_offset_ms: int = 0  # the site's UTC offset, so days break at local midnight

    def __post_init__(self) -> None:
        if self.min_days < 1 or self.min_cluster_readings < 1:
            raise ValueError("min_days and min_cluster_readings must be at least 1")
        if not (math.isfinite(self.max_area_m2) and self.max_area_m2 > 0):
            raise ValueError(f"max_area_m2 must be positive, got {self.max_area_m2}")


@dataclass(frozen=True)
class FixedAps:
    """Per emitter: fixed or not, why, and the numbers behind it.

    Attributes
    ----------
    fixed : ndarray, shape (n_em,), bool
    reason : ndarray, shape (n_em,), int8
        Index into ``FIXED_AP_REASONS``: ``FIXED`` or the first rule that failed.
    n_days : ndarray, shape (n_em,), int64
        Distinct days the emitter was heard.
    max_rssi_dbm : ndarray, shape (n_em,), float64
        Strongest reading; NaN when never heard.
    n_cluster : ndarray, shape (n_em,), int64
        Readings above ``cluster_dbm`` with a finite position.
    centroid_xy_m : ndarray, shape (n_em, 2), float64
        Mean of those positions; NaN when there are none.
    cluster_area_m2 : ndarray, shape (n_em,), float64
        ``A = 2π (σ_x² + σ_y²)`` of those positions; NaN when there are none.
    """

    fixed: BoolArray
    reason: NDArray[np.int8]
    n_days: IntArray
    max_rssi_dbm: FloatArray
    n_cluster: IntArray
    centroid_xy_m: FloatArray
    cluster_area_m2: FloatArray

    @property
    def counts(self) -> dict[str, int]:
        """Emitters per outcome, keyed by ``FIXED_AP_REASONS``."""
        n = np.bincount(self.reason, minlength=len(FIXED_AP_REASONS))
        return {name: int(c) for name, c in zip(FIXED_AP_REASONS, n, strict=True)}


def identify_fixed_aps(
    emitter: ArrayLike,
    rssi_dbm: ArrayLike,
    t_ms: ArrayLike,
    xy_m: ArrayLike,
    *,
    n_emitters: int | None = None,
    params: FixedApParams | None = None,
) -> FixedAps:
    """Which emitters are fixed APs of this floor (IV-E1, module docstring).

    Parameters
    ----------
    emitter : array_like, shape (n,), int
        Emitter index of each reading, ``0 <= emitter < n_emitters``.
    rssi_dbm : array_like, shape (n,)
        RSS in dBm, finite.
    t_ms : array_like, shape (n,)
        Reading times, ms since the epoch.
    xy_m : array_like, shape (n, 2)
        Aligned position of each reading on this floor, metres; NaN rows for readings
        without one (open segments); they count for days and strength, not for the
        cluster.
    n_emitters : int, optional
        Number of emitters; ``max(emitter) + 1`` by default.
    params : FixedApParams, optional

    Returns
    -------
    FixedAps
    """
    params = params or FixedApParams()
    e = _ints("emitter", emitter)
    n = e.size
    r = _floats("rssi_dbm", rssi_dbm, n)
    t = _floats("t_ms", t_ms, n)
    xy = np.asarray(xy_m, dtype=np.float64)
    if xy.shape != (n, 2):
        raise ValueError(f"xy_m must have shape ({n}, 2), got {xy.shape}")
    if n_emitters is None:
        n_em = int(e.max()) + 1 if n else 0
    elif n_emitters < 0:
        raise ValueError(f"n_emitters must be >= 0, got {n_emitters}")
    else:
        n_em = n_emitters
    if n and (e.min() < 0 or e.max() >= n_em):
        raise ValueError(f"emitter must be in [0, {n_em}), got values in [{e.min()}, {e.max()}]")

    heard = np.bincount(e, minlength=n_em)
    day = np.floor((t + params.day_offset_ms) / DAY_MS).astype(np.int64)
    seen_days = np.unique(np.column_stack([e, day]), axis=0)
    n_days = np.bincount(seen_days[:, 0], minlength=n_em).astype(np.int64)
    max_rssi = np.full(n_em, -np.inf)
    np.maximum.at(max_rssi, e, r)
    max_rssi[heard == 0] = np.nan

    strong = np.flatnonzero((r > params.cluster_dbm) & np.all(np.isfinite(xy), axis=1))
    se, sp = e[strong], xy[strong]
    n_cluster = np.bincount(se, minlength=n_em).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid = np.column_stack(
            [np.bincount(se, weights=sp[:, d], minlength=n_em) / n_cluster for d in (0, 1)]
        ).reshape(n_em, 2)
        squares = np.bincount(se, weights=np.sum((sp - centroid[se]) ** 2, axis=1), minlength=n_em)
        area = 2.0 * np.pi * squares / n_cluster

    reason = np.full(n_em, FIXED, dtype=np.int8)
    rules = [
        (SPREAD, ~(area < params.max_area_m2)),
        (FEW_STRONG_POSITIONS, n_cluster < params.min_cluster_readings),
        (NOT_STRONG, ~(max_rssi > params.strong_dbm)),
        (FEW_DAYS, n_days < params.min_days),
        (NOT_HEARD, heard == 0),
    ]
    for code, failed in rules:  # the last rule written wins: the paper's first failing rule
        reason[failed] = code
    return FixedAps(
        fixed=np.asarray(reason == FIXED),
        reason=reason,
        n_days=n_days,
        max_rssi_dbm=max_rssi,
        n_cluster=n_cluster,
        centroid_xy_m=centroid,
        cluster_area_m2=area,
    )
