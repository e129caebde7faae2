"""Radio maps as dense matrices and weighted K-nearest-neighbour matching.

PLACEHOLDER: the full module is being written.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MISSING_DBM = -100.0


@dataclass(frozen=True)
class RadioMap:
    """Reference points x emitters.

    rp_xy: (n_rp, 2) float32 metres; rp_floor: (n_rp,) int32 floor index;
    mean_dbm, var_db2: (n_rp, n_em) float32 (MISSING_DBM / 0 where not heard);
    count: (n_rp, n_em) int32; emitters: column keys ``"wifi:<bssid>"`` / ``"ble:<id>"``.
    """

    rp_xy: np.ndarray
    rp_floor: np.ndarray
    mean_dbm: np.ndarray
    var_db2: np.ndarray
    count: np.ndarray
    emitters: tuple[str, ...]
