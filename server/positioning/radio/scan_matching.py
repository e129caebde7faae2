"""Matching a scan against the map's own scans: the radio evidence every engine reads.

The map (``ScanMap``) keeps the surveyed scans themselves, each at the position it was
taken, instead of averaging them into cells: a cell's mean mixes readings of several
walks, phone holds and moments, while a raw scan is one consistent picture. A query scan
is compared with every reference scan that shares an emitter with it:

* **distance** over the emitters both heard, plus a penalty for those only one of them
  heard (no "missing = -100 dBm" fill, which makes the distance a count of emitters)::

      d_i = sum_j w_ij |q_j - r_ij| / sum_j w_ij  +  C (1 - s_i)^2

  with ``s_i`` the weighted share of the two scans' emitters that both heard (a Dice
  coefficient: twice the shared weight over the two scans' total weight);
* **weights** ``w_ij = a_j f(q_j) f(r_ij)``: ``a_j = n_walks(j)^-1/2`` makes an emitter
  heard on few walks (a local one) count more than one heard everywhere; ``f`` discounts a
  reading by its age (a phone's scan lists cached results, seconds old, beside fresh
  ones; Android's ``ScanResult.timestamp`` and iOS' beacon ranging give the age):
  ``f = decay ** max(age_s - 1, 0)``;
* **position**: the ``k`` nearest reference scans weighted by ``1 / d^power``, of any
  floor (``same_floor`` off): the floors of a building share their footprint, and
  where the survey of the phone's own floor does not reach its place (the IPIN logs
  with one trial left out) the scans taken above or below it are nearer than any of
  its floor's: this was better on both development venues;
* **floor**: per floor a Gaussian likelihood of the scan given its nearest reference
  scans (``floor_scores``), where a reference that did not hear an emitter counts it at
  ``MISSING_DBM``: that the phone's strongest access points were not heard at all is
  what tells floors apart where they hear the same ones. The floor filter
  (``floor_hmm``) then makes the floor sticky over time. A vote of the scan's
  strongest emitters for the floor where the map heard each loudest, added to this
  likelihood or to one from the shared-emitter distances, was tried and dropped: it
  lowered the floor hit on both venues' validation splits (``bench/accuracy.md``).

Emitters heard fewer than ``MIN_READINGS`` times in the map (and in fewer than 1 % of its
scans) are dropped: a passing phone hotspot, a neighbour's access point seen once. The
parameters' defaults were chosen on the inner validation splits of both development
venues (``bench/accuracy.md``).

Reading ages are optional everywhere: a scan without them counts every reading as fresh.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.events import RadioReading, radio_key
from server.positioning.radio.fingerprints import MISSING_DBM, WknnFix
from server.positioning.radio.floor_hmm import logsumexp

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

MIN_READINGS = 10
"""Emitters the map heard fewer times than this are dropped, unless that is more than
``RARE_SHARE`` of its scans (a small survey keeps what it heard)."""
RARE_SHARE = 0.01
RARITY_EXPONENT = 0.5
"""An emitter's weight is (walks that heard it)^-RARITY_EXPONENT."""
FRESH_S = 1.0
"""Readings up to this age count in full."""

KeyedReading = tuple[str, float]  # (column key "wifi:<bssid>" | "ble:<id>", rssi_dbm)


@dataclass(frozen=True)
class MatchParams:
    """How scans are compared, weighted and voted on (module docstring)."""

    k: int = 10
    power: float = 8.0
    penalty_db: float = 60.0
    decay_per_s: float = 0.88
    same_floor: bool = False  # place the scan by reference scans of its floor only
    floor_k: int = 4  # nearest reference scans per floor in its likelihood
    floor_sd_db: float = 32.0  # RSS error per emitter in the floor likelihood
    floor_max_emitters: int = 5  # emitters counted as independent in it, at most


@dataclass(frozen=True, eq=False)
class ScanMap:
    """Reference scans and, per emitter column, the scans that heard it (sparse by column).

    Attributes
    ----------
    xy_m : ndarray, shape (n, 2)
    floor : ndarray, shape (n,), int
    emitters : tuple of str
        Column keys (``"wifi:<bssid>"``, ``"ble:<id>"``), sorted.
    indptr : ndarray, shape (n_em + 1,), int
        Column ``j``'s entries are ``[indptr[j], indptr[j + 1])`` of the arrays below.
    rows : ndarray, shape (nnz,), int32
        Reference scan of each entry.
    rssi_dbm : ndarray, shape (nnz,), float32
    fresh : ndarray, shape (nnz,), float32
        Age weight ``f`` of each reading (1 without an age).
    rarity : ndarray, shape (n_em,)
        ``a_j``.
    totals : ndarray, shape (n,)
        ``sum_j a_j f(r_ij)`` over each reference scan's emitters (the Dice denominator's
        reference part).
    decay_per_s : float
        The age decay ``fresh`` was computed with.
    """

    xy_m: FloatArray
    floor: IntArray
    emitters: tuple[str, ...]
    indptr: IntArray
    rows: NDArray[np.int32]
    rssi_dbm: NDArray[np.float32]
    fresh: NDArray[np.float32]
    rarity: FloatArray
    totals: FloatArray
    decay_per_s: float
    column: dict[str, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "column", {key: j for j, key in enumerate(self.emitters)})

    @property
    def n_floors(self) -> int:
        return int(self.floor.max(initial=-1)) + 1

    def __len__(self) -> int:
        return int(self.floor.shape[0])


def age_weight(age_ms: FloatArray, decay_per_s: float) -> FloatArray:
    """``f``: 1 up to ``FRESH_S``, then ``decay_per_s`` per further second."""
    over: FloatArray = np.maximum(np.nan_to_num(age_ms, nan=0.0) / 1000.0 - FRESH_S, 0.0)
    return np.power(decay_per_s, over)


def build_scan_map(
    xy_m: FloatArray,
    floor: IntArray,
    readings: Sequence[Sequence[KeyedReading]],
    *,
    ages_ms: Sequence[Sequence[float | None]] | None = None,
    walk: IntArray | None = None,
    decay_per_s: float = MatchParams.decay_per_s,
    min_readings: int = MIN_READINGS,
) -> ScanMap:
    """The map of reference scans.

    Parameters
    ----------
    xy_m, floor : ndarray
        Position and floor index of each scan.
    readings : sequence of n sequences of (column key, rssi_dbm)
        An emitter listed twice in a scan keeps its strongest reading; readings at or
        below ``MISSING_DBM`` say no more than "not heard" and are left out.
    ages_ms : sequence of n sequences of float or None, optional
        Each reading's age (parallel to ``readings``); None or missing: fresh.
    walk : ndarray, shape (n,), int, optional
        The walk of each scan (-1: on its own) for the rarity weights; every scan its own
        walk when None.
    """
    n = len(readings)
    keys: list[str] = []
    row_of: list[int] = []
    values: list[float] = []
    ages: list[float] = []
    for i, scan in enumerate(readings):
        scan_ages = ages_ms[i] if ages_ms is not None and i < len(ages_ms) else ()
        for r, (key, value) in enumerate(scan):
            if value > MISSING_DBM and math.isfinite(value):
                keys.append(key)
                row_of.append(i)
                values.append(value)
                known = scan_ages[r] if r < len(scan_ages) else None
                ages.append(math.nan if known is None else float(known))
    names, col = np.unique(np.array(keys, dtype=object), return_inverse=True)
    col = col.astype(np.int64).reshape(-1)
    rows = np.asarray(row_of, dtype=np.int64)
    rssi = np.asarray(values, dtype=np.float64)
    age = np.asarray(ages, dtype=np.float64)
    # one entry per (scan, emitter): the strongest
    order = np.lexsort((-rssi, rows, col))
    col, rows, rssi, age = col[order], rows[order], rssi[order], age[order]
    first = np.r_[True, (col[1:] != col[:-1]) | (rows[1:] != rows[:-1])] if col.size else col
    col, rows, rssi, age = col[first], rows[first], rssi[first], age[first]
    # emitters heard too rarely are dropped
    counts = np.bincount(col, minlength=names.size)
    keep_col = counts >= min(min_readings, math.ceil(RARE_SHARE * n))
    keep = keep_col[col]
    new_index = np.cumsum(keep_col) - 1
    col, rows, rssi, age = new_index[col[keep]], rows[keep], rssi[keep], age[keep]
    names = names[keep_col]
    n_em = names.size
    floors = np.asarray(floor, dtype=np.int64).reshape(-1)
    # walks per emitter: distinct (emitter, walk) pairs, a scan outside any walk alone
    walks = np.asarray(walk, dtype=np.int64) if walk is not None else np.full(n, -1)
    group = np.where(walks[rows] >= 0, walks[rows], -1 - rows)
    pairs = np.unique(np.stack([col, group]), axis=1) if col.size else np.zeros((2, 0), int)
    n_walks = np.bincount(pairs[0], minlength=n_em).astype(np.float64)
    rarity = np.maximum(n_walks, 1.0) ** -RARITY_EXPONENT
    fresh = age_weight(age, decay_per_s)
    totals = np.bincount(rows, weights=rarity[col] * fresh, minlength=n).astype(np.float64)
    indptr = np.r_[0, np.cumsum(np.bincount(col, minlength=n_em))].astype(np.int64)
    return ScanMap(
        xy_m=np.asarray(xy_m, dtype=np.float64).reshape(-1, 2),
        floor=floors,
        emitters=tuple(str(s) for s in names.tolist()),
        indptr=indptr,
        rows=rows.astype(np.int32),
        rssi_dbm=rssi.astype(np.float32),
        fresh=fresh.astype(np.float32),
        rarity=rarity,
        totals=totals,
        decay_per_s=decay_per_s,
    )


@dataclass(frozen=True)
class Query:
    """A scan laid over a scan map: its columns, RSS and age weights."""

    cols: IntArray
    rssi_dbm: FloatArray
    fresh: FloatArray

    @property
    def n_matched(self) -> int:
        return int(self.cols.size)


def query(smap: ScanMap, readings: Sequence[RadioReading], kind: str) -> Query:
    """The readings of a scan of ``kind`` that the map knows, strongest per emitter."""
    best: dict[int, tuple[float, float]] = {}
    for r in readings:
        j = smap.column.get(radio_key(kind, r.emitter))
        if j is None or not (math.isfinite(r.rssi_dbm) and r.rssi_dbm > MISSING_DBM):
            continue
        if j not in best or r.rssi_dbm > best[j][0]:
            best[j] = (r.rssi_dbm, math.nan if r.age_ms is None else float(r.age_ms))
    cols = np.fromiter(best, dtype=np.int64, count=len(best))
    rssi = np.array([v[0] for v in best.values()], dtype=np.float64)
    ages = np.array([v[1] for v in best.values()], dtype=np.float64)
    return Query(cols, rssi, age_weight(ages, smap.decay_per_s))


def _entries(starts: IntArray, ends: IntArray) -> tuple[IntArray, IntArray]:
    """The entries of the columns ``[starts, ends)`` one after another, and the column
    (position in ``starts``) of each."""
    lengths = ends - starts
    total = int(lengths.sum())
    offsets = np.repeat(starts - np.r_[0, np.cumsum(lengths)[:-1]], lengths)
    return offsets + np.arange(total), np.repeat(np.arange(starts.size), lengths)


def distances(smap: ScanMap, q: Query, penalty_db: float) -> tuple[IntArray, FloatArray]:
    """The reference scans sharing an emitter with the query and their distances ``d_i``."""
    entry, which = _entries(smap.indptr[q.cols], smap.indptr[q.cols + 1])
    if entry.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    rows = smap.rows[entry]
    a = smap.rarity[q.cols][which]
    fq = q.fresh[which]
    fr = smap.fresh[entry].astype(np.float64)
    w = a * fq * fr
    diff = np.abs(q.rssi_dbm[which] - smap.rssi_dbm[entry])
    n = len(smap)
    shared_w = np.bincount(rows, weights=w, minlength=n)
    diff_w = np.bincount(rows, weights=w * diff, minlength=n)
    dice = np.bincount(rows, weights=a * (fq + fr), minlength=n)
    cand = np.flatnonzero(shared_w > 0)
    total_q = float(np.sum(smap.rarity[q.cols] * q.fresh))
    share = dice[cand] / (total_q + smap.totals[cand])
    d = diff_w[cand] / shared_w[cand] + penalty_db * (1.0 - np.minimum(share, 1.0)) ** 2
    return cand, d


def _k_nearest(d: FloatArray, k: int) -> IntArray:
    """Positions of the ``k`` smallest values, nearest first (ties by position)."""
    part = np.argpartition(d, k - 1)[:k] if k < d.size else np.arange(d.size)
    return part[np.lexsort((part, d[part]))].astype(np.int64)


def floor_scores(smap: ScanMap, q: Query, params: MatchParams, n_floors: int) -> FloatArray:
    """Log-likelihood of each floor from the scan alone (module docstring), the best at
    0; ``-inf`` for floors the map has no reference scan on.

    Per floor, the mean squared RSS difference ``m_f`` of the scan to its
    ``floor_k`` nearest reference scans, per query emitter, an emitter the reference did
    not hear counting as ``MISSING_DBM`` (and a floor's scans that heard none of the
    phone's emitters making up its ``floor_k`` where fewer heard any); the
    log-likelihood is ``-n m_f / (2 sd^2)`` with ``n`` the query's emitters capped at
    ``floor_max_emitters`` (readings of nearby emitters share their errors). Unlike the
    distance that places the scan, this one holds the "missing" fill: that a reference
    did not hear the phone's strongest access point at all is what tells two floors
    apart where they hear the same ones.
    """
    starts, ends = smap.indptr[q.cols], smap.indptr[q.cols + 1]
    entry, which = _entries(starts, ends)
    rows = smap.rows[entry]
    n = len(smap)
    fill = (q.rssi_dbm - MISSING_DBM) ** 2
    diff = (q.rssi_dbm[which] - smap.rssi_dbm[entry]) ** 2 - fill[which]
    heard = np.bincount(rows, minlength=n) > 0
    cand = np.flatnonzero(heard)
    squared = np.bincount(rows, weights=diff, minlength=n)[cand] + float(fill.sum())
    per_emitter = max(q.n_matched, 1)
    msd = np.full(n_floors, float(fill.sum()) / per_emitter)  # no reference hears any
    on = smap.floor[cand]
    on_map = np.bincount(smap.floor, minlength=n_floors)
    for f in np.unique(on).tolist():
        if 0 <= f < n_floors:
            here = squared[on == f]
            nearest = here[_k_nearest(here, params.floor_k)]
            # a floor whose other scans heard none of the phone's emitters: as far as that
            missing = min(params.floor_k, int(on_map[f])) - nearest.size
            total = float(nearest.sum()) + missing * float(fill.sum())
            msd[f] = total / (nearest.size + missing) / per_emitter
    mapped = on_map[:n_floors] > 0
    m = min(q.n_matched, params.floor_max_emitters)
    score = np.where(mapped, -m * msd / (2.0 * params.floor_sd_db**2), -np.inf)
    return score - float(score.max())


def locate(
    smap: ScanMap,
    q: Query,
    params: MatchParams,
    floor_log_prior: FloatArray | None = None,
    n_floors: int | None = None,
    candidates: NDArray[np.bool_] | None = None,
    penalty_db: FloatArray | None = None,
    floor_group: IntArray | None = None,
) -> WknnFix | None:
    """Position and floor of a query scan (module docstring); None when no reference scan
    shares an emitter with it.

    ``floor_log_prior`` (the floor filter's prediction) is added to the scan's floor
    scores; ``floor_logp`` of the answer is the normalised result. ``candidates`` (a
    mask over the reference scans) keeps only some of them, ``penalty_db`` (per
    reference scan) is added to their distances: the floor is then still scored on every
    reference scan, the position only on those kept. ``floor_group`` (per floor index,
    e.g. its building) keeps the position's neighbours on floors of the chosen floor's
    group when they may come from any floor: buildings have frames of their own. ``neighbours`` are
    reference scan indices, ``distances_db`` their ``d_i``, ``var_m2`` the weighted
    spread of the neighbours about the fix.
    """
    if q.cols.size == 0:
        return None
    cand, d = distances(smap, q, params.penalty_db)
    if candidates is not None:
        kept = candidates[cand]
        cand, d = cand[kept], d[kept]
    if penalty_db is not None:
        d = d + penalty_db[cand]
    if cand.size == 0:
        return None
    n = max(n_floors or 0, smap.n_floors)
    if floor_log_prior is not None and floor_log_prior.shape[0] > n:
        n = floor_log_prior.shape[0]
    score = floor_scores(smap, q, params, n)
    logp = score.copy()
    if floor_log_prior is not None and floor_log_prior.shape[0] == n:
        logp = logp + floor_log_prior
        if not np.isfinite(logp).any():
            logp = score.copy()
    logp -= float(logsumexp(logp))
    on = smap.floor[cand]
    matched = np.isin(np.arange(n), on)
    floor = int(np.argmax(np.where(matched, logp, -np.inf)))
    if params.same_floor:
        here = np.flatnonzero(on == floor)
    elif floor_group is not None and floor < floor_group.shape[0]:
        group = np.asarray(floor_group)
        here = np.flatnonzero(group[np.clip(on, 0, group.shape[0] - 1)] == group[floor])
    else:
        here = np.arange(cand.size)
    sel = here[_k_nearest(d[here], params.k)]
    inv = np.maximum(d[sel], 1e-3) ** -params.power
    weights = inv / inv.sum()
    ref = cand[sel]
    xy_ref = smap.xy_m[ref]
    xy = weights @ xy_ref
    spread = float(weights @ np.sum((xy_ref - xy) ** 2, axis=1))
    return WknnFix(
        x_m=float(xy[0]),
        y_m=float(xy[1]),
        floor=floor,
        var_m2=spread,
        neighbours=ref.astype(np.int64),
        weights=weights,
        distances_db=d[sel],
        floor_logp=logp,
        n_matched=q.n_matched,
    )


def merge_scan_maps(maps: Sequence[ScanMap]) -> ScanMap | None:
    """Several maps of reference scans as one (a site's buildings): scans stacked, columns
    the union of the emitters; an emitter in several maps weighs as heard on all their
    walks together."""
    if len(maps) <= 1:
        return maps[0] if maps else None
    names = sorted({key for m in maps for key in m.emitters})
    column = {key: j for j, key in enumerate(names)}
    cols, rows, rssi, fresh = [], [], [], []
    walks = np.zeros(len(names))
    start = 0
    for m in maps:
        own = np.fromiter((column[k] for k in m.emitters), np.int64, len(m.emitters))
        per_column = np.diff(m.indptr)
        cols.append(np.repeat(own, per_column))
        rows.append(m.rows.astype(np.int64) + start)
        rssi.append(m.rssi_dbm)
        fresh.append(m.fresh)
        walks[own] += m.rarity ** (-1.0 / RARITY_EXPONENT)
        start += len(m)
    col = np.concatenate(cols)
    order = np.argsort(col, kind="stable")
    col, row = col[order], np.concatenate(rows)[order]
    fresh_all = np.concatenate(fresh)[order]
    rarity = np.maximum(walks, 1.0) ** -RARITY_EXPONENT
    return ScanMap(
        xy_m=np.concatenate([m.xy_m for m in maps]),
        floor=np.concatenate([m.floor for m in maps]),
        emitters=tuple(names),
        indptr=np.r_[0, np.cumsum(np.bincount(col, minlength=len(names)))].astype(np.int64),
        rows=row.astype(np.int32),
        rssi_dbm=np.concatenate(rssi)[order],
        fresh=fresh_all,
        rarity=rarity,
        totals=np.bincount(row, weights=rarity[col] * fresh_all, minlength=start).astype(
            np.float64
        ),
        decay_per_s=maps[0].decay_per_s,
    )
