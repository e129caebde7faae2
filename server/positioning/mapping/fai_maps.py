"""What the fingerprinting accuracy indicators need of a radio map, built with the map
(``papers/000_*`` eq 15-18 and 23): each column's emitter fitted by the log-distance
path-loss model to the mean RSS of the reference points that heard it
(``path_loss.fit_emitter``, on the floor where most of them are), and each reference point's
DSF (``accuracy_indicators.spreads``).
"""

from __future__ import annotations

import numpy as np

from server.positioning.radio.accuracy_indicators import FaiMaps, FaiParams, spreads
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap
from server.positioning.radio.path_loss import fit_emitter

MIN_POINTS = 8  # reference points that heard an emitter before its model is fitted


def build_fai_maps(radio: RadioMap, params: FaiParams) -> FaiMaps:
    """Emitter models and DSF of ``radio`` (module docstring)."""
    n_em = len(radio.emitters)
    xy = np.full((n_em, 2), np.nan)
    p0 = np.full(n_em, np.nan)
    gamma = np.full(n_em, np.nan)
    heard = radio.mean_dbm > MISSING_DBM
    for j in np.flatnonzero(heard.sum(axis=0) >= MIN_POINTS).tolist():
        rows = np.flatnonzero(heard[:, j])
        floors, counts = np.unique(radio.rp_floor[rows], return_counts=True)
        rows = rows[radio.rp_floor[rows] == floors[np.argmax(counts)]]
        if rows.size < MIN_POINTS:
            continue
        fit = fit_emitter(radio.rp_xy[rows].astype(np.float64), radio.mean_dbm[rows, j])
        if fit is not None and fit.exponent > 0:
            xy[j], p0[j], gamma[j] = fit.xy, fit.p0_dbm, fit.exponent
    return FaiMaps(xy, p0, gamma, spreads(radio, params.kappa_d, params.min_sd_db))
