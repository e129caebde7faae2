"""Scan vectors and WKNN on toy radio maps where the answer is known exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import ArrayLike

from server.positioning.model.events import BleEvent, RadioReading, window_ble
from server.positioning.radio.fingerprints import (
    MISSING_DBM,
    RadioMap,
    ScanVector,
    scan_vector,
    signal_distances,
    wknn,
)

WIFI = ("wifi:aa", "wifi:bb", "wifi:cc")
EMITTERS = (*WIFI, "ble:beacon-1")


def make_map(
    xy: ArrayLike, floor: ArrayLike, mean: ArrayLike, emitters: tuple[str, ...]
) -> RadioMap:
    mean_dbm = np.asarray(mean, dtype=np.float32)
    heard = mean_dbm > MISSING_DBM
    return RadioMap(
        rp_xy=np.asarray(xy, dtype=np.float32),
        rp_floor=np.asarray(floor, dtype=np.int32),
        mean_dbm=mean_dbm,
        var_db2=np.where(heard, 4.0, 0.0).astype(np.float32),
        count=heard.astype(np.int32),
        emitters=emitters,
    )


def grid_map() -> RadioMap:
    """3 x 3 RPs 2 m apart; each WiFi AP fades 6 dB per metre from its own corner."""
    xy = np.array([(x, y) for y in (0.0, 2.0, 4.0) for x in (0.0, 2.0, 4.0)])
    aps = np.array([(0.0, 0.0), (4.0, 0.0), (0.0, 4.0)])
    dist = np.linalg.norm(xy[:, None, :] - aps[None, :, :], axis=2)
    mean = np.column_stack([-40.0 - 6.0 * dist, np.full(9, MISSING_DBM)])
    return make_map(xy, np.zeros(9), mean, EMITTERS)


def readings_of(radio_map: RadioMap, rp: int, kind: str = "wifi") -> list[RadioReading]:
    prefix = f"{kind}:"
    return [
        RadioReading(key.removeprefix(prefix).upper(), float(radio_map.mean_dbm[rp, j]))
        for j, key in enumerate(radio_map.emitters)
        if key.startswith(prefix) and radio_map.mean_dbm[rp, j] > MISSING_DBM
    ]


def test_scan_vector_lays_out_columns_by_kind() -> None:
    m = grid_map()
    readings = [
        RadioReading("AA", -60.0),
        RadioReading("aa", -55.0),  # duplicate, stronger: kept
        RadioReading("aa", -70.0),  # duplicate, weaker
        RadioReading("cc", -80.0),
        RadioReading("ff", -30.0),  # unknown emitter: ignored
        RadioReading("beacon-1", -50.0),  # a BLE id, but this is a WiFi scan: no match
    ]
    scan = scan_vector(m, readings, "wifi")
    assert scan.rssi_dbm.dtype == np.float32
    assert scan.rssi_dbm.tolist() == [-55.0, MISSING_DBM, -80.0, MISSING_DBM]
    assert scan.mask.tolist() == [True, True, True, False]
    assert scan.n_matched == 2

    ble = scan_vector(m, [RadioReading("Beacon-1", -65.0)], "ble")
    assert ble.rssi_dbm.tolist() == [MISSING_DBM, MISSING_DBM, MISSING_DBM, -65.0]
    assert ble.mask.tolist() == [False, False, False, True]
    assert ble.n_matched == 1


def test_scan_vector_ignores_non_finite_readings() -> None:
    scan = scan_vector(grid_map(), [RadioReading("aa", float("nan"))], "wifi")
    assert scan.n_matched == 0
    assert np.all(scan.rssi_dbm == MISSING_DBM)


def test_unknown_emitters_give_no_fix() -> None:
    m = grid_map()
    scan = scan_vector(m, [RadioReading("de:ad:be:ef:00:01", -50.0)], "wifi")
    assert scan.n_matched == 0
    assert wknn(m, scan) is None


@pytest.mark.parametrize("rp", range(9))
def test_scan_equal_to_a_fingerprint_gives_that_rp(rp: int) -> None:
    m = grid_map()
    fix = wknn(m, scan_vector(m, readings_of(m, rp), "wifi"))
    assert fix is not None
    assert fix.neighbours[0] == rp
    assert fix.distances_db[0] == 0.0
    assert (fix.x_m, fix.y_m) == pytest.approx(tuple(m.rp_xy[rp]), abs=1e-4)
    assert fix.floor == 0
    assert fix.weights.sum() == pytest.approx(1.0)


def test_midpoint_symmetry_and_eq17() -> None:
    m = make_map(
        [(0.0, 0.0), (4.0, 0.0), (2.0, 9.0)],
        [0, 0, 0],
        [[-40.0, -60.0], [-60.0, -40.0], [-90.0, -90.0]],
        ("wifi:a", "wifi:b"),
    )
    scan = scan_vector(m, [RadioReading("a", -50.0), RadioReading("b", -50.0)], "wifi")
    fix = wknn(m, scan, k=2)
    assert fix is not None
    assert (fix.x_m, fix.y_m) == pytest.approx((2.0, 0.0))
    np.testing.assert_allclose(fix.weights, [0.5, 0.5])
    np.testing.assert_allclose(fix.distances_db, [np.sqrt(200.0)] * 2)
    # papers/003_* eq 17: sum w^2 * |fix - rp| = 0.25 * 2 + 0.25 * 2
    assert fix.var_m2 == pytest.approx(1.0)


def test_weights_are_inverse_distances() -> None:
    m = make_map([(0.0, 0.0), (3.0, 0.0)], [0, 0], [[-50.0], [-53.0]], ("wifi:a",))
    fix = wknn(m, scan_vector(m, [RadioReading("a", -51.0)], "wifi"), k=2)
    assert fix is not None
    # D = 1 and 2 -> weights 2/3 and 1/3 (papers/002_* eq 3)
    np.testing.assert_allclose(fix.weights, [2.0 / 3.0, 1.0 / 3.0])
    assert fix.x_m == pytest.approx(1.0)
    assert fix.var_m2 == pytest.approx(4.0 / 9.0 * 1.0 + 1.0 / 9.0 * 2.0)


def test_floor_vote_is_weighted_not_nearest() -> None:
    # nearest RP is on floor 0 (D = 1), but three floor-1 RPs at D = 2 outvote it
    m = make_map(
        [(0.0, 0.0), (10.0, 0.0), (20.0, 0.0), (1.0, 1.0), (2.0, 1.0), (3.0, 1.0)],
        [0, 0, 0, 1, 1, 1],
        [[-51.0], [-70.0], [-80.0], [-52.0], [-48.0], [-52.0]],
        ("wifi:a",),
    )
    fix = wknn(m, scan_vector(m, [RadioReading("a", -50.0)], "wifi"), k=4)
    assert fix is not None
    assert fix.floor == 1
    assert sorted(fix.neighbours.tolist()) == [3, 4, 5]
    assert (fix.x_m, fix.y_m) == pytest.approx((2.0, 1.0))


def test_floor_is_the_one_whose_k_nearest_match_best() -> None:
    # floor 0 holds the single nearest RP (D = 0.5) but its other RPs are far (D = 40);
    # floor 1's three RPs are all at D = 4: the floor whose K nearest match best wins
    m = make_map(
        [(0.0, 0.0), (10.0, 0.0), (1.0, 1.0), (2.0, 1.0), (3.0, 1.0)],
        [0, 0, 1, 1, 1],
        [[-50.5], [-90.0], [-54.0], [-46.0], [-54.0]],
        ("wifi:a",),
    )
    fix = wknn(m, scan_vector(m, [RadioReading("a", -50.0)], "wifi"), k=4)
    assert fix is not None
    assert fix.floor == 1
    assert fix.floor_prob > 0.5
    assert np.exp(fix.floor_logp).sum() == pytest.approx(1.0)


def test_a_floor_prior_outweighs_a_weak_scan() -> None:
    m = make_map(
        [(0.0, 0.0), (1.0, 0.0), (0.0, 0.0), (1.0, 0.0)],
        [0, 0, 1, 1],
        [[-50.0], [-52.0], [-53.0], [-55.0]],
        ("wifi:a",),
    )
    scan = scan_vector(m, [RadioReading("a", -51.0)], "wifi")
    alone = wknn(m, scan, k=2)
    assert alone is not None
    assert alone.floor == 0
    prior = np.log(np.array([0.01, 0.99]))
    held = wknn(m, scan, k=2, floor_log_prior=prior)
    assert held is not None
    assert held.floor == 1
    assert held.floor_prob < 0.99  # the scan still pulled towards floor 0


def test_too_few_emitters_give_no_fix() -> None:
    m = grid_map()
    scan = scan_vector(
        m, [RadioReading(WIFI[0][5:], -50.0), RadioReading(WIFI[1][5:], -60.0)], "wifi"
    )
    assert wknn(m, scan, min_matched=3) is None
    assert wknn(m, scan, min_matched=2) is not None


def test_floor_choice_on_a_two_floor_building() -> None:
    base = grid_map()
    upper = base.mean_dbm.copy()
    upper[:, :3] -= 25.0  # same APs through the ceiling
    upper[:, 3] = -45.0  # and a beacon only upstairs
    m = make_map(
        np.concatenate([base.rp_xy, base.rp_xy]),
        np.repeat([0, 1], 9),
        np.concatenate([base.mean_dbm, upper]),
        EMITTERS,
    )
    for floor in (0, 1):
        rp = 9 * floor + 4
        for kind in ("wifi", "ble") if floor == 1 else ("wifi",):
            fix = wknn(m, scan_vector(m, readings_of(m, rp, kind), kind))
            assert fix is not None
            assert fix.floor == floor
            assert np.all(m.rp_floor[fix.neighbours] == floor)


def test_candidates_restrict_the_search() -> None:
    m = grid_map()
    scan = scan_vector(m, readings_of(m, 0), "wifi")
    fix = wknn(m, scan, k=2, candidates=np.array([7, 8, 5]))
    assert fix is not None
    assert set(fix.neighbours.tolist()) <= {5, 7, 8}
    by_mask = wknn(m, scan, k=2, candidates=np.isin(np.arange(9), [5, 7, 8]))
    assert by_mask is not None
    np.testing.assert_array_equal(by_mask.neighbours, fix.neighbours)
    assert wknn(m, scan, candidates=np.array([], dtype=np.int64)) is None


def test_k_must_be_positive() -> None:
    m = grid_map()
    with pytest.raises(ValueError, match="k must be"):
        wknn(m, scan_vector(m, readings_of(m, 0), "wifi"), k=0)


def test_signal_distance_is_euclidean_over_the_mask() -> None:
    m = grid_map()
    scan = ScanVector(
        rssi_dbm=np.array([-50.0, -60.0, -70.0, -10.0], dtype=np.float32),
        mask=np.array([True, True, True, False]),
        n_matched=3,
    )
    d = signal_distances(m, scan)
    expected = np.linalg.norm(m.mean_dbm[:, :3] - np.array([-50.0, -60.0, -70.0]), axis=1)
    np.testing.assert_allclose(d, expected, rtol=1e-6)


@settings(max_examples=100, deadline=None)
@given(
    rssi=st.lists(st.floats(-99.0, -30.0), min_size=3, max_size=3),
    k=st.integers(1, 12),
)
def test_fix_is_a_convex_combination_of_its_neighbours(rssi: list[float], k: int) -> None:
    m = grid_map()
    readings = [RadioReading(key[5:], v) for key, v in zip(WIFI, rssi, strict=True)]
    fix = wknn(m, scan_vector(m, readings, "wifi"), k=k)
    assert fix is not None
    assert len(fix.neighbours) >= min(k, 9)  # ties at the K-th distance all take part
    assert np.all(fix.weights > 0)
    assert fix.weights.sum() == pytest.approx(1.0)
    assert np.all(np.diff(fix.distances_db) >= 0)  # nearest first
    xy = m.rp_xy[fix.neighbours]
    assert xy[:, 0].min() - 1e-6 <= fix.x_m <= xy[:, 0].max() + 1e-6
    assert xy[:, 1].min() - 1e-6 <= fix.y_m <= xy[:, 1].max() + 1e-6
    assert fix.var_m2 >= 0.0


def test_rps_tied_at_the_kth_distance_all_take_part() -> None:
    xy = [(float(i), 2.0 * i) for i in range(6)]
    m = make_map(xy, np.zeros(6), np.full((6, 1), -60.0), ("wifi:a",))
    fix = wknn(m, scan_vector(m, [RadioReading("a", -50.0)], "wifi"), k=3)
    assert fix is not None
    assert fix.neighbours.tolist() == [0, 1, 2, 3, 4, 5]
    assert (fix.x_m, fix.y_m) == pytest.approx((2.5, 5.0))  # not the first three


def test_window_ble_groups_rows_into_scans_with_mean_rssi() -> None:
    rows = [
        BleEvent(1000, (RadioReading("a", -70.0),)),
        BleEvent(1500, (RadioReading("b", -80.0),)),
        BleEvent(2900, (RadioReading("a", -60.0),)),
        BleEvent(3100, (RadioReading("c", -90.0),)),  # more than 2 s after the first
        BleEvent(9000, (RadioReading("a", -75.0),)),
    ]
    scans = window_ble(rows[::-1], window_ms=2000)
    assert [s.t_ms for s in scans] == [2900, 3100, 9000]
    assert {(r.emitter, r.rssi_dbm) for r in scans[0].readings} == {("a", -65.0), ("b", -80.0)}
    assert [r.emitter for r in scans[1].readings] == ["c"]
    assert window_ble([]) == []
    with pytest.raises(ValueError, match="window_ms"):
        window_ble(rows, window_ms=0)


def test_a_floor_without_reference_points_is_never_chosen() -> None:
    # RPs on floors 0 and 2 only; a weak scan, repeated, must not drift onto floor 1
    m = make_map(
        [(0.0, 0.0), (1.0, 0.0), (0.0, 0.0), (1.0, 0.0)],
        [0, 0, 2, 2],
        [[-60.0, -62.0], [-61.0, -63.0], [-75.0, -70.0], [-76.0, -71.0]],
        ("wifi:a", "wifi:b"),
    )
    scan = scan_vector(m, [RadioReading("a", -90.0), RadioReading("b", -92.0)], "wifi")
    logp = None
    for _ in range(10):
        fix = wknn(m, scan, k=2, floor_log_prior=logp)
        assert fix is not None
        assert fix.floor in (0, 2)
        assert np.exp(fix.floor_logp[1]) == 0.0
        logp = fix.floor_logp


def test_a_prior_over_another_number_of_floors_is_dropped() -> None:
    m = make_map([(0.0, 0.0), (0.0, 0.0)], [0, 1], [[-50.0], [-80.0]], ("wifi:a",))
    scan = scan_vector(m, [RadioReading("a", -50.0)], "wifi")
    alone = wknn(m, scan, k=1)
    stale = wknn(m, scan, k=1, floor_log_prior=np.log([0.01, 0.01, 0.98]))
    assert alone is not None
    assert stale is not None
    np.testing.assert_allclose(stale.floor_logp[:2], alone.floor_logp[:2])


def test_readings_at_the_missing_level_are_not_evidence() -> None:
    m = grid_map()
    readings = [
        RadioReading(WIFI[0][5:], -70.0),
        RadioReading(WIFI[1][5:], -70.0),
        RadioReading(WIFI[2][5:], MISSING_DBM),
    ]
    assert scan_vector(m, readings, "wifi").n_matched == 2
