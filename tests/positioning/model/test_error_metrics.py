"""Error statistics on examples small enough to work out by hand."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from server.positioning.model.error_metrics import (
    WITHIN_1SIGMA_IDEAL,
    WITHIN_2SIGMA_IDEAL,
    ErrorReport,
    error_cdf,
    error_report,
    ipin_score,
)

NAN = math.nan

# errors 0, 5, 1, (missing), 10 m against the origin
EST = np.array([(0.0, 0.0), (3.0, 4.0), (0.0, 1.0), (NAN, NAN), (6.0, 8.0)])
TRUTH = np.zeros((5, 2))
EST_FLOOR = np.array([0, 1, 0, 0, 2])  # row 1 on the wrong floor
TRUE_FLOOR = np.array([0, 0, 0, 0, 2])
EST_BUILDING = np.array([1, 1, 2, 9, 1])  # row 2 in the wrong building (row 3 is missing)
TRUE_BUILDING = np.ones(5, dtype=int)
SIGMA = np.array([1.0, 4.0, 1.0, 1.0, NAN])
R68 = np.array([0.5, 6.0, 0.5, 1.0, 12.0])
R95 = np.array([1.0, 4.0, 2.0, 1.0, NAN])

KEYS = {
    "n_points",
    "n_missing",
    "mean_m",
    "rms_m",
    "p50_m",
    "p75_m",
    "p80_m",
    "p90_m",
    "p95_m",
    "max_m",
    "floor_hit_rate",
    "building_hit_rate",
    "evaal_mean_m",
    "within_1sigma",
    "within_2sigma",
    "within_68",
    "within_95",
    "error_correlation",
}


def full_report() -> ErrorReport:
    return error_report(
        EST,
        TRUTH,
        EST_FLOOR,
        TRUE_FLOOR,
        sigma_m=SIGMA,
        accuracy_68_m=R68,
        accuracy_95_m=R95,
        est_building=EST_BUILDING,
        true_building=TRUE_BUILDING,
    )


def test_every_key_by_hand() -> None:
    r = full_report().to_dict()
    assert set(r) == KEYS
    # sorted errors 0, 1, 5, 10; linear percentile at position q/100 * 3
    expected = {
        "n_points": 4,
        "n_missing": 1,
        "mean_m": 4.0,
        "rms_m": math.sqrt((0 + 25 + 1 + 100) / 4),
        "p50_m": 3.0,  # 1 + 0.5 * (5 - 1)
        "p75_m": 6.25,  # 5 + 0.25 * (10 - 5)
        "p80_m": 7.0,  # 5 + 0.4 * 5
        "p90_m": 8.5,  # 5 + 0.7 * 5
        "p95_m": 9.25,  # 5 + 0.85 * 5
        "max_m": 10.0,
        "floor_hit_rate": 0.75,
        "building_hit_rate": 0.75,
        "evaal_mean_m": (0 + (5 + 4) + (1 + 50) + 10) / 4,
        "within_1sigma": 2 / 3,  # row 4 has no sigma: 0 <= 1, 5 > 4, 1 <= 1
        "within_2sigma": 1.0,  # 5 <= 8
        "within_68": 3 / 4,  # 0 <= 0.5, 5 <= 6, 1 > 0.5, 10 <= 12
        "within_95": 2 / 3,  # row 4 has no radius: 0 <= 1, 5 > 4, 1 <= 2
        # Pearson's r of the radii 0.5, 6, 0.5, 12 (mean 4.75) and errors 0, 5, 1, 10 (4)
        "error_correlation": (
            (-4.25 * -4 + 1.25 * 1 + -4.25 * -3 + 7.25 * 6)
            / math.sqrt((4.25**2 * 2 + 1.25**2 + 7.25**2) * (16 + 1 + 9 + 36))
        ),
    }
    assert r == pytest.approx(expected, rel=1e-12)


def test_to_dict_is_json_ready() -> None:
    r = full_report().to_dict()
    assert json.loads(json.dumps(r)) == r
    assert all(type(v) in {int, float} for v in r.values())


def test_percentiles_use_numpys_linear_rule() -> None:
    rng = np.random.default_rng(3)
    est = rng.normal(size=(101, 2))
    errors = np.hypot(est[:, 0], est[:, 1])
    r = error_report(est, np.zeros((101, 2)), np.zeros(101), np.zeros(101))
    got = [r.p50_m, r.p75_m, r.p80_m, r.p90_m, r.p95_m]
    assert got == pytest.approx(np.percentile(errors, [50, 75, 80, 90, 95], method="linear"))


def test_evaal_penalties_are_parameters() -> None:
    r = error_report(
        EST,
        TRUTH,
        EST_FLOOR,
        TRUE_FLOOR,
        est_building=EST_BUILDING,
        true_building=TRUE_BUILDING,
        floor_penalty_m=15.0,
        building_penalty_m=0.0,
    )
    assert r.evaal_mean_m == pytest.approx((0 + 5 + 15 + 1 + 10) / 4)


def test_a_wrong_floor_and_building_pay_both_penalties() -> None:
    r = error_report([(1.0, 0.0)], [(0.0, 0.0)], [3], [0], est_building=[1], true_building=[0])
    assert r.evaal_mean_m == pytest.approx(1.0 + 4.0 + 50.0)
    assert r.floor_hit_rate == 0.0
    assert r.building_hit_rate == 0.0


def test_without_buildings_or_sigma_those_keys_are_none() -> None:
    r = error_report(EST, TRUTH, EST_FLOOR, TRUE_FLOOR)
    assert r.building_hit_rate is None
    assert r.evaal_mean_m is None
    assert r.within_1sigma is None
    assert r.within_2sigma is None
    assert r.mean_m == 4.0
    assert r.floor_hit_rate == 0.75


def test_sigma_calibration_of_an_isotropic_gaussian() -> None:
    """Per-axis σ = 2 m, errors drawn from that Gaussian: 1 - e^-1/2 and 1 - e^-2."""
    rng = np.random.default_rng(7)
    n = 20_000
    truth = rng.uniform(0.0, 50.0, size=(n, 2))
    est = truth + rng.normal(0.0, 2.0, size=(n, 2))
    floors = np.zeros(n, dtype=int)
    r = error_report(est, truth, floors, floors, sigma_m=np.full(n, 2.0))
    assert math.isclose(WITHIN_1SIGMA_IDEAL, 0.3935, abs_tol=1e-4)
    assert math.isclose(WITHIN_2SIGMA_IDEAL, 0.8647, abs_tol=1e-4)
    assert r.within_1sigma == pytest.approx(WITHIN_1SIGMA_IDEAL, abs=0.01)
    assert r.within_2sigma == pytest.approx(WITHIN_2SIGMA_IDEAL, abs=0.01)
    # an over-confident sigma (half the truth) holds far fewer
    r_half = error_report(est, truth, floors, floors, sigma_m=np.full(n, 1.0))
    assert r_half.within_1sigma is not None
    assert r_half.within_1sigma < 0.15


def test_missing_rows_are_counted_and_excluded() -> None:
    est = np.array([(1.0, 0.0), (NAN, 2.0), (NAN, NAN)])
    r = error_report(est, np.zeros((3, 2)), [0, 0, 0], [0, 1, 1], sigma_m=[1.0, 0.0, 0.0])
    assert (r.n_points, r.n_missing) == (1, 2)
    assert r.mean_m == r.max_m == r.p50_m == 1.0
    assert r.floor_hit_rate == 1.0  # the missing rows' wrong floors do not count
    assert r.within_1sigma == 1.0


def test_all_missing_gives_none_statistics() -> None:
    est = np.full((3, 2), NAN)
    r = error_report(
        est,
        np.zeros((3, 2)),
        [-1, -1, -1],
        [0, 0, 0],
        sigma_m=[NAN] * 3,
        est_building=[-1] * 3,
        true_building=[0] * 3,
    )
    d = r.to_dict()
    assert (d["n_points"], d["n_missing"]) == (0, 3)
    assert all(d[key] is None for key in KEYS - {"n_points", "n_missing"})


def test_empty_input_is_not_a_crash() -> None:
    r = error_report(np.zeros((0, 2)), np.zeros((0, 2)), [], [], sigma_m=[])
    d = r.to_dict()
    assert (d["n_points"], d["n_missing"]) == (0, 0)
    assert all(d[key] is None for key in KEYS - {"n_points", "n_missing"})
    assert error_report([], [], [], []).n_points == 0


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="true_xy_m"):
        error_report(EST, TRUTH[:4], EST_FLOOR, TRUE_FLOOR)
    with pytest.raises(ValueError, match="true_xy_m must be finite"):
        error_report(EST, EST, EST_FLOOR, TRUE_FLOOR)
    with pytest.raises(ValueError, match="est_floor"):
        error_report(EST, TRUTH, EST_FLOOR[:2], TRUE_FLOOR)
    with pytest.raises(ValueError, match="sigma_m"):
        error_report(EST, TRUTH, EST_FLOOR, TRUE_FLOOR, sigma_m=SIGMA[:3])
    with pytest.raises(ValueError, match="both"):
        error_report(EST, TRUTH, EST_FLOOR, TRUE_FLOOR, est_building=EST_BUILDING)
    with pytest.raises(ValueError, match=r"\(n, 2\)"):
        error_report(np.zeros((5, 3)), TRUTH, EST_FLOOR, TRUE_FLOOR)


def test_error_cdf() -> None:
    errors, share = error_cdf([3.0, NAN, 1.0, 2.0])
    np.testing.assert_array_equal(errors, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(share, [1 / 3, 2 / 3, 1.0])
    errors, share = error_cdf([])
    assert errors.shape == share.shape == (0,)


def test_ipin_score_by_hand() -> None:
    # errors 0, 5, 1, (missing), 10; row 1 one floor off, row 4 two floors off
    est_level = np.array([0, -1, 0, 0, 0])
    true_level = np.array([0, 0, 0, 0, -2])
    # 0, 20, 1, 40 sorted 0, 1, 20, 40: P75 at position 2.25
    assert ipin_score(EST, TRUTH, est_level, true_level) == pytest.approx(20 + 0.25 * 20)
    assert ipin_score(EST, TRUTH, est_level, true_level, floor_penalty_m=0.0) == pytest.approx(
        full_report().p75_m
    )
    assert ipin_score(np.full((2, 2), NAN), np.zeros((2, 2)), [0, 0], [0, 0]) is None
    with pytest.raises(ValueError, match="est_level"):
        ipin_score(EST, TRUTH, est_level[:3], true_level)
