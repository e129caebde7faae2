"""WiFi access points that can serve as anchors inside a floor (``papers/003_*`` IV-E2).

Outer anchors (entrances, elevators) bound a walk only at its ends: a long walk drifts in
between, and a walk that does not pass two of them cannot be placed. Mansour et al.
therefore locate the floor's own access points from the radio map built so far and use
a close pass by one of them as an anchor (IV-E3). An access point qualifies when, on
one floor of the map:

1. its reference points (RPs) with dense, steady readings of it -- more than
   ``min_readings`` readings (the paper: 20, from different traces) and an RSS spread
   ``sigma <= max_std_db`` (8 dB) -- number more than ``min_rps`` (50);
2. it is heard strongly there: the strongest of those RPs' mean RSS is above
   ``min_mean_dbm`` (-55 dBm), so the AP is on this floor;
3. the path-loss model (eq 8-10, ``path_loss.fit_emitter``) fitted to those RPs' mean RSS
   at their positions converges.

Its position, RSS at 1 m (``P0``) and exponent come from the fit. A walk passes the anchor
when its smoothed RSS of that AP peaks at or above ``P0`` (IV-E3: within about a metre).

Mansour also requires an anchor AP to be a *fixed* one (IV-E1: seen on more than three
days, in a cluster under 100 m^2); the radio map keeps no reading times, so that test is
``mapping.signatures.identify_fixed_aps``' job where the readings are at hand (the map
quality report) and is not repeated here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from server.positioning.radio.fingerprints import RadioMap
from server.positioning.radio.path_loss import EmitterFit, fit_emitter


@dataclass(frozen=True)
class AnchorNodeParams:
    min_readings: int = 20  # per RP, exceeded (IV-E2: "more than 20 from different traces")
    max_std_db: float = 8.0  # IV-E2: sigma_RSS <= 8 dBm
    min_rps: int = 50  # exceeded (IV-E2: "more than 50" qualified RPs)
    min_mean_dbm: float = -55.0  # IV-E2: strong RSS, the AP is on this floor


@dataclass(frozen=True)
class AnchorNode:
    emitter: str  # radio-map key, "wifi:<bssid>"
    floor: int  # floor index of the map
    fit: EmitterFit


def anchor_nodes(radio: RadioMap, params: AnchorNodeParams | None = None) -> list[AnchorNode]:
    """The map's WiFi APs that qualify as anchors (module docstring), per floor."""
    p = params or AnchorNodeParams()
    wifi = [j for j, key in enumerate(radio.emitters) if key.startswith("wifi:")]
    if not wifi:
        return []
    count = radio.count[:, wifi]
    steady = (count > p.min_readings) & (np.sqrt(radio.var_db2[:, wifi]) <= p.max_std_db)
    found = []
    for f in np.unique(radio.rp_floor).tolist():
        on_floor = radio.rp_floor == f
        qualified = steady & on_floor[:, None]
        for col in np.flatnonzero(qualified.sum(axis=0) > p.min_rps).tolist():
            rows = np.flatnonzero(qualified[:, col])
            mean = radio.mean_dbm[rows, wifi[col]].astype(np.float64)
            if mean.max() <= p.min_mean_dbm:
                continue
            fit = fit_emitter(radio.rp_xy[rows].astype(np.float64), mean)
            if fit is not None:
                found.append(AnchorNode(radio.emitters[wifi[col]], int(f), fit))
    return found
