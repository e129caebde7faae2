"""Recorded data made up for the lab's tests."""

from __future__ import annotations

from typing import Any

import numpy as np

from lab.datasets.uji import Fingerprints
from server.positioning.model.walk import Walk


def ilc_trace(**fields: Any) -> Walk:
    """A trace of one path on floor F1 with three waypoints and nothing else, but for
    ``fields``."""
    none = np.zeros((0, 4))
    default: dict[str, Any] = {
        "path_id": "p",
        "floor": "F1",
        "waypoint_t_ms": np.array([100, 200, 300], dtype=np.int64),
        "waypoint_xy_m": np.array([[0.0, 0.0], [5.0, 0.0], [9.0, 0.0]]),
        "wifi": (),
        "ble": (),
        "accel": none,
        "gyro": none,
        "magnetic": none,
        "rotation": none,
        "uncalibrated": frozenset(),
        "t_first_ms": 0,
        "t_last_ms": 300,
    }
    return Walk(**{**default, **fields})


UJI_AP_XY = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0], [15.0, 15.0]])


def uji_fingerprints(
    xy_m: np.ndarray, phone_id: np.ndarray, offset_db: np.ndarray, rng: np.random.Generator
) -> Fingerprints:
    """Scans on one floor of one building from a log-distance field of five access points,
    each phone reading ``offset_db`` above it, with 2 dB noise."""
    d = np.linalg.norm(xy_m[:, None, :] - UJI_AP_XY[None, :, :], axis=2)
    rssi = -35.0 - 25.0 * np.log10(np.maximum(d, 1.0)) + offset_db[:, None]
    rssi += rng.normal(0.0, 2.0, rssi.shape)
    n = xy_m.shape[0]
    return Fingerprints(
        rssi_dbm=np.round(rssi).astype(np.float32),
        emitters=tuple(f"WAP{j + 1:03d}" for j in range(UJI_AP_XY.shape[0])),
        xy_m=xy_m.astype(np.float64),
        floor=np.zeros(n, dtype=np.int64),
        building=np.zeros(n, dtype=np.int64),
        t_s=np.zeros(n, dtype=np.int64),
        phone_id=phone_id.astype(np.int64),
    )


def uji_offset_sets() -> tuple[Fingerprints, Fingerprints]:
    """Training: phone 1 (true level) surveys a 3 m grid twice; phone 2 (+8 dB) surveys its
    left third beside it. Test: phone 2 all over the floor, and phone 3 (unknown) a bit."""
    rng = np.random.default_rng(11)
    grid = np.array([(x, y) for x in range(0, 31, 3) for y in range(0, 31, 3)], dtype=float)
    left = grid[grid[:, 0] <= 9.0]
    xy = np.concatenate([grid, grid, left, left])
    phone = np.array([1] * (2 * len(grid)) + [2] * (2 * len(left)))
    train = uji_fingerprints(xy, phone, np.where(phone == 2, 8.0, 0.0), rng)
    test_xy = rng.uniform(0.0, 30.0, (60, 2))
    test_phone = np.array([2] * 50 + [3] * 10)
    test = uji_fingerprints(test_xy, test_phone, np.where(test_phone == 2, 8.0, 0.0), rng)
    return train, test
