"""A synthetic 60 m x 3 m corridor with a floor plan, a radio map and a known magnetic
field, and walks along it, for the engine tests (``pf_magnetic``, ``fai_ekf`` and the
contract every engine keeps).

Eight WiFi access points (``ap0`` .. ``ap7``) stand at x = 0, 20, 40, 60 m on both walls
with noiseless log-distance path loss (``rssi``); the radio map has a reference point
every metre at y = 0.5, 1.5, 2.5 m, and the field (``field_ut``) is smooth and
non-periodic along the corridor (``site_maps``). ``scan`` is what a phone hears at a
point; ``walk`` is 0.7 m steps east along y = 1.5 m, each with the field measured there;
``batches`` is six one-second batches of a walk with every kind of event.
"""

from __future__ import annotations

import math

import numpy as np

from client_sim.imu import blocks, synthesize_walk
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.magnetic.field_grid import MagneticMap
from server.positioning.mapping.magnetic_gridding import grid_from_samples
from server.positioning.model.events import (
    Event,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
    radio_key,
)
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.radio.fingerprints import RadioMap

T0 = 1_700_000_000_000
LENGTH_M, WIDTH_M = 60.0, 3.0
AP_XY = np.array([[x, y] for x in (0.0, 20.0, 40.0, 60.0) for y in (0.0, 3.0)])


def field_ut(x: np.ndarray) -> np.ndarray:
    """A smooth, non-periodic field along the corridor (µT)."""
    out: np.ndarray = (
        45.0 + 6.0 * np.sin(x / 3.1) + 4.0 * np.sin(x / 1.7 + 1.0) + 3.0 * np.cos(x / 7.3)
    )
    return out


def rssi(x: float, y: float) -> np.ndarray:
    d = np.maximum(np.hypot(AP_XY[:, 0] - x, AP_XY[:, 1] - y), 1.0)
    out: np.ndarray = -40.0 - 25.0 * np.log10(d)
    return out


def site_maps() -> SiteMaps:
    plan = plan_from_geojson(
        {
            "type": "FeatureCollection",
            "features": [
                {
                    "type": "Feature",
                    "properties": {"kind": "walkable"},
                    "geometry": {
                        "type": "Polygon",
                        "coordinates": [
                            [[0, 0], [LENGTH_M, 0], [LENGTH_M, WIDTH_M], [0, WIDTH_M], [0, 0]]
                        ],
                    },
                }
            ],
        }
    )
    gx, gy = np.meshgrid(np.arange(0.0, LENGTH_M, 0.25), np.arange(0.0, WIDTH_M, 0.25))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid_from_samples(xy, field_ut(xy[:, 0]), extent=(0.0, 0.0, LENGTH_M, WIDTH_M))
    rp = np.array([[x, y] for x in range(61) for y in (0.5, 1.5, 2.5)], dtype=np.float32)
    mean = np.array([rssi(float(x), float(y)) for x, y in rp], dtype=np.float32)
    radio = RadioMap(
        rp_xy=rp,
        rp_floor=np.zeros(len(rp), dtype=np.int32),
        mean_dbm=mean,
        var_db2=np.ones_like(mean),
        count=np.ones(mean.shape, dtype=np.int32),
        emitters=tuple(radio_key("wifi", f"ap{i}") for i in range(len(AP_XY))),
    )
    return SiteMaps(
        (FloorRef("b", "f0", 0),),
        radio,
        "v",
        plans=(plan,),
        magnetic=MagneticMap((grid,), "v"),
    )


def scan(t_ms: int, x: float, y: float) -> WifiEvent:
    readings = tuple(RadioReading(f"ap{i}", float(round(v))) for i, v in enumerate(rssi(x, y)))
    return WifiEvent(t_ms, readings)


def walk(start_x: float, n: int, rng: np.random.Generator, t0: int = T0) -> list[Event]:
    """Steps of 0.7 m east along y = 1.5, each with the field measured there (+ noise)."""
    events: list[Event] = []
    for i in range(1, n + 1):
        t = t0 + 600 * i
        x = start_x + 0.7 * i
        strength = float(field_ut(np.array([x]))[0] + rng.normal(0.0, 0.5))
        events += [MagEvent(t, magnitude_ut=strength), StepEvent(t, 0.7, math.pi / 2)]
    return events


def batches() -> list[list[Event]]:
    """Six one-second batches of a walk east along the corridor with all kinds of event:
    phone steps with the field, raw IMU samples and a scan each second."""
    rng = np.random.default_rng(11)
    trace = synthesize_walk(lambda t: np.full_like(t, math.pi / 2), 6.0, rng, t0_ms=T0)
    imu = [
        ImuEvent(b.t_ms, accel=b.accel, gyro=b.gyro, magnetic=b.magnetic, rotation=b.rotation)
        for b in blocks(trace, 1000.0)
    ]
    steps = walk(5.0, 10, rng, t0=T0)
    out: list[list[Event]] = []
    for k in range(6):
        lo, hi = T0 + 1000 * k, T0 + 1000 * (k + 1)
        batch: list[Event] = [scan(lo + 1, 5.0 + 0.7 * k, 1.5)]
        batch += [e for e in steps if lo <= e.t_ms < hi]
        batch += [e for e in imu if lo <= e.t_ms < hi]
        out.append(batch)
    return out
