"""The ``wknn`` engine on a toy two-floor map where the answer is known exactly.

Each floor has 3 x 3 reference points 2 m apart. Three WiFi access points per floor and
one BLE beacon per floor fade 6 dB per metre from their spot and 20 dB per floor crossed,
so every RP's fingerprint is distinct.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from server.positioning.engines.registry import ENGINES, get_engine
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.engines.step_ekf import StepEkfParams
from server.positioning.engines.wknn import SPEC, WknnParams, WknnState, initial_state
from server.positioning.model import state_codec
from server.positioning.model.events import (
    BleEvent,
    Event,
    Fix,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)
from server.positioning.radio import fix_error
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap, scan_vector, wknn

GRID = np.array([(x, y) for y in (0.0, 2.0, 4.0) for x in (0.0, 2.0, 4.0)])
# (key, x, y, floor) of each emitter
EMITTERS = (
    ("wifi:aa", 0.0, 0.0, 0),
    ("wifi:bb", 4.0, 0.0, 0),
    ("wifi:cc", 0.0, 4.0, 0),
    ("wifi:dd", 4.0, 4.0, 1),
    ("wifi:ee", 0.0, 4.0, 1),
    ("wifi:ff", 4.0, 0.0, 1),
    ("ble:b0", 0.0, 0.0, 0),
    ("ble:b1", 4.0, 4.0, 1),
)


def toy_map(with_ble: bool = True) -> RadioMap:
    emitters = [e for e in EMITTERS if with_ble or e[0].startswith("wifi:")]
    xy = np.concatenate([GRID, GRID])
    floor = np.repeat([0, 1], len(GRID))
    mean = np.empty((len(xy), len(emitters)))
    for j, (_, ex, ey, ef) in enumerate(emitters):
        d = np.hypot(xy[:, 0] - ex, xy[:, 1] - ey)
        mean[:, j] = -40.0 - 6.0 * d - 20.0 * np.abs(floor - ef)
    return RadioMap(
        rp_xy=xy.astype(np.float32),
        rp_floor=floor.astype(np.int32),
        mean_dbm=mean.astype(np.float32),
        var_db2=np.full(mean.shape, 4.0, dtype=np.float32),
        count=np.ones(mean.shape, dtype=np.int32),
        emitters=tuple(e[0] for e in emitters),
    )


FLOORS = (FloorRef("b", "f0", 0), FloorRef("b", "f1", 1))
MAPS = SiteMaps(floors=FLOORS, radio=toy_map(), version="toy")


def readings_of(radio_map: RadioMap, rp: int, kind: str) -> tuple[RadioReading, ...]:
    """The RP's fingerprint as a scan of the given kind."""
    prefix = f"{kind}:"
    return tuple(
        RadioReading(key.removeprefix(prefix).upper(), float(radio_map.mean_dbm[rp, j]))
        for j, key in enumerate(radio_map.emitters)
        if key.startswith(prefix) and radio_map.mean_dbm[rp, j] > MISSING_DBM
    )


def run_all(
    events: list[Event], maps: SiteMaps = MAPS, params: WknnParams | None = None
) -> tuple[WknnState, list[Fix]]:
    p = params or WknnParams()
    return SPEC.run(initial_state(p), events, maps, p, np.random.default_rng(0))


@pytest.mark.parametrize("rp", [0, 4, 8, 9, 13, 17])
def test_a_scan_equal_to_a_fingerprint_gives_that_rp_and_floor(rp: int) -> None:
    assert MAPS.radio is not None
    state, fixes = run_all([WifiEvent(100, readings_of(MAPS.radio, rp, "wifi"))])
    assert len(fixes) == 1
    fix = fixes[0]
    assert (fix.x_m, fix.y_m) == pytest.approx(tuple(MAPS.radio.rp_xy[rp]), abs=1e-4)
    assert fix.floor == int(MAPS.radio.rp_floor[rp])
    assert fix.t_ms == 100
    assert fix.source == "wifi"
    assert fix.heading_rad is None
    # the variance is what a fix of six matched emitters is worth, not the eq 17 spread
    var = fix_error.DEFAULT.variance("wifi", 6)
    assert fix.cov == (var, 0.0, 0.0, var)
    assert fix.diagnostics["n_matched"] == 6.0
    assert fix.diagnostics["wknn_var_m2"] == pytest.approx(0.0, abs=1e-4)
    assert (state.floor, state.n_fixes, state.last_t_ms) == (fix.floor, 1, 100)
    assert state.floor_logp.shape == (2,)
    assert np.exp(state.floor_logp[fix.floor]) == pytest.approx(fix.diagnostics["floor_prob"])


@pytest.mark.parametrize(("rp", "floor"), [(0, 0), (17, 1)])
def test_ble_scans_give_ble_fixes(rp: int, floor: int) -> None:
    assert MAPS.radio is not None
    scan = BleEvent(5, readings_of(MAPS.radio, rp, "ble"))
    # two beacons are below the default evidence a fix needs
    assert run_all([scan])[1] == []
    _, fixes = run_all([scan], params=WknnParams(min_matched=1))
    assert len(fixes) == 1
    assert fixes[0].source == "ble"
    assert fixes[0].floor == floor
    assert (fixes[0].x_m, fixes[0].y_m) == pytest.approx(tuple(MAPS.radio.rp_xy[rp]), abs=1e-4)


def test_ble_scans_give_nothing_on_a_map_without_ble_columns() -> None:
    maps = SiteMaps(floors=FLOORS, radio=toy_map(with_ble=False), version="wifi-only")
    state, fixes = run_all([BleEvent(5, readings_of(toy_map(), 0, "ble"))], maps=maps)
    assert fixes == []
    assert state.n_fixes == 0


def test_fix_is_the_wknn_of_the_scan_with_the_variance_floor() -> None:
    assert MAPS.radio is not None
    rng = np.random.default_rng(4)
    scan = tuple(
        RadioReading(r.emitter, r.rssi_dbm + float(rng.normal(0.0, 6.0)))
        for r in readings_of(MAPS.radio, 4, "wifi")
    )
    params = WknnParams(k=3, min_fix_var_m2=0.01)
    _, fixes = run_all([WifiEvent(0, scan)], params=params)
    expected = wknn(MAPS.radio, scan_vector(MAPS.radio, scan, "wifi"), k=3)
    assert expected is not None
    var = max(fix_error.DEFAULT.variance("wifi", 6), 0.01)
    assert (fixes[0].x_m, fixes[0].y_m, fixes[0].floor) == (
        expected.x_m,
        expected.y_m,
        expected.floor,
    )
    assert fixes[0].cov == (var, 0.0, 0.0, var)


def test_one_fix_per_scan_in_time_order_other_events_ignored() -> None:
    assert MAPS.radio is not None
    events: list[Event] = [
        WifiEvent(300, readings_of(MAPS.radio, 13, "wifi")),
        StepEvent(150, 0.7, 0.0),
        MagEvent(160, magnitude_ut=45.0),
        WifiEvent(100, readings_of(MAPS.radio, 2, "wifi")),
        WifiEvent(200, (RadioReading("unknown", -50.0),)),  # hears no map column
    ]
    state, fixes = run_all(events)
    assert [f.t_ms for f in fixes] == [100, 300]
    assert [f.floor for f in fixes] == [0, 1]
    assert (state.floor, state.n_fixes, state.last_t_ms) == (1, 2, 300)


def test_no_map_no_fixes() -> None:
    maps = SiteMaps(floors=FLOORS, radio=None, version="empty")
    state, fixes = run_all([WifiEvent(10, (RadioReading("aa", -50.0),))], maps=maps)
    assert fixes == []
    assert state.n_fixes == 0
    assert state.floor == -1


def test_state_round_trips_through_arrays_and_batches_compose() -> None:
    assert MAPS.radio is not None
    events: list[Event] = [
        WifiEvent(100 * i, readings_of(MAPS.radio, rp, "wifi"))
        for i, rp in enumerate([0, 5, 10, 15], start=1)
    ]
    params = WknnParams()
    state, first = SPEC.run(
        initial_state(params), events[:2], MAPS, params, np.random.default_rng(1)
    )
    arrays = state_codec.to_arrays(state)
    assert all(np.issubdtype(a.dtype, np.number) for a in arrays.values())
    restored = state_codec.from_arrays(WknnState, arrays)
    assert state_codec.to_arrays(restored).keys() == arrays.keys()
    for key, value in state_codec.to_arrays(restored).items():
        np.testing.assert_array_equal(value, arrays[key])
    state, second = SPEC.run(restored, events[2:], MAPS, params, np.random.default_rng(2))
    whole_state, whole = run_all(events)
    assert (state.floor, state.n_fixes, state.last_t_ms) == (1, 4, 400)
    np.testing.assert_array_equal(state.floor_logp, whole_state.floor_logp)
    assert first + second == whole


def test_registered_in_engines() -> None:
    assert ENGINES["wknn"] is SPEC
    assert get_engine("wknn").name == "wknn"
    assert SPEC.params_type is WknnParams
    assert (
        state_codec.to_arrays(SPEC.initial_state(WknnParams())).keys()
        == state_codec.to_arrays(WknnState()).keys()
    )
    assert SPEC.uses == frozenset({"wifi", "ble", "pressure"})


def test_defaults_match_step_ekf() -> None:
    ours, theirs = WknnParams(), StepEkfParams()
    assert ours.k == theirs.k
    assert ours.min_fix_var_m2 == theirs.min_fix_var_m2


@pytest.mark.parametrize(
    "change", [{"k": 0}, {"min_fix_var_m2": 0.0}, {"min_fix_var_m2": float("nan")}]
)
def test_bad_params_are_refused(change: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match=next(iter(change))):
        dataclasses.replace(WknnParams(), **change)


def test_two_beacons_are_worth_far_less_than_a_hundred_access_points() -> None:
    # a corridor 100 m long: 100 WiFi APs and 2 BLE beacons, RSS falling with distance
    xy = np.column_stack([np.arange(100.0), np.zeros(100)])
    aps = np.column_stack([np.arange(100.0), np.full(100, 3.0)])
    beacons = np.array([[20.0, 0.0], [80.0, 0.0]])
    spots = np.concatenate([aps, beacons])
    d = np.hypot(xy[:, None, 0] - spots[None, :, 0], xy[:, None, 1] - spots[None, :, 1])
    mean = -40.0 - 20.0 * np.log10(1.0 + d)
    keys = (*tuple(f"wifi:ap{j}" for j in range(100)), "ble:b0", "ble:b1")
    radio = RadioMap(
        rp_xy=xy.astype(np.float32),
        rp_floor=np.zeros(100, dtype=np.int32),
        mean_dbm=mean.astype(np.float32),
        var_db2=np.full(mean.shape, 4.0, dtype=np.float32),
        count=np.ones(mean.shape, dtype=np.int32),
        emitters=keys,
    )
    maps = SiteMaps(floors=(FloorRef("b", "f0", 0),), radio=radio, version="corridor")
    rp = 50
    wifi = WifiEvent(1, tuple(RadioReading(f"ap{j}", float(mean[rp, j])) for j in range(100)))
    ble = BleEvent(
        2, (RadioReading("b0", float(mean[rp, 100])), RadioReading("b1", float(mean[rp, 101])))
    )
    _, wifi_fixes = run_all([wifi], maps=maps)
    assert len(wifi_fixes) == 1
    # the default wants more than two emitters for a fix at all
    assert run_all([ble], maps=maps)[1] == []
    # allowed one anyway, the BLE fix claims a far larger uncertainty
    _, ble_fixes = run_all([ble], maps=maps, params=WknnParams(min_matched=1))
    assert len(ble_fixes) == 1
    assert ble_fixes[0].uncertainty_m > 2.0 * wifi_fixes[0].uncertainty_m
