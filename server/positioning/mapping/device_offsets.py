"""Per-device RSS offsets estimated from co-located readings, and their removal.

Phones of different models report the same signal a few dB apart (antenna, chipset,
firmware calibration, case); Li (``papers/000_*``, section I-B1) lists this *device
diversity* among the main causes of mismatch between a fingerprint database and live
scans, and Mansour (``papers/003_*``, section V-A) notes that offline databases built by
heterogeneous smartphones mismatch online scans. Here the mismatch is modelled as one
additive offset per device model.

Model. Reading ``i`` is the RSS in dBm that device ``d_i`` read from emitter ``e_i`` in
cell ``c_i`` (a small patch of floor where the field is taken as constant)::

    r_i = m(c_i, e_i) + o(d_i) + eps_i                                            (1)

with ``m`` the field of the (cell, emitter) pair ``p = (c, e)``, ``o`` the device offset
and ``eps`` noise. ``m + o`` is unchanged when a constant is added to every ``o`` and taken
from every ``m``, so one constraint fixes the level (2): either a ``reference`` device has
offset 0, or the offsets' mean weighted by each device's number of readings ``N_d`` is 0,
which keeps a map built from corrected readings at the level of the raw one::

    o(ref) = 0        or        sum_d N_d o(d) = 0                                (2)

Only pairs heard by at least two devices (*co-located pairs*) tell devices apart; a
device's offset is estimated from the ``n_d`` co-located pairs it heard.

Estimator: alternating medians over the pair x device table (a leave-one-out median
polish, after Tukey, *Exploratory Data Analysis*, 1977, ch. 11). The readings of one
device on one pair are first reduced to their median ``y_pd`` (a device that stood long in
one place gets one vote there, and single outlying readings drop out). Then, starting from
``o = 0``, until no offset moves by ``TOL_DB`` or more (at most ``MAX_ITER`` rounds)::

    m_p^(-d) <- median over the other devices d' on p of  (y_pd' - o_d')          (3)
    o_d      <- (o_d + median over the co-located pairs p of d of
                       (y_pd - m_p^(-d))) / 2                                     (4)
    o        <- o - o(ref)   or   o - sum_d N_d o_d / sum_d N_d                   (5)

``m_p^(-d)`` is the pair's field as the *other* devices see it. Leaving ``d`` out matters:
with its own value inside the median, a device that is the middle one on a pair has
residual exactly 0 there, the residuals of (4) get an atom at 0, and every offset close to
the start becomes a fixed point (on the synthetic field of the tests the plain polish
stopped 0.7 dB short of a 6 dB offset, ten standard errors). The step of (4) is halved
because the undamped update overshoots: with two devices it flips their difference
between 0 and twice the right value forever, and on UJIIndoorLoc it kept swinging by
0.56 dB after 100 rounds; halved, it settles (55 rounds there). The fixed point is the
same: for two devices ``o_a - o_b = median_p (y_pa - y_pb)``, the median of their
differences.

Why medians and not least squares: multipath, a body in the way or a mislabelled position
give readings tens of dB off (the gross errors Mansour removes by IQR, section IV-D); a
median's breakdown point is 50 % where a mean's is 0. It needs no scale constant (a Huber
or soft-L1 loss of ``scipy.optimize.least_squares`` does, and one unknown per pair), only
sorts, and ``numpy`` alone.

Uncertainty. With the fitted offsets the residuals are
``u_pd = y_pd - m_p^(-d) - o_d``; they carry the device's noise and the noise of the other
devices' field estimate. A device's spread and the standard uncertainty of its offset::

    sigma_d = 1.4826 * median_p |u_pd|                                            (6)
    std_d   = sqrt(pi / 2) * sigma_d / sqrt(n_d)                                  (7)

(1.4826 turns a median absolute deviation into a Gaussian standard deviation; ``sqrt(pi /
2)`` is the large-sample efficiency loss of a median against a mean). It is the
uncertainty of ``o_d`` against the other devices' level. For two devices it is exactly
that of their difference, so it overstates each one's under the weighted-mean constraint
(twice, for equal weights). On the three-device field of the tests (200 repetitions, 40
cells x 8 emitters, 3 dB noise) it came out 0.39 dB against a scatter of the estimates of
0.40-0.43 dB under the weighted-mean constraint and 0.44 dB against a reference device:
about right, 12 % low against a reference.

Quality control and scope:

* Readings below ``min_rssi_dbm`` are dropped first (Mansour's -90 dBm rule, section
  IV-D): weak readings are the noisiest, and near a phone's sensitivity they are censored
  differently per phone. The cut still censors: on a pair whose field is near it, a
  device that reads low loses more readings than one that reads high, which pulls their
  offsets slightly together; pairs well above the cut are unaffected.
* A device on fewer than ``min_pairs`` co-located pairs gets no offset; it is left out
  and the count is redone without it until every device kept has enough pairs.
* Offsets compare only devices linked by chains of co-located pairs. When the kept
  devices fall into several such groups, only one is estimated: the reference's, or by
  default the one with most readings. The others get no offset.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

MAX_ITER = 500  # rounds of (3)-(5) at most; UJIIndoorLoc's 15 phones settle in 55
TOL_DB = 1e-4  # stop when no offset moved more than this in a round
MAD_TO_SIGMA = 1.4826  # eq 6: Gaussian sigma from a median absolute deviation
MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2.0)  # eq 7: std of a median / std of a mean


@dataclass(frozen=True)
class DeviceOffset:
    """One device model's offset: what it reads above the common level (eq 1-2)."""

    offset_db: float  # o(d), eq 4-5; subtract it from the device's readings
    n_pairs: int  # n_d: co-located (cell, emitter) pairs the estimate rests on
    std_db: float  # standard uncertainty of offset_db, eq 6-7


def estimate_offsets(
    cell: ArrayLike,
    emitter: ArrayLike,
    rssi_dbm: ArrayLike,
    device: ArrayLike | Sequence[str],
    *,
    reference: str | None = None,
    min_pairs: int = 20,
    min_rssi_dbm: float = -90.0,
) -> dict[str, DeviceOffset]:
    """Per-device RSS offsets by a leave-one-out median polish over co-located readings.

    Parameters
    ----------
    cell : array_like, shape (n,), int
        Cell id of each reading (any integer labels; readings with the same cell id are
        taken as co-located).
    emitter : array_like, shape (n,), int
        Emitter id of each reading.
    rssi_dbm : array_like, shape (n,)
        RSS in dBm. NaN readings (not heard) and readings below ``min_rssi_dbm`` are
        ignored.
    device : array_like of str, shape (n,)
        Device model of each reading.
    reference : str, optional
        Device whose offset is 0 (eq 2, left); by default the offsets' reading-weighted
        mean is 0 (eq 2, right).
    min_pairs : int
        Co-located pairs a device needs to get an offset.
    min_rssi_dbm : float
        Weakest reading used.

    Returns
    -------
    dict of str to DeviceOffset
        By device model, for the devices that could be estimated; others are absent.

    Raises
    ------
    ValueError
        Naming the argument: shapes differ, ids are not integers, ``min_pairs < 1``,
        ``min_rssi_dbm`` is NaN, or ``reference`` cannot be estimated (unknown, too few
        co-located pairs).
    """
    c = _labels("cell", cell)
    n = c.size
    e = _labels("emitter", emitter, n)
    r = np.asarray(rssi_dbm, dtype=np.float64)
    if r.shape != (n,):
        raise ValueError(f"rssi_dbm must have shape ({n},), got {r.shape}")
    dev = np.asarray(device).astype(str)
    if dev.shape != (n,):
        raise ValueError(f"device must have shape ({n},), got {dev.shape}")
    if isinstance(min_pairs, bool) or not isinstance(min_pairs, int | np.integer):
        raise ValueError(f"min_pairs must be an integer, got {min_pairs!r}")
    if min_pairs < 1:
        raise ValueError(f"min_pairs must be at least 1, got {min_pairs}")
    if math.isnan(min_rssi_dbm):
        raise ValueError("min_rssi_dbm must not be NaN")
    if reference is not None and not isinstance(reference, str):
        raise ValueError(f"reference must be a device model string, got {reference!r}")

    keep = np.isfinite(r) & (r >= min_rssi_dbm)
    names, d = np.unique(dev[keep], return_inverse=True)
    d = d.astype(np.int64)
    r = r[keep]
    if reference is not None and reference not in set(names.tolist()):
        raise ValueError(f"reference {reference!r} has no reading at or above min_rssi_dbm")
    n_dev = names.size
    if n_dev == 0:
        return {}
    readings = np.bincount(d, minlength=n_dev).astype(np.float64)  # N_d of eq 2

    # y_pd: the median of device d's readings on pair p
    _, pair = np.unique(np.column_stack([c[keep], e[keep]]), axis=0, return_inverse=True)
    entry, where = np.unique(pair.reshape(-1) * n_dev + d, return_inverse=True)
    y = _group_median(where.reshape(-1), r, entry.size)
    entry_pair, entry_dev = entry // n_dev, entry % n_dev

    kept = _enough_pairs(entry_pair, entry_dev, n_dev, min_pairs)
    kept &= _component(entry_pair, entry_dev, kept, readings, names, reference)
    if reference is not None and not kept[np.searchsorted(names, reference)]:
        raise ValueError(
            f"reference {reference!r} has fewer than min_pairs={min_pairs} co-located pairs"
        )
    if not kept.any():
        return {}
    on = kept[entry_dev] & _colocated(entry_pair, entry_dev, kept)
    _, p = np.unique(entry_pair[on], return_inverse=True)
    p = p.reshape(-1)
    dv, y = entry_dev[on], y[on]
    n_p = int(p.max()) + 1
    w = np.where(kept, readings, 0.0)
    ref = None if reference is None else int(np.searchsorted(names, reference))

    o = np.zeros(n_dev)
    for _ in range(MAX_ITER):
        m = _leave_one_out_median(p, y - o[dv], n_p)  # eq 3, per entry
        new = np.where(kept, 0.5 * (o + _group_median(dv, y - m, n_dev)), 0.0)  # eq 4, damped
        new -= new[ref] if ref is not None else np.dot(w, new) / w.sum()  # eq 5
        new = np.where(kept, new, 0.0)
        moved = float(np.max(np.abs(new - o)))
        o = new
        if moved < TOL_DB:
            break

    u = np.abs(y - _leave_one_out_median(p, y - o[dv], n_p) - o[dv])
    sigma = MAD_TO_SIGMA * _group_median(dv, u, n_dev)  # eq 6
    n_pairs = np.bincount(dv, minlength=n_dev)
    std = MEDIAN_EFFICIENCY * sigma / np.sqrt(np.maximum(n_pairs, 1))  # eq 7
    return {
        str(names[i]): DeviceOffset(float(o[i]), int(n_pairs[i]), float(std[i]))
        for i in np.flatnonzero(kept).tolist()
    }


def apply_offsets(rssi_dbm: ArrayLike, offset_db: ArrayLike) -> NDArray[np.floating]:
    """Readings with the device offset taken off: ``r - o(d)`` (eq 1).

    Parameters
    ----------
    rssi_dbm : array_like, any shape
        RSS in dBm; NaN (not heard) stays NaN.
    offset_db : array_like, broadcastable to ``rssi_dbm``
        Offset of the device behind each reading, e.g. shape (n, 1) for a matrix of
        ``n`` scans by emitters. NaN means no estimate: those readings are left as they are.

    Returns
    -------
    ndarray
        Same shape and memory layout as ``rssi_dbm``; same dtype when it is a float type,
        else float64.

    Raises
    ------
    ValueError
        When ``offset_db`` does not broadcast to the shape of ``rssi_dbm``.
    """
    r = np.asarray(rssi_dbm)
    dtype = r.dtype if np.issubdtype(r.dtype, np.floating) else np.dtype(np.float64)
    o = np.asarray(offset_db, dtype=np.float64)
    try:
        o = np.broadcast_to(o, r.shape)
    except ValueError:
        raise ValueError(
            f"offset_db of shape {o.shape} does not broadcast to rssi_dbm's {r.shape}"
        ) from None
    # the layout of rssi_dbm is kept: column gathers of a map are fast on Fortran order
    corrected: NDArray[np.floating] = np.empty_like(r, dtype=dtype)
    np.subtract(r, np.nan_to_num(o, nan=0.0), out=corrected, casting="same_kind")
    return corrected


def cell_ids(xy_m: ArrayLike, group: ArrayLike, cell_m: float) -> IntArray:
    """Cell id of each position: square cells of side ``cell_m`` per group (e.g. floor).

    Parameters
    ----------
    xy_m : array_like, shape (n, 2)
        Positions in metres.
    group : array_like, shape (n,) or (n, g), int
        Labels that must match too for two positions to share a cell, e.g. building and
        floor as two columns.
    cell_m : float
        Cell side, > 0.

    Returns
    -------
    ndarray, shape (n,), int64
        Ids ``0..n_cells - 1``, ordered by (group, floor(x / cell_m), floor(y / cell_m)).
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy_m must have shape (n, 2), got {xy.shape}")
    n = xy.shape[0]
    g = np.asarray(group)
    g = g.reshape(n, -1) if g.ndim == 1 and g.shape == (n,) else g
    if g.ndim != 2 or g.shape[0] != n or not np.issubdtype(g.dtype, np.integer):
        raise ValueError(f"group must hold integers of shape ({n},) or ({n}, g), got {g.shape}")
    if not cell_m > 0:
        raise ValueError(f"cell_m must be positive, got {cell_m}")
    if not np.isfinite(xy).all():
        raise ValueError("xy_m must be finite")
    key = np.column_stack([g.astype(np.int64), np.floor(xy / cell_m).astype(np.int64)])
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    _, ids = np.unique(key, axis=0, return_inverse=True)
    return ids.reshape(-1).astype(np.int64)


def scan_readings(
    rssi_dbm: ArrayLike, cell: ArrayLike, device: ArrayLike | Sequence[str]
) -> tuple[IntArray, IntArray, FloatArray, NDArray[np.str_]]:
    """The heard entries of a scans x emitters matrix as the readings of ``estimate_offsets``.

    Parameters
    ----------
    rssi_dbm : array_like, shape (n, n_em)
        RSS in dBm, NaN where not heard.
    cell : array_like, shape (n,), int
        Cell id of each scan.
    device : array_like of str, shape (n,)
        Device model of each scan.

    Returns
    -------
    cell, emitter, rssi_dbm, device : ndarray, shape (n_heard,)
        One entry per heard (scan, emitter); ``emitter`` is the column index.
    """
    R = np.asarray(rssi_dbm, dtype=np.float64)
    if R.ndim != 2:
        raise ValueError(f"rssi_dbm must have shape (n, n_em), got {R.shape}")
    c = _labels("cell", cell, R.shape[0])
    dev = np.asarray(device).astype(str)
    if dev.shape != (R.shape[0],):
        raise ValueError(f"device must have shape ({R.shape[0]},), got {dev.shape}")
    row, col = np.nonzero(~np.isnan(R))
    return c[row], col.astype(np.int64), R[row, col], dev[row]


def row_offsets(
    device: ArrayLike | Sequence[str], offsets: Mapping[str, DeviceOffset]
) -> FloatArray:
    """The offset of each row's device, NaN where the device has none (for ``apply_offsets``).

    Parameters
    ----------
    device : array_like of str, shape (n,)
        Device model of each scan.
    offsets : mapping of str to DeviceOffset
        From ``estimate_offsets``.

    Returns
    -------
    ndarray, shape (n,), float64
    """
    dev = np.asarray(device).astype(str).reshape(-1)
    return np.array(
        [offsets[name].offset_db if name in offsets else np.nan for name in dev.tolist()],
        dtype=np.float64,
    )


def _labels(name: str, value: ArrayLike, n: int | None = None) -> IntArray:
    a = np.asarray(value)
    if a.ndim != 1 or (n is not None and a.shape != (n,)):
        expected = "(n,)" if n is None else f"({n},)"
        raise ValueError(f"{name} must have shape {expected}, got {a.shape}")
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"{name} must hold integers, got dtype {a.dtype}")
    return a.astype(np.int64)


def _group_median(group: IntArray, values: FloatArray, n_groups: int) -> FloatArray:
    """Median of ``values`` per group label ``0..n_groups - 1`` (NaN for an empty group)."""
    order = np.lexsort((values, group))
    v = values[order]
    counts = np.bincount(group, minlength=n_groups)
    start = np.cumsum(counts) - counts
    out = np.full(n_groups, np.nan)
    has = counts > 0
    lo = start[has] + (counts[has] - 1) // 2
    hi = start[has] + counts[has] // 2
    out[has] = 0.5 * (v[lo] + v[hi])
    return out


def _leave_one_out_median(group: IntArray, values: FloatArray, n_groups: int) -> FloatArray:
    """Per element, the median of the *other* elements of its group (each group >= 2)."""
    order = np.lexsort((values, group))
    v, g = values[order], group[order]
    counts = np.bincount(group, minlength=n_groups)
    start = (np.cumsum(counts) - counts)[g]
    k = counts[g]
    rank = np.arange(g.size) - start  # of each sorted element within its group
    # positions lo, hi of the median among the k - 1 others, mapped past the left-out one
    lo = (k - 2) // 2
    hi = (k - 1) // 2
    lo = lo + (lo >= rank)
    hi = hi + (hi >= rank)
    out = np.empty_like(values)
    out[order] = 0.5 * (v[start + lo] + v[start + hi])
    return out


def _colocated(
    entry_pair: IntArray, entry_dev: IntArray, kept: NDArray[np.bool_]
) -> NDArray[np.bool_]:
    """Per (pair, device) entry: its pair is heard by two or more kept devices."""
    on = kept[entry_dev]
    devices_on_pair = np.bincount(entry_pair[on], minlength=int(entry_pair.max(initial=-1)) + 1)
    return devices_on_pair[entry_pair] >= 2


def _enough_pairs(
    entry_pair: IntArray, entry_dev: IntArray, n_dev: int, min_pairs: int
) -> NDArray[np.bool_]:
    """Devices with at least ``min_pairs`` co-located pairs among the devices kept; dropping
    one can leave others short, so repeat until nothing changes."""
    kept = np.ones(n_dev, dtype=bool)
    while True:
        on = kept[entry_dev] & _colocated(entry_pair, entry_dev, kept)
        now = kept & (np.bincount(entry_dev[on], minlength=n_dev) >= min_pairs)
        if (now == kept).all():
            return kept
        kept = now


def _component(
    entry_pair: IntArray,
    entry_dev: IntArray,
    kept: NDArray[np.bool_],
    readings: FloatArray,
    names: NDArray[np.str_],
    reference: str | None,
) -> NDArray[np.bool_]:
    """The kept devices linked to the reference (or, without one, to the group with most
    readings) by chains of co-located pairs."""
    n_dev = kept.size
    parent = list(range(n_dev))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    on = kept[entry_dev] & _colocated(entry_pair, entry_dev, kept)
    pair, dev = entry_pair[on], entry_dev[on]
    if pair.size:
        order = np.lexsort((dev, pair))
        pair, dev = pair[order], dev[order]
        first = dev[np.searchsorted(pair, pair)]  # the first device on each entry's pair
        for a, b in set(zip(first.tolist(), dev.tolist(), strict=True)):
            parent[root(a)] = root(b)
    roots = np.array([root(i) for i in range(n_dev)], dtype=np.int64)
    if reference is not None:
        chosen = int(roots[np.searchsorted(names, reference)])
    else:
        size = np.bincount(roots, weights=np.where(kept, readings, 0.0), minlength=n_dev)
        chosen = int(np.argmax(size))
    linked: NDArray[np.bool_] = kept & (roots == chosen)
    return linked
