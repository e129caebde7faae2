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

from server.positioning.fingerprint import MISSING_DBM, RadioMap


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
    rssi = np.asarray(rssi_dbm, dtype=np.float64)
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

    heard = np.isfinite(rssi)
    value = np.where(heard, rssi, 0.0)
    count = np.zeros((n_rp, n_em), dtype=np.int64)
    total = np.zeros((n_rp, n_em), dtype=np.float64)
    np.add.at(count, inverse, heard.astype(np.int64))
    np.add.at(total, inverse, value)
    mean = np.divide(total, count, out=np.full_like(total, MISSING_DBM), where=count > 0)

    # two-pass variance: squared deviations from the cell mean
    deviation = np.where(heard, rssi - mean[inverse], 0.0)
    squares = np.zeros((n_rp, n_em), dtype=np.float64)
    np.add.at(squares, inverse, deviation**2)
    var = np.divide(
        squares, count - 1, out=np.full_like(squares, default_var_db2), where=count >= 2
    )
    var = np.where(count > 0, np.maximum(var, min_var_db2), 0.0)

    return RadioMap(
        rp_xy=rp_xy.astype(np.float32),
        rp_floor=keys[:, 0].astype(np.int32),
        mean_dbm=mean.astype(np.float32),
        var_db2=var.astype(np.float32),
        count=count.astype(np.int32),
        emitters=tuple(emitters),
    )
