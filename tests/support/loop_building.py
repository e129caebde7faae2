"""A synthetic two-floor building and a walk round a loop in it, for the engine tests
(``step_ekf``, ``map_markov``, ``auto``).

The building is 40 m x 20 m with eight WiFi access points per floor and log-distance
path loss (P0 = -35 dBm at 1 m, exponent 3, 4 m between floors, 15 dB per floor crossed).
A survey every metre (two samples a point, 2 dB noise) is gridded into the radio map with
``build_radio_map`` (``MAPS``). A walker goes round a 30 m x 10 m loop with 0.7 m steps;
the phone reports each step with 5 % length noise and 5 deg heading noise, and a WiFi
scan (5 dB noise, nothing below -90 dBm) every third step (``loop_walk``). ``errors`` and
``wknn_errors`` measure fixes, and WKNN alone, against the walk's truth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.mapping.gridding import build_radio_map
from server.positioning.model.events import Event, Fix, RadioReading, StepEvent, WifiEvent
from server.positioning.radio.fingerprints import scan_vector, wknn

FloatArray = NDArray[np.float64]

WIDTH_M, DEPTH_M, FLOOR_HEIGHT_M = 40.0, 20.0, 4.0
AP_XY = np.array(
    [(2, 2), (20, 2), (38, 2), (2, 18), (20, 18), (38, 18), (11, 10), (29, 10)], dtype=float
)
N_FLOORS = 2
BSSIDS = tuple(f"02:00:00:00:{f:02x}:{i:02x}" for f in range(N_FLOORS) for i in range(len(AP_XY)))
STEP_M = 0.7
LOOP = np.array([(5.0, 5.0), (35.0, 5.0), (35.0, 15.0), (5.0, 15.0), (5.0, 5.0)])


def true_rssi(xy: FloatArray, floor: int) -> FloatArray:
    """Noise-free RSS, shape (n, n_aps over all floors)."""
    columns = []
    for ap_floor in range(N_FLOORS):
        dz = FLOOR_HEIGHT_M * abs(ap_floor - floor)
        d = np.sqrt(np.sum((xy[:, None, :] - AP_XY[None, :, :]) ** 2, axis=2) + dz**2)
        columns.append(-35.0 - 30.0 * np.log10(np.maximum(d, 1.0)) - 15.0 * abs(ap_floor - floor))
    return np.concatenate(columns, axis=1)


def noisy_rssi(rssi: FloatArray, sigma_db: float, rng: np.random.Generator) -> FloatArray:
    heard = rssi + rng.normal(0.0, sigma_db, rssi.shape)
    return np.where(heard < -90.0, np.nan, heard)


def building_maps() -> SiteMaps:
    rng = np.random.default_rng(2024)
    xs, ys = np.meshgrid(np.arange(0.5, WIDTH_M), np.arange(0.5, DEPTH_M))
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    xy, floor, rssi = [], [], []
    for f in range(N_FLOORS):
        for _ in range(2):
            xy.append(grid)
            floor.append(np.full(len(grid), f))
            rssi.append(noisy_rssi(true_rssi(grid, f), 2.0, rng))
    radio = build_radio_map(
        np.concatenate(xy),
        np.concatenate(floor),
        np.concatenate(rssi),
        tuple(f"wifi:{b}" for b in BSSIDS),
    )
    floors = tuple(FloorRef("b1", f"f{f}", f) for f in range(N_FLOORS))
    return SiteMaps(floors=floors, radio=radio, version="test")


MAPS = building_maps()


def scan_at(
    xy: Sequence[float] | FloatArray, floor: int, t_ms: int, rng: np.random.Generator
) -> WifiEvent:
    rssi = noisy_rssi(true_rssi(np.array([xy], dtype=float), floor), 5.0, rng)[0]
    return WifiEvent(
        t_ms,
        tuple(
            RadioReading(b.upper(), float(v))
            for b, v in zip(BSSIDS, rssi, strict=True)
            if not np.isnan(v)
        ),
    )


@dataclass(frozen=True)
class Walk:
    events: list[Event]
    truth: dict[int, FloatArray]  # true position at each event time


def loop_walk(seed: int, laps: int = 2) -> Walk:
    """Steps round the loop and a scan every third step, starting with a scan."""
    rng = np.random.default_rng(seed)
    seg = np.diff(LOOP, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    total = laps * seg_len.sum()
    s = np.arange(0.0, total, STEP_M) % seg_len.sum()
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    i = np.searchsorted(cum, s, side="right") - 1
    pos = LOOP[i] + seg[i] * ((s - cum[i]) / seg_len[i])[:, None]
    events: list[Event] = [scan_at(pos[0], 0, 0, rng)]
    truth = {0: pos[0]}
    for k in range(1, len(pos)):
        t = 500 * k
        d = pos[k] - pos[k - 1]
        heading = math.atan2(d[0], d[1]) + rng.normal(0.0, math.radians(5.0))
        length = float(np.linalg.norm(d)) * (1.0 + rng.normal(0.0, 0.05))
        events.append(StepEvent(t, length, heading))
        truth[t] = pos[k]
        if k % 3 == 0:
            events.append(scan_at(pos[k], 0, t + 1, rng))
            truth[t + 1] = pos[k]
    return Walk(events, truth)


def errors(fixes: Sequence[Fix], truth: dict[int, FloatArray]) -> FloatArray:
    return np.array([math.dist((f.x_m, f.y_m), truth[f.t_ms]) for f in fixes])


def wknn_errors(walk: Walk) -> FloatArray:
    assert MAPS.radio is not None
    out = []
    for e in walk.events:
        if isinstance(e, WifiEvent):
            fix = wknn(MAPS.radio, scan_vector(MAPS.radio, e.readings, "wifi"))
            assert fix is not None
            out.append(math.dist((fix.x_m, fix.y_m), walk.truth[e.t_ms]))
    return np.array(out)
