"""Radio fixes of held-out training paths: the data ``fix_error.fit`` learns from.

The training paths are split into ``folds`` groups (by path, so a path's own scans never
build the map that locates it: a scan matched against its own reference point would look
far better than any phone's). For each group a radio map is gridded from the other
groups' scans exactly as the site's map is, and the group's scans are located on it by
WKNN; the horizontal error of each fix whose floor is right is kept with the fix's kind
and matched-emitter count. Floors are the floor filter's business; a fix on the wrong
floor says nothing about the horizontal error of a fix on the right one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from server.positioning.events import RadioReading
from server.positioning.fingerprint import in_place_order, scan_vector, wknn
from server.positioning.fix_error import FixErrorModel, fit
from server.positioning.mapping.gridding import build_radio_map
from server.positioning.mapping.matrices import readings_matrix


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
    k: int = 4,
    folds: int = 5,
    max_per_fold: int = 1500,
    cell_m: float = 1.0,
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
        Path of each scan; paths are dealt into folds at random.
    scans : sequence of n sequences of (column key, rssi_dbm)
        Readings keyed as map columns (``"wifi:<bssid>"``, ``"ble:<mac>"``); the kind of
        a scan is the prefix of its first key.
    rng : numpy.random.Generator
        Deals paths into folds and picks at most ``max_per_fold`` scans per fold.
    """
    paths = np.unique(group)
    fold_of_path = dict(
        zip(paths.tolist(), (rng.permutation(paths.size) % folds).tolist(), strict=True)
    )
    fold = np.array([fold_of_path[g] for g in group.tolist()], dtype=np.int64)
    emitters, rssi = readings_matrix(scans)
    kinds: list[str] = []
    n_matched: list[int] = []
    errors: list[float] = []
    floor_ok: list[bool] = []
    for f in range(folds):
        test = np.flatnonzero(fold == f)
        train = np.flatnonzero(fold != f)
        if test.size == 0 or train.size == 0:
            continue
        # the fold's map knows only the emitters its own scans heard, as any map does
        heard = np.isfinite(rssi[train]).any(axis=0)
        radio = in_place_order(
            build_radio_map(
                xy_m[train],
                floor[train],
                rssi[np.ix_(train, np.flatnonzero(heard))],
                tuple(emitters[j] for j in np.flatnonzero(heard).tolist()),
                cell_m=cell_m,
            )
        )
        if test.size > max_per_fold:
            test = np.sort(rng.choice(test, max_per_fold, replace=False))
        for i in test.tolist():
            readings = scans[i]
            if not readings:
                continue
            kind = readings[0][0].split(":", 1)[0]
            prefix = f"{kind}:"
            scan = scan_vector(
                radio, [RadioReading(key[len(prefix) :], v) for key, v in readings], kind
            )
            found = wknn(radio, scan, k=k)
            if found is None:
                continue
            ok = found.floor == int(floor[i])
            kinds.append(kind)
            n_matched.append(scan.n_matched)
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
    **kwargs: int | float,
) -> FixErrorModel:
    """``fix_error.fit`` on ``held_out_fixes``."""
    held = held_out_fixes(xy_m, floor, group, scans, rng, **kwargs)  # type: ignore[arg-type]
    return fit(held.kinds, held.n_matched, held.error_m)
