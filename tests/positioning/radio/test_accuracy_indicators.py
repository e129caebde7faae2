"""The fingerprinting accuracy indicators on toy maps with answers by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.positioning.radio.accuracy_indicators import (
    FaiParams,
    combine,
    geometry,
    likelihood_fix,
    log_likelihoods,
    signal_strength,
    spreads,
    weighted_spread,
    with_location_uncertainty,
)
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap, ScanVector


def corridor(n: int = 5, emitters: int = 2) -> RadioMap:
    """RPs 1 m apart along x; emitter j's mean falls by 3 dB per metre from the start."""
    x = np.arange(n, dtype=np.float32)
    mean = np.column_stack([-40.0 - 3.0 * x - 10.0 * j for j in range(emitters)])
    return RadioMap(
        rp_xy=np.column_stack([x, np.zeros(n, np.float32)]),
        rp_floor=np.zeros(n, np.int32),
        mean_dbm=mean.astype(np.float32),
        var_db2=np.full(mean.shape, 16.0, np.float32),
        count=np.ones(mean.shape, np.int32),
        emitters=tuple(f"wifi:ap{j}" for j in range(emitters)),
    )


def test_sd_is_the_dop_of_a_known_geometry() -> None:
    square = np.array([[10.0, 0.0], [-10.0, 0.0], [0.0, 10.0], [0.0, -10.0]])
    # H^T H = diag(2, 2): DOP sqrt(1/2 + 1/2) = 1
    assert geometry((0.0, 0.0), square, alpha=5.0) == pytest.approx(5.0)
    # three emitters 120 degrees apart: H^T H = diag(3/2, 3/2), DOP sqrt(4/3)
    angles = np.radians([90.0, 210.0, 330.0])
    tri = 20.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    assert geometry((0.0, 0.0), tri, alpha=1.0) == pytest.approx(math.sqrt(4.0 / 3.0))
    # all on one line through the device: the across-track position is not determined
    line = np.array([[5.0, 0.0], [9.0, 0.0], [-3.0, 0.0]])
    assert geometry((0.0, 0.0), line, alpha=1.0) == math.inf
    assert geometry((0.0, 0.0), square[:1], alpha=1.0) == math.inf


def test_ss_is_the_scaled_harmonic_mean_of_the_implied_distances() -> None:
    # P0 -40 dBm, gamma 2: -60 dBm implies 10 m, -53.98 dBm 5 m
    r5 = -40.0 - 20.0 * math.log10(5.0)
    ss = signal_strength([-60.0, r5], [-40.0, -40.0], [2.0, 2.0], alpha=0.2)
    assert ss == pytest.approx(0.2 / ((0.1 + 0.2) / 2))
    # nearer emitters predict a smaller error
    assert signal_strength([-45.0], [-40.0], [2.0], 0.2) < ss
    assert signal_strength([], [], [], 0.2) == math.inf


def test_wd_of_similar_fingerprints_at_known_distances() -> None:
    radio = corridor()
    dsf = spreads(radio, kappa_d=2, min_sd_db=4.0)
    # inside, the two most alike are the neighbours 1 m off; at the ends 1 m and 2 m
    np.testing.assert_allclose(dsf, [1.5, 1.0, 1.0, 1.0, 1.5])
    points = np.array([0, 1], dtype=np.int64)
    assert weighted_spread(dsf, points, np.array([0.75, 0.25])) == pytest.approx(1.375)
    assert math.isnan(weighted_spread(np.full(5, np.nan), points, np.array([0.5, 0.5])))


def test_the_likelihood_fix_weighs_the_most_likely_points() -> None:
    radio = corridor()
    rssi = radio.mean_dbm[2].copy()
    scan = ScanVector(rssi, np.ones(2, bool), 2)
    ll = log_likelihoods(radio, scan, np.ones(5, bool), min_sd_db=4.0)
    assert int(np.argmax(ll)) == 2
    # one point less likely than its neighbour by the Gaussian of eq 11: 2 x (3/4)^2 / 2
    assert ll[2] - ll[1] == pytest.approx(2 * 0.5 * (3.0 / 4.0) ** 2)
    fix = likelihood_fix(ll, radio.rp_xy, kappa=3)
    assert fix is not None
    assert list(fix.points) == [2, 1, 3] or list(fix.points) == [2, 3, 1]
    assert fix.x_m == pytest.approx(2.0)  # the two neighbours weigh alike
    assert fix.weights.sum() == pytest.approx(1.0)
    deaf = ScanVector(np.full(2, MISSING_DBM, np.float32), np.ones(2, bool), 0)
    assert (
        likelihood_fix(log_likelihoods(radio, deaf, np.ones(5, bool), 4.0), radio.rp_xy, 3) is None
    )


def test_combinations_and_location_uncertainty() -> None:
    params = FaiParams()
    both = combine(2.0, 4.0, 10.0, params)
    assert both.mc == pytest.approx(0.2 * 2 + 0.3 * 4 + 0.5 * 10)
    assert both.mcm == 10.0
    assert both.pick("ct", params.ct_m) == 6.0
    assert both.pick("sd", params.ct_m) == 4.0
    # an indicator that cannot be computed takes no part
    no_geometry = combine(2.0, math.inf, 10.0, params)
    assert no_geometry.mc == pytest.approx((0.2 * 2 + 0.5 * 10) / 0.7)
    assert no_geometry.mcm == 10.0
    assert with_location_uncertainty(3.0, 4.0) == 5.0
