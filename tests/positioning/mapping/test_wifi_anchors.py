"""WiFi APs located from a radio map as anchors (Mansour IV-E2): the paper's thresholds."""

from __future__ import annotations

import numpy as np

from server.positioning.mapping.wifi_anchors import AnchorNodeParams, anchor_nodes
from server.positioning.radio.fingerprints import RadioMap

AP = np.array([12.0, 7.0])


def _map(count: int, rng: np.random.Generator, p0: float = -38.0) -> RadioMap:
    """RPs every 2 m over 30 m x 20 m (floor 0) hearing one AP by log-distance path loss,
    plus a weak AP from another floor; ``count`` readings per RP."""
    gx, gy = np.meshgrid(np.arange(1.0, 30.0, 2.0), np.arange(1.0, 20.0, 2.0))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    d = np.maximum(np.hypot(*(xy - AP).T), 1.0)
    near = p0 - 25.0 * np.log10(d) + rng.normal(0.0, 1.0, len(xy))
    far = np.full(len(xy), -80.0)
    n = len(xy)
    return RadioMap(
        rp_xy=xy.astype(np.float32),
        rp_floor=np.zeros(n, dtype=np.int32),
        mean_dbm=np.column_stack([near, far]).astype(np.float32),
        var_db2=np.full((n, 2), 9.0, dtype=np.float32),
        count=np.full((n, 2), count, dtype=np.int32),
        emitters=("wifi:ap-near", "wifi:ap-far"),
    )


def test_a_densely_heard_ap_is_located() -> None:
    (node,) = anchor_nodes(_map(25, np.random.default_rng(0)))
    assert node.emitter == "wifi:ap-near"
    assert node.floor == 0
    assert np.hypot(*(node.fit.xy - AP)) < 1.0
    assert abs(node.fit.p0_dbm - -38.0) < 3.0


def test_the_papers_thresholds_hold() -> None:
    rng = np.random.default_rng(1)
    assert anchor_nodes(_map(20, rng)) == []  # "more than 20" readings per RP
    assert len(anchor_nodes(_map(20, rng), AnchorNodeParams(min_readings=19))) == 1
    assert anchor_nodes(_map(25, rng), AnchorNodeParams(min_rps=200)) == []
    # an AP never heard above -55 dBm is not on this floor
    assert anchor_nodes(_map(25, rng, p0=-70.0)) == []
    noisy = _map(25, rng)
    noisy = RadioMap(
        noisy.rp_xy, noisy.rp_floor, noisy.mean_dbm, noisy.var_db2 * 9, noisy.count, noisy.emitters
    )
    assert anchor_nodes(noisy) == []  # sigma 9 dB > 8 dB
