"""Radio model: path loss falls with distance, floors and walls; shadowing fixed, noise not."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from client_sim.building import SyntheticBuilding, count_crossings, synthesize_building
from client_sim.radio import WIFI, PathLoss, RadioEnvironment, synthesize_radio

QUIET = PathLoss(tx_sigma_db=0.0, shadow_sigma_db=0.0, wall_loss_db=0.0)


@pytest.fixture(scope="module")
def building() -> SyntheticBuilding:
    return synthesize_building(np.random.default_rng(0))


def radio(building: SyntheticBuilding, seed: int = 1, wifi: PathLoss = WIFI) -> RadioEnvironment:
    return synthesize_radio(building, np.random.default_rng(seed), wifi=wifi)


def around(centre: np.ndarray, r_m: float, n: int = 64) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.asarray(centre + r_m * np.column_stack([np.sin(a), np.cos(a)]), dtype=np.float64)


def test_placement_covers_every_floor_with_unique_ids(building: SyntheticBuilding) -> None:
    env = radio(building)
    assert len(env.wifi) == 36
    assert len(env.ble) == 8
    assert sorted(set(env.wifi.level.tolist())) == [0, 1]
    assert len(set(env.wifi.ids)) == len(env.wifi.ids)
    assert len(set(env.ble.ids)) == len(env.ble.ids)
    assert np.all((env.wifi.xy >= 0) & (env.wifi.xy <= [60.0, 30.0]))
    for level in (0, 1):
        on_level = env.ble.xy[env.ble.level == level]
        assert np.all(building.floor(level).contains(on_level))


def test_without_shadowing_the_mean_is_the_log_distance_law(building: SyntheticBuilding) -> None:
    env = radio(building, wifi=QUIET)
    ap = env.wifi.xy[0]
    level = int(env.wifi.level[0])
    for r in (0.5, 1.0, 2.0, 10.0, 30.0):
        mean = env.wifi.mean_rssi_dbm(around(ap, r, 8), level)[:, 0]
        expected = -40.0 - 28.0 * np.log10(max(r, 1.0))
        assert mean == pytest.approx(np.full(8, expected))
    # one level up: the floor loss and the extra 4 m of distance
    above = env.wifi.mean_rssi_dbm(ap[None, :], level + 1)[0, 0]
    assert above == pytest.approx(-40.0 - 15.0 - 28.0 * np.log10(4.0))


def test_rss_falls_with_distance_in_expectation(building: SyntheticBuilding) -> None:
    """Averaged over emitters and directions (over the shadowing), with walls and noise."""
    env = radio(building)
    means = []
    for r in (1.5, 3.0, 6.0, 12.0, 24.0):
        values = [
            env.wifi.mean_rssi_dbm(around(env.wifi.xy[j], r), int(env.wifi.level[j]))[:, j]
            for j in range(len(env.wifi))
        ]
        means.append(float(np.mean(values)))
    assert all(a > b for a, b in itertools.pairwise(means))
    assert means[0] - means[-1] > 20.0


def test_walls_cost_wall_loss_each(building: SyntheticBuilding) -> None:
    walled = radio(building, wifi=PathLoss(tx_sigma_db=0, shadow_sigma_db=0, wall_loss_db=3.0))
    open_plan = radio(building, wifi=QUIET)
    points = building.floor(0).walkable_grid(3.0)
    crossings = count_crossings(
        points[:, None, :], walled.wifi.xy[None, :, :], building.floor(0).walls
    )
    difference = open_plan.wifi.mean_rssi_dbm(points, 0) - walled.wifi.mean_rssi_dbm(points, 0)
    assert difference == pytest.approx(3.0 * crossings)
    assert crossings.max() > 0


def test_shadowing_is_fixed_and_scan_noise_is_not(building: SyntheticBuilding) -> None:
    env = radio(building)
    points = building.floor(1).walkable_grid(4.0)
    assert np.array_equal(env.wifi.mean_rssi_dbm(points, 1), env.wifi.mean_rssi_dbm(points, 1))
    rng = np.random.default_rng(3)
    a, b = env.wifi.scan(points, 1, rng), env.wifi.scan(points, 1, rng)
    assert not np.array_equal(a, b, equal_nan=True)
    # scan noise: sigma_scan around the fixed mean (plus whole-dBm rounding) where heard
    near = env.wifi.mean_rssi_dbm(points, 1) > -75.0
    residual = np.concatenate([(s - env.wifi.mean_rssi_dbm(points, 1))[near] for s in (a, b)])
    assert np.mean(residual) == pytest.approx(0.0, abs=0.3)  # the scan's expectation is the mean
    assert np.std(residual) == pytest.approx(np.hypot(WIFI.scan_sigma_db, 12**-0.5), rel=0.1)
    # same generator state, same scan
    again = env.wifi.scan(points, 1, np.random.default_rng(3))
    assert np.array_equal(a, again, equal_nan=True)


def test_scans_drop_what_is_below_the_sensitivity(building: SyntheticBuilding) -> None:
    env = radio(building)
    points = building.floor(0).walkable_grid(2.0)
    rssi = env.wifi.scan(points, 0, np.random.default_rng(0))
    heard = rssi[~np.isnan(rssi)]
    assert heard.min() >= -95.0
    assert heard.max() <= 0.0
    assert np.isnan(rssi).any()
    assert np.array_equal(heard, np.round(heard))
    readings = env.wifi.readings(rssi[0])
    assert len(readings) == int(np.sum(~np.isnan(rssi[0])))
    assert all(
        set(r) == {"bssid", "rssi_dbm"} and isinstance(r["rssi_dbm"], float) for r in readings
    )
    ble = env.ble.readings(env.ble.scan(points[:1], 0, np.random.default_rng(0))[0])
    assert all(set(r) == {"id", "rssi_dbm"} for r in ble)


def test_same_seed_same_environment(building: SyntheticBuilding) -> None:
    a, b = radio(building, seed=5), radio(building, seed=5)
    assert a.wifi.ids == b.wifi.ids
    assert np.array_equal(a.wifi.xy, b.wifi.xy)
    p = building.floor(0).walkable_grid(5.0)
    assert np.array_equal(a.wifi.mean_rssi_dbm(p, 0), b.wifi.mean_rssi_dbm(p, 0))
    assert radio(building, seed=6).wifi.ids != a.wifi.ids
