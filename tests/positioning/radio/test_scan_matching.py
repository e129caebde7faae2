"""Matching scans against the map's own scans: distances, age weights, floors."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.model.events import RadioReading
from server.positioning.radio import scan_matching as sm

EMITTERS = [f"e{i}" for i in range(10)]


def _keyed(values: list[float], names: list[str] = EMITTERS) -> list[tuple[str, float]]:
    return [(f"wifi:{name}", v) for name, v in zip(names, values, strict=True)]


def _query(values: list[float], ages: Sequence[float | None] | None = None) -> list[RadioReading]:
    ages = ages or [None] * len(values)
    return [RadioReading(e, v, a) for e, v, a in zip(EMITTERS, values, ages, strict=True)]


def _stale_pair_map(decay: float) -> sm.ScanMap:
    """Reference A hears e0-e4 freshly as the query does and e5-e9 20 s old and 15 dB
    off; B hears e0-e4 freshly but 8 dB off and e5-e9 20 s old exactly as the query."""
    query = [-50.0, -55, -60, -65, -70, -52, -57, -62, -67, -72]
    a = query[:5] + [v - 15 for v in query[5:]]
    b = [v - 8 for v in query[:5]] + query[5:]
    ages = [[0.0] * 5 + [20_000.0] * 5] * 2
    return sm.build_scan_map(
        np.array([[0.0, 0.0], [30.0, 0.0]]),
        np.array([0, 0]),
        [_keyed(a), _keyed(b)],
        ages_ms=ages,
        walk=np.array([0, 1]),
        decay_per_s=decay,
        min_readings=1,
    )


QUERY = [-50.0, -55, -60, -65, -70, -52, -57, -62, -67, -72]


def test_the_fresh_match_ranks_first_when_half_the_map_is_stale() -> None:
    smap = _stale_pair_map(decay=sm.MatchParams.decay_per_s)
    found = sm.locate(smap, sm.query(smap, _query(QUERY), "wifi"), sm.MatchParams(k=1))
    assert found is not None
    assert found.neighbours[0] == 0  # A: its fresh readings agree with the query
    assert (found.x_m, found.y_m) == (0.0, 0.0)


def test_without_age_weights_the_stale_agreement_would_win() -> None:
    # the same map with ages ignored (no decay): B's stale agreement makes it nearer
    smap = _stale_pair_map(decay=1.0)
    found = sm.locate(smap, sm.query(smap, _query(QUERY), "wifi"), sm.MatchParams(k=1))
    assert found is not None
    assert found.neighbours[0] == 1


def test_a_stale_query_reading_counts_less() -> None:
    # the same references without ages; the query's own e5-e9 readings are 30 s old
    a = QUERY[:5] + [v - 15 for v in QUERY[5:]]
    b = [v - 8 for v in QUERY[:5]] + QUERY[5:]
    smap = sm.build_scan_map(
        np.array([[0.0, 0.0], [30.0, 0.0]]),
        np.array([0, 0]),
        [_keyed(a), _keyed(b)],
        min_readings=1,
    )
    fresh = sm.locate(smap, sm.query(smap, _query(QUERY), "wifi"), sm.MatchParams(k=1))
    assert fresh is not None
    assert fresh.neighbours[0] == 1
    ages: list[float | None] = [0.0, 0.0, 0.0, 0.0, 0.0, 3e4, 3e4, 3e4, 3e4, 3e4]
    q = sm.query(smap, _query(QUERY, ages), "wifi")
    found = sm.locate(smap, q, sm.MatchParams(k=1))
    assert found is not None
    assert found.neighbours[0] == 0


def test_age_weight_is_full_for_a_second_then_decays() -> None:
    w = sm.age_weight(np.array([0.0, 1000.0, 2000.0, 3000.0, np.nan]), 0.9)
    np.testing.assert_allclose(w, [1.0, 1.0, 0.9, 0.81, 1.0])


def test_shared_emitter_penalty_prefers_a_reference_hearing_the_same_emitters() -> None:
    # C agrees on the one emitter it shares; D is 3 dB off on all ten
    smap = sm.build_scan_map(
        np.array([[0.0, 0.0], [10.0, 0.0]]),
        np.array([0, 0]),
        [_keyed([-50.0], ["e0"]), _keyed([v - 3 for v in QUERY])],
        min_readings=1,
    )
    cand, d = sm.distances(smap, sm.query(smap, _query(QUERY), "wifi"), penalty_db=60.0)
    assert cand.tolist() == [0, 1]
    assert d[1] < d[0]
    # without the penalty the lone exact agreement would be the nearest
    _, bare = sm.distances(smap, sm.query(smap, _query(QUERY), "wifi"), penalty_db=0.0)
    assert bare[0] < bare[1]


def test_an_unsurveyed_part_of_floor_0_is_placed_on_floor_0() -> None:
    """Floor 0's emitters f* were surveyed only in the east part of floor 0; floor 1 was
    surveyed everywhere, with its own emitters g* and the floor-0 ones faint. A scan in
    the west of floor 0 hears f* fairly and g* faintly."""
    rng = np.random.default_rng(3)
    f_names, g_names = [f"f{i}" for i in range(6)], [f"g{i}" for i in range(6)]
    xy, floors, scans = [], [], []
    for x in np.linspace(60.0, 100.0, 20):  # floor 0, east only
        xy.append((x, 0.0))
        floors.append(0)
        scans.append(_keyed(list(-55.0 + rng.normal(0, 3, 6)), f_names))
    for x in np.linspace(0.0, 100.0, 40):  # floor 1, everywhere
        xy.append((x, 0.0))
        floors.append(1)
        values = list(-50.0 + rng.normal(0, 3, 6)) + list(-85.0 + rng.normal(0, 3, 3))
        scans.append(_keyed(values, g_names + f_names[:3]))
    smap = sm.build_scan_map(np.array(xy), np.array(floors), scans, min_readings=1)
    readings = [RadioReading(n, -62.0) for n in f_names] + [
        RadioReading(n, -88.0) for n in g_names[:2]
    ]
    found = sm.locate(smap, sm.query(smap, readings, "wifi"), sm.MatchParams())
    assert found is not None
    assert found.floor == 0
    assert found.floor_prob > 0.9


def test_rare_emitters_are_dropped_and_weights_fall_with_the_walks_that_heard_them() -> None:
    n = 1200  # 1 % of the scans is 12: emitters heard fewer than 10 times are dropped
    scans = [_keyed([-60.0, -70.0], ["common", "local"]) for _ in range(n)]
    for i in range(9):
        scans[i] = [*scans[i], ("wifi:passing", -40.0)]
    walks = np.repeat(np.arange(3), [600, 300, 300])
    smap = sm.build_scan_map(
        np.zeros((n, 2)), np.zeros(n, dtype=np.int64), scans, walk=walks, min_readings=10
    )
    assert smap.emitters == ("wifi:common", "wifi:local")
    np.testing.assert_allclose(smap.rarity, [3**-0.5, 3**-0.5])


def test_a_small_survey_keeps_what_it_heard() -> None:
    scans = [_keyed([-60.0], ["a"]), _keyed([-65.0], ["b"]), _keyed([-70.0], ["a"])]
    smap = sm.build_scan_map(np.zeros((3, 2)), np.zeros(3, dtype=np.int64), scans)
    assert smap.emitters == ("wifi:a", "wifi:b")
    # a scan outside any walk is a walk of its own
    np.testing.assert_allclose(smap.rarity, [2**-0.5, 1.0])


def test_a_reading_listed_twice_keeps_its_strongest() -> None:
    smap = sm.build_scan_map(
        np.zeros((1, 2)),
        np.zeros(1, dtype=np.int64),
        [_keyed([-70.0, -60.0], ["a", "a"])],
        min_readings=1,
    )
    assert smap.rssi_dbm.tolist() == [-60.0]


def test_no_shared_emitter_gives_no_fix() -> None:
    smap = _stale_pair_map(decay=0.88)
    q = sm.query(smap, [RadioReading("unknown", -50.0)], "wifi")
    assert q.n_matched == 0
    assert sm.locate(smap, q, sm.MatchParams()) is None
    # BLE readings never meet WiFi columns
    assert sm.query(smap, _query(QUERY), "ble").n_matched == 0


@given(
    st.lists(st.floats(-99.0, -20.0), min_size=10, max_size=10),
    st.integers(1, 12),
)
def test_the_fix_lies_within_its_neighbours_and_weights_sum_to_one(
    values: list[float], k: int
) -> None:
    rng = np.random.default_rng(0)
    n = 30
    xy = rng.uniform(0, 50, (n, 2))
    scans = [_keyed(list(rng.uniform(-90, -40, 10))) for _ in range(n)]
    smap = sm.build_scan_map(xy, rng.integers(0, 2, n), scans, min_readings=1)
    found = sm.locate(smap, sm.query(smap, _query(values), "wifi"), sm.MatchParams(k=k))
    assert found is not None
    assert found.weights.sum() == pytest.approx(1.0)
    near = xy[found.neighbours]
    assert near[:, 0].min() - 1e-9 <= found.x_m <= near[:, 0].max() + 1e-9
    assert near[:, 1].min() - 1e-9 <= found.y_m <= near[:, 1].max() + 1e-9
    assert np.all(np.diff(found.distances_db) >= 0)
    assert np.exp(found.floor_logp).sum() == pytest.approx(1.0)


def test_neighbours_stay_in_the_chosen_floors_building() -> None:
    """Floor 0 (building A) and floor 1 (building B, another frame) both hold scans near
    the query in signal; with the floors' buildings given, the position is A's alone."""
    xy = np.array([[0.0, 0.0], [2.0, 0.0], [500.0, 500.0], [502.0, 500.0]])
    scans = [_keyed(QUERY), _keyed([v - 1 for v in QUERY]), _keyed(QUERY), _keyed(QUERY)]
    smap = sm.build_scan_map(xy, np.array([0, 0, 1, 1]), scans, min_readings=1)
    q = sm.query(smap, _query(QUERY), "wifi")
    mixed = sm.locate(smap, q, sm.MatchParams(k=4))
    assert mixed is not None
    assert mixed.x_m > 100.0  # averaged over both buildings' frames
    prior = np.log(np.array([0.99, 0.01]))
    found = sm.locate(smap, q, sm.MatchParams(k=4), prior, floor_group=np.array([0, 1]))
    assert found is not None
    assert found.floor == 0
    assert set(found.neighbours.tolist()) == {0, 1}
    assert found.x_m <= 2.0


def test_a_floor_is_as_far_as_its_nearest_scans_including_those_hearing_nothing() -> None:
    """Floor 1 has five scans: one heard exactly what the phone hears, four none of it.
    Floor 0's five scans heard all ten emitters, 25 dB off. The floor's four nearest
    scans on floor 1 are mostly deaf to the phone: floor 0 is likelier."""
    xy = np.zeros((10, 2))
    floor0 = [_keyed([v - 25 for v in QUERY]) for _ in range(5)]
    floor1 = [_keyed(QUERY)] + [_keyed([-60.0], ["other"]) for _ in range(4)]
    smap = sm.build_scan_map(xy, np.array([0] * 5 + [1] * 5), floor0 + floor1, min_readings=1)
    score = sm.floor_scores(smap, sm.query(smap, _query(QUERY), "wifi"), sm.MatchParams(), 2)
    assert score[0] == 0.0
    assert score[1] < -1.0


def test_maps_merged_are_the_map_of_all_their_scans() -> None:
    rng = np.random.default_rng(5)
    n = 40
    xy = rng.uniform(0, 30, (n, 2))
    floors = rng.integers(0, 3, n)
    names = [f"e{i}" for i in range(14)]
    scans = [
        [(f"wifi:{e}", float(v)) for e, v in zip(names, rng.uniform(-90, -40, 14), strict=True)
         if rng.random() < 0.5]
        for _ in range(n)
    ]  # fmt: skip
    ages = [[float(a) for a in rng.uniform(0, 6000, len(s))] for s in scans]
    half = n // 2
    parts = [
        sm.build_scan_map(xy[sl], floors[sl], scans[sl], ages_ms=ages[sl], min_readings=1)
        for sl in (slice(0, half), slice(half, n))
    ]
    merged = sm.merge_scan_maps(parts)
    whole = sm.build_scan_map(xy, floors, scans, ages_ms=ages, min_readings=1)
    assert merged is not None
    assert merged.emitters == whole.emitters
    for name in ("xy_m", "floor", "indptr", "rows", "rssi_dbm", "fresh", "rarity", "totals"):
        np.testing.assert_allclose(getattr(merged, name), getattr(whole, name), err_msg=name)
    assert sm.merge_scan_maps(parts[:1]) is parts[0]
    assert sm.merge_scan_maps([]) is None
