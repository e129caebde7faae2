"""Radio fixes of held-out training paths: the data ``fix_error.fit`` learns from.

The training paths are split into ``folds`` groups (by path, so a path's own scans never
build the map that locates it: a scan matched against its own neighbours on the same walk
would look far better than any phone's). For each group a map of reference scans is built
from the other groups' scans exactly as the site's is (``scan_matching``), and the group's
scans are located on it; the horizontal error of each fix whose floor is right is kept
with the fix's kind and matched-emitter count. Floors are the floor filter's business; a
fix on the wrong floor says nothing about the horizontal error of a fix on the right one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.events import RadioReading
from server.positioning.radio.fix_error import FixErrorModel, fit
from server.positioning.radio.scan_matching import MatchParams, build_scan_map, locate, query

DEFAULT_MATCH = MatchParams()


@dataclass(frozen=True)
class HeldOutFixes:
    """One row per held-out scan that matched its map.

    kinds : (n,) scan kind; n_matched : (n,) int; error_m : (n,) horizontal error, NaN
    when the fix's floor was wrong; floor_ok : (n,) bool.
    """

    kinds: tuple[str, ...]
    n_matched: NDArray[np.int64]
    error_m: NDArray[np.float64]
    floor_ok: NDArray[np.bool_]


def held_out_fixes(
    xy_m: NDArray[np.float64],
    floor: NDArray[np.int64],
    group: NDArray[np.int64],
    scans: Sequence[Sequence[tuple[str, float]]],
    rng: np.random.Generator,
    *,
    ages_ms: Sequence[Sequence[float | None]] | None = None,
    walk: NDArray[np.int64] | None = None,
    params: MatchParams = DEFAULT_MATCH,
    folds: int = 5,
    max_per_fold: int = 1500,
) -> HeldOutFixes:
    """Locate each fold's scans on a map built from the other folds (see the module
    docstring).

    Parameters
    ----------
    xy_m : ndarray, shape (n, 2)
        True position of each scan.
    floor : ndarray, shape (n,), int
        True floor index of each scan.
    group : ndarray, shape (n,), int
        Path (or route) of each scan; groups are dealt into folds at random.
    scans : sequence of n sequences of (column key, rssi_dbm)
        Readings keyed as map columns (``"wifi:<bssid>"``, ``"ble:<mac>"``); the kind of
        a scan is the prefix of its first key.
    rng : numpy.random.Generator
        Deals paths into folds and picks at most ``max_per_fold`` scans per fold.
    ages_ms, walk :
        Each reading's age and each scan's walk, as ``scan_matching.build_scan_map``
        takes them.
    """
    paths = np.unique(group)
    fold_of_path = dict(
        zip(paths.tolist(), (rng.permutation(paths.size) % folds).tolist(), strict=True)
    )
    fold = np.array([fold_of_path[g] for g in group.tolist()], dtype=np.int64)
    walks = walk if walk is not None else np.full(len(scans), -1, dtype=np.int64)
    kinds: list[str] = []
    n_matched: list[int] = []
    errors: list[float] = []
    floor_ok: list[bool] = []
    for f in range(folds):
        test = np.flatnonzero(fold == f)
        train = np.flatnonzero(fold != f)
        if test.size == 0 or train.size == 0:
            continue
        smap = build_scan_map(
            xy_m[train],
            floor[train],
            [scans[i] for i in train.tolist()],
            ages_ms=[ages_ms[i] for i in train.tolist()] if ages_ms else None,
            walk=walks[train],
            decay_per_s=params.decay_per_s,
        )
        if test.size > max_per_fold:
            test = np.sort(rng.choice(test, max_per_fold, replace=False))
        for i in test.tolist():
            readings = scans[i]
            if not readings:
                continue
            kind = readings[0][0].split(":", 1)[0]
            prefix = f"{kind}:"
            ages = ages_ms[i] if ages_ms else [None] * len(readings)
            q = query(
                smap,
                [
                    RadioReading(key[len(prefix) :], v, age)
                    for (key, v), age in zip(readings, ages, strict=True)
                ],
                kind,
            )
            found = locate(smap, q, params, n_floors=int(floor.max(initial=-1)) + 1)
            if found is None:
                continue
            ok = found.floor == int(floor[i])
            kinds.append(kind)
            n_matched.append(q.n_matched)
            floor_ok.append(ok)
            errors.append(
                float(np.hypot(found.x_m - xy_m[i, 0], found.y_m - xy_m[i, 1])) if ok else np.nan
            )
    return HeldOutFixes(
        tuple(kinds),
        np.asarray(n_matched, dtype=np.int64),
        np.asarray(errors, dtype=np.float64),
        np.asarray(floor_ok, dtype=bool),
    )


def learn_fix_error(
    xy_m: NDArray[np.float64],
    floor: NDArray[np.int64],
    group: NDArray[np.int64],
    scans: Sequence[Sequence[tuple[str, float]]],
    rng: np.random.Generator,
    **kwargs: Any,
) -> FixErrorModel:
    """``fix_error.fit`` on ``held_out_fixes``."""
    held = held_out_fixes(xy_m, floor, group, scans, rng, **kwargs)
    return fit(held.kinds, held.n_matched, held.error_m)
