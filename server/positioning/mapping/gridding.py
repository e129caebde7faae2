"""Gridding labelled fingerprints into a radio map.

Labelled points (a position, a floor and an RSS vector over the emitters, NaN where an
emitter was not heard) become reference points (RPs) of a ``RadioMap`` by these rules:

1. Cells. A point at ``(x, y)`` on floor ``f`` falls in the cell
   ``(f, floor(y / cell_m), floor(x / cell_m))`` (floor, cell row, cell column). All points
   of one cell become one RP, placed at the mean position of those points (not at the
   cell centre, so a sparse survey keeps its positions).
2. Order. RPs are sorted by (floor, cell row, cell column), so the map does not depend
   on the order in which points are given.
3. Statistics per RP and emitter, over the points of the cell that heard the emitter
   (``n`` of them):

   * ``count = n``;
   * ``mean_dbm`` = mean of the heard readings;
   * ``var_db2`` = unbiased sample variance ``sum (r - mean)^2 / (n - 1)`` when
     ``n >= 2``, else ``default_var_db2``; never below ``min_var_db2``;
   * when ``n = 0``: ``mean_dbm = MISSING_DBM``, ``var_db2 = 0``, ``count = 0``.
4. Columns. Every emitter given is kept as a column, even one heard nowhere; dropping
   columns is the caller's decision.

The means are the database fingerprints ``M_i`` that WKNN matches against
(``papers/002_*`` eq 1); variances and counts are kept for likelihood matching and map
quality.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap


def build_radio_map(
    xy_m: ArrayLike,
    floor: ArrayLike,
    rssi_dbm: ArrayLike,
    emitters: tuple[str, ...],
    cell_m: float = 1.0,
    default_var_db2: float = 16.0,
    min_var_db2: float = 1.0,
) -> RadioMap:
    """Grid labelled fingerprints into reference points (see the module docstring).

    Parameters
    ----------
    xy_m : array_like, shape (n, 2)
        Point positions in metres (x east, y north).
    floor : array_like, shape (n,), int
        Floor index of each point.
    rssi_dbm : array_like, shape (n, n_em)
        RSS in dBm; NaN where the emitter was not heard.
    emitters : tuple of str, length n_em
        Column keys, in the column order of ``rssi_dbm``.
    cell_m : float
        Cell side in metres.
    default_var_db2 : float
        Variance given to an RP x emitter heard by a single point.
    min_var_db2 : float
        Lower bound on every heard RP x emitter variance.

    Returns
    -------
    RadioMap
        ``n_rp`` RPs (the number of occupied cells) over the ``n_em`` emitters.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    fl = np.asarray(floor)
    rssi = np.asarray(rssi_dbm)
    if not np.issubdtype(rssi.dtype, np.floating):
        rssi = rssi.astype(np.float64)
    n_em = len(emitters)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy_m must have shape (n, 2), got {xy.shape}")
    n = xy.shape[0]
    if fl.shape != (n,):
        raise ValueError(f"floor must have shape ({n},), got {fl.shape}")
    if fl.size and not np.issubdtype(fl.dtype, np.integer):
        raise ValueError(f"floor must hold integers, got dtype {fl.dtype}")
    if rssi.shape != (n, n_em):
        raise ValueError(f"rssi_dbm must have shape ({n}, {n_em}), got {rssi.shape}")
    if not np.all(np.isfinite(xy)):
        raise ValueError("xy_m must be finite")
    if not cell_m > 0:
        raise ValueError(f"cell_m must be positive, got {cell_m}")

    cells = np.column_stack(
        [fl.astype(np.int64), np.floor(xy[:, 1] / cell_m), np.floor(xy[:, 0] / cell_m)]
    ).astype(np.int64)
    # np.unique sorts rows lexicographically: (floor, row, col) order, input order free
    keys, inverse = np.unique(cells.reshape(n, 3), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    n_rp = keys.shape[0]

    n_points = np.bincount(inverse, minlength=n_rp).astype(np.float64)
    rp_xy = np.column_stack(
        [np.bincount(inverse, weights=xy[:, d], minlength=n_rp) / n_points for d in (0, 1)]
    ).reshape(n_rp, 2)

    # statistics over the heard entries only (a scan hears a few dozen of thousands of
    # columns): no dense float64 temporaries of the whole (n, n_em) matrix
    point, column = np.nonzero(np.isfinite(rssi))
    value = rssi[point, column].astype(np.float64)
    entry, at = np.unique(inverse[point] * n_em + column, return_inverse=True)
    at = at.ravel()
    n_heard = np.bincount(at, minlength=entry.size).astype(np.float64)
    entry_mean = np.bincount(at, weights=value, minlength=entry.size).astype(np.float64) / n_heard
    # two-pass variance: squared deviations from the cell mean
    squares = np.bincount(at, weights=(value - entry_mean[at]) ** 2, minlength=entry.size)
    squares = squares.astype(np.float64)
    entry_var = np.divide(
        squares, n_heard - 1, out=np.full_like(squares, default_var_db2), where=n_heard >= 2
    )
    entry_var = np.maximum(entry_var, min_var_db2)

    count = np.zeros(n_rp * n_em, dtype=np.int32)
    mean = np.full(n_rp * n_em, MISSING_DBM, dtype=np.float32)
    var = np.zeros(n_rp * n_em, dtype=np.float32)
    count[entry] = n_heard
    mean[entry] = entry_mean
    var[entry] = entry_var

    return RadioMap(
        rp_xy=_inside_cells(rp_xy, keys, cell_m),
        rp_floor=keys[:, 0].astype(np.int32),
        mean_dbm=mean.reshape(n_rp, n_em),
        var_db2=var.reshape(n_rp, n_em),
        count=count.reshape(n_rp, n_em),
        emitters=tuple(emitters),
        rp_points=n_points.astype(np.int32),
    )


def _inside_cells(xy: np.ndarray, keys: np.ndarray, cell_m: float) -> np.ndarray:
    """RP positions as float32, kept inside their cells ``keys`` (floor, row, col): a mean
    just below a cell's upper edge could round onto the edge, i.e. into the next cell,
    where a later fold (which finds RPs' cells from their positions) would misplace it."""
    out = xy.astype(np.float32)
    for axis, col in ((0, 2), (1, 1)):
        lo = (keys[:, col] * cell_m).astype(np.float32)
        hi = np.nextafter(((keys[:, col] + 1) * cell_m).astype(np.float32), np.float32(-np.inf))
        out[:, axis] = np.clip(out[:, axis], lo, hi)
    return out


def fold_radio_maps(
    base: RadioMap,
    new: RadioMap,
    cell_m: float = 1.0,
    default_var_db2: float = 16.0,
    min_var_db2: float = 1.0,
) -> RadioMap:
    """Fold a newly gridded contribution into a map: the statistics of both point sets.

    Both maps must come from ``build_radio_map`` (or this function) with the same
    ``cell_m`` and floor indices, and carry ``rp_points``. RPs are matched by their cell
    ``(floor, floor(y / cell_m), floor(x / cell_m))`` (an RP's mean position lies in its
    cell); a cell of only one map is copied. Per RP: the position is the mean of both
    positions weighted by the points behind them. Per RP x emitter, with ``M2 = var (n - 1)``
    (0 when ``n < 2``), the pairwise update of Chan, Golub and LeVeque::

        n = n_a + n_b,  d = mean_b - mean_a,  mean = mean_a + d n_b / n,
        M2 = M2_a + M2_b + d^2 n_a n_b / n,  var = M2 / (n - 1)

    then the variance rules of ``build_radio_map`` (``default_var_db2`` for ``n = 1``, at
    least ``min_var_db2``). Counts and means equal those of gridding both point sets at
    once, whatever the order of the folds; a variance that was raised to ``min_var_db2``
    carries that floor into ``M2`` (slightly larger than the exact value). Columns are the
    base's emitters, then the new ones in the contribution's order.
    """
    if base.rp_points is None or new.rp_points is None:
        raise ValueError("both maps need rp_points (grid them with build_radio_map)")
    emitters = base.emitters + tuple(k for k in new.emitters if k not in set(base.emitters))
    col = {k: i for i, k in enumerate(emitters)}
    new_cols = np.fromiter((col[k] for k in new.emitters), dtype=np.int64, count=len(new.emitters))

    def cells(m: RadioMap) -> np.ndarray:
        xy = np.asarray(m.rp_xy, dtype=np.float64)
        return np.column_stack(
            [m.rp_floor.astype(np.int64), np.floor(xy[:, 1] / cell_m), np.floor(xy[:, 0] / cell_m)]
        ).astype(np.int64)

    n_a = base.rp_xy.shape[0]
    keys, inverse = np.unique(
        np.vstack([cells(base), cells(new)]).reshape(-1, 3), axis=0, return_inverse=True
    )
    inverse = inverse.ravel()
    rows_a, rows_b = inverse[:n_a], inverse[n_a:]
    n_rp, n_em = keys.shape[0], len(emitters)

    points = np.zeros(n_rp, dtype=np.int64)
    np.add.at(points, rows_a, base.rp_points)
    np.add.at(points, rows_b, new.rp_points)
    weighted = np.zeros((n_rp, 2))
    np.add.at(weighted, rows_a, base.rp_xy.astype(np.float64) * base.rp_points[:, None])
    np.add.at(weighted, rows_b, new.rp_xy.astype(np.float64) * new.rp_points[:, None])
    rp_xy = weighted / np.maximum(points, 1)[:, None]

    # the base, laid out on the union; then the contribution's RPs folded in
    count = np.zeros((n_rp, n_em), dtype=np.int64)
    mean = np.full((n_rp, n_em), MISSING_DBM, dtype=np.float64)
    var = np.zeros((n_rp, n_em), dtype=np.float64)
    count[rows_a, : len(base.emitters)] = base.count
    mean[rows_a, : len(base.emitters)] = base.mean_dbm
    var[rows_a, : len(base.emitters)] = base.var_db2

    grid_b = np.ix_(rows_b, new_cols)
    n1, m1, v1 = count[grid_b], mean[grid_b], var[grid_b]
    n2 = new.count.astype(np.int64)
    m2_, v2 = new.mean_dbm.astype(np.float64), new.var_db2.astype(np.float64)
    n = n1 + n2
    d = m2_ - m1
    with np.errstate(invalid="ignore", divide="ignore"):
        folded_mean = np.where(n1 == 0, m2_, np.where(n2 == 0, m1, m1 + d * n2 / np.maximum(n, 1)))
        ss = (
            np.where(n1 >= 2, v1 * (n1 - 1), 0.0)
            + np.where(n2 >= 2, v2 * (n2 - 1), 0.0)
            + np.where((n1 > 0) & (n2 > 0), d * d * n1 * n2 / np.maximum(n, 1), 0.0)
        )
        folded_var = np.where(n >= 2, ss / np.maximum(n - 1, 1), default_var_db2)
    folded_var = np.where(n > 0, np.maximum(folded_var, min_var_db2), 0.0)
    count[grid_b] = n
    mean[grid_b] = np.where(n > 0, folded_mean, MISSING_DBM)
    var[grid_b] = folded_var

    return RadioMap(
        rp_xy=_inside_cells(rp_xy, keys, cell_m),
        rp_floor=keys[:, 0].astype(np.int32),
        mean_dbm=mean.astype(np.float32),
        var_db2=var.astype(np.float32),
        count=count.astype(np.int32),
        emitters=emitters,
        rp_points=points.astype(np.int32),
    )
