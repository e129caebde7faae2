"""Dense matrices from sparse radio readings, and site radio maps from building maps.

A survey or a trace lists, per labelled point, the emitters heard and their RSS. The
gridding step (``gridding.build_radio_map``) wants a dense ``(n_points, n_emitters)``
matrix with NaN where an emitter was not heard; ``readings_matrix`` makes it. A site may
hold several buildings, each with its own radio map version; ``merge_radio_maps`` stacks
their reference points and takes the union of their emitter columns, so one WKNN search
covers every floor of the site (floor indices must already be site-wide).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap


def readings_matrix(
    scans: Sequence[Sequence[tuple[str, float]]],
) -> tuple[tuple[str, ...], NDArray[np.float32]]:
    """Column keys (sorted) and the ``(n_points, n_emitters)`` RSS matrix, NaN = not heard.

    An emitter listed twice in one scan keeps its strongest reading.
    """
    emitters = tuple(sorted({key for scan in scans for key, _ in scan}))
    col = {key: i for i, key in enumerate(emitters)}
    rssi = np.full((len(scans), len(emitters)), np.nan, dtype=np.float32)
    for row, scan in enumerate(scans):
        for key, value in scan:
            j = col[key]
            current = rssi[row, j]
            if np.isnan(current) or value > current:
                rssi[row, j] = value
    return emitters, rssi


def merge_radio_maps(maps: Sequence[RadioMap]) -> RadioMap | None:
    """Stack reference points of several maps over the union of their emitter columns."""
    if not maps:
        return None
    if len(maps) == 1:
        return maps[0]
    emitters = tuple(sorted({key for m in maps for key in m.emitters}))
    col = {key: i for i, key in enumerate(emitters)}
    n_rp = sum(m.rp_xy.shape[0] for m in maps)
    mean = np.full((n_rp, len(emitters)), MISSING_DBM, dtype=np.float32)
    var = np.zeros((n_rp, len(emitters)), dtype=np.float32)
    count = np.zeros((n_rp, len(emitters)), dtype=np.int32)
    start = 0
    for m in maps:
        rows = slice(start, start + m.rp_xy.shape[0])
        cols = np.fromiter((col[k] for k in m.emitters), dtype=np.int64, count=len(m.emitters))
        mean[rows, cols] = m.mean_dbm
        var[rows, cols] = m.var_db2
        count[rows, cols] = m.count
        start = rows.stop
    return RadioMap(
        rp_xy=np.concatenate([m.rp_xy for m in maps]).astype(np.float32),
        rp_floor=np.concatenate([m.rp_floor for m in maps]).astype(np.int32),
        mean_dbm=mean,
        var_db2=var,
        count=count,
        emitters=emitters,
    )
