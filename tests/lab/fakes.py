"""Recorded data made up for the lab's tests."""

from __future__ import annotations

from typing import Any

import numpy as np

from server.datasets.ilc import IlcTrace


def ilc_trace(**fields: Any) -> IlcTrace:
    """A trace of one path on floor F1 with three waypoints and nothing else, but for
    ``fields``."""
    none = np.zeros((0, 4))
    default: dict[str, Any] = {
        "path_id": "p",
        "floor": "F1",
        "site_id": None,
        "waypoint_t_ms": np.array([100, 200, 300], dtype=np.int64),
        "waypoint_xy_m": np.array([[0.0, 0.0], [5.0, 0.0], [9.0, 0.0]]),
        "wifi": (),
        "ble": (),
        "accel": none,
        "gyro": none,
        "magnetic": none,
        "rotation": none,
        "uncalibrated": frozenset(),
        "bad_lines": 0,
        "joined_lines": 0,
        "stale_wifi_readings": 0,
        "skipped_types": {},
        "t_first_ms": 0,
        "t_last_ms": 300,
    }
    return IlcTrace(**{**default, **fields})
