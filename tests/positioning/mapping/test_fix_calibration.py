"""Held-out radio fixes: each path located on a map built without it."""

from __future__ import annotations

import numpy as np

from server.positioning.mapping.fix_calibration import held_out_fixes, learn_fix_error


def survey(
    n_paths: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[list[tuple[str, float]]]]:
    """Paths along a 60 m x 20 m hall with 30 WiFi APs and 3 BLE beacons, a scan per
    metre, RSS by log-distance with 4 dB noise; the BLE scans hear only the beacons."""
    aps = rng.uniform([0, 0], [60, 20], (30, 2))
    beacons = np.array([[10.0, 10.0], [30.0, 10.0], [50.0, 10.0]])
    xy, floor, group, scans = [], [], [], []
    for p in range(n_paths):
        y = rng.uniform(2, 18)
        for x in np.arange(0.5, 60.0, 1.0):
            here = np.array([x, y])
            for kind, spots in (("wifi", aps), ("ble", beacons)):
                d = np.hypot(*(spots - here).T)
                rssi = -40.0 - 25.0 * np.log10(1.0 + d) + rng.normal(0, 4.0, d.size)
                scans.append([(f"{kind}:e{j}", float(v)) for j, v in enumerate(rssi)])
                xy.append(here)
                floor.append(0)
                group.append(p)
    return np.array(xy), np.array(floor), np.array(group), scans


def test_every_held_out_scan_is_located_without_its_own_path() -> None:
    rng = np.random.default_rng(0)
    xy, floor, group, scans = survey(10, rng)
    held = held_out_fixes(xy, floor, group, scans, np.random.default_rng(1), folds=5)
    assert len(held.kinds) == held.n_matched.size == held.error_m.size
    assert set(held.kinds) == {"wifi", "ble"}
    assert held.floor_ok.all()  # one floor
    # a scan located on a map holding its own readings would be near-exact; held out, not
    assert np.median(held.error_m) > 0.5
    wifi = np.asarray(held.kinds) == "wifi"
    assert np.all(held.n_matched[wifi] == 30)
    assert np.all(held.n_matched[~wifi] == 3)


def test_three_beacons_are_learned_to_be_worth_less_than_thirty_aps() -> None:
    rng = np.random.default_rng(2)
    xy, floor, group, scans = survey(10, rng)
    model = learn_fix_error(xy, floor, group, scans, np.random.default_rng(3))
    assert model.sigma("ble", 3) > model.sigma("wifi", 30)
    assert 0.3 < model.sigma("wifi", 30) < 10.0
