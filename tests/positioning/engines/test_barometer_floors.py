"""Every engine follows a walk up the stairs and back down by lift within 5 s of the truth,
on two phones of different pressure offsets, where the scans alone tell the floors apart
only slowly (the two floors hear the same access points, 3 dB apart)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from client_sim.imu import Block, Sensors, blocks, synthesize_walk
from server.positioning.engines import get_engine
from server.positioning.events import Event, Fix, ImuEvent, RadioReading, WifiEvent, radio_key
from server.positioning.fingerprint import RadioMap
from server.positioning.sitemaps import FloorRef, SiteMaps

FLOORS = (FloorRef("b", "ground", 0), FloorRef("b", "first", 1))
AP_XY = np.array([[x, y] for x in (0.0, 13.0, 26.0, 40.0) for y in (0.0, 6.0)])
FLOOR_DB = 3.0  # floor 1 hears every access point this much weaker
STOREY_M = 3.6
STAIRS = (30.0, 42.0)  # on floor 1 from 42 s
LIFT = (80.0, 86.0)  # back on floor 0 from 86 s
DURATION_S = 130.0
PHONES = {
    "phone reading 0.4 hPa high": Sensors(pressure_bias_hpa=0.4, weather_hpa_per_h=1.0),
    "phone reading 0.3 hPa low": Sensors(
        pressure_hz=5.0, pressure_bias_hpa=-0.3, weather_hpa_per_h=-0.8, pressure_noise_hpa=0.03
    ),
}
ENGINES = ("wknn", "step_ekf", "auto", "everywhere_ekf", "two_stage_ekf", "pf_magnetic")


def rssi(x_m: float, y_m: float, level: int) -> np.ndarray:
    d = np.maximum(np.hypot(AP_XY[:, 0] - x_m, AP_XY[:, 1] - y_m), 1.0)
    out: np.ndarray = -40.0 - 25.0 * np.log10(d) - FLOOR_DB * level
    return out


def two_floor_map() -> SiteMaps:
    xy = np.array([[x, y] for x in range(41) for y in range(7)], dtype=np.float32)
    both = np.vstack([xy, xy])
    floor = np.repeat([0, 1], len(xy)).astype(np.int32)
    mean = np.array(
        [rssi(float(x), float(y), int(f)) for (x, y), f in zip(both, floor, strict=True)]
    )
    radio = RadioMap(
        rp_xy=both,
        rp_floor=floor,
        mean_dbm=mean.astype(np.float32),
        var_db2=np.ones(mean.shape, dtype=np.float32),
        count=np.ones(mean.shape, dtype=np.int32),
        emitters=tuple(radio_key("wifi", f"02:00:00:00:00:{i:02x}") for i in range(len(AP_XY))),
    )
    return SiteMaps(FLOORS, radio, version="two floors")


def true_level(t_s: float) -> int:
    return int(STAIRS[1] <= t_s < LIFT[1])


def walk(phone: Sensors) -> tuple[list[Event], int]:
    """Back and forth along the corridor (east 20 s, west 20 s, ...), standing in the lift;
    a scan every 2 s from the true floor; IMU blocks of a second with the barometer."""
    turns = [[t, math.pi / 2 if (t // 20) % 2 == 0 else -math.pi / 2] for t in range(0, 140, 20)]
    height = [(STAIRS[0], 0.0), (STAIRS[1], STOREY_M), (LIFT[0], STOREY_M), (LIFT[1], 0.0)]
    walking = [(0.0, LIFT[0] - 2.0), (LIFT[1] + 2.0, DURATION_S)]
    trace = synthesize_walk(
        np.array(turns, dtype=np.float64),
        DURATION_S,
        np.random.default_rng(11),
        walking=walking,
        sensors=phone,
        height=height,
    )
    rng = np.random.default_rng(5)
    events: list[Event] = [imu_event(b) for b in blocks(trace)]
    for t_s in np.arange(1.0, DURATION_S, 2.0):
        i = int(np.searchsorted(trace.t_ms, trace.t0_ms + 1000 * t_s))
        x, y = 5.0 + trace.xy[i, 0] % 30.0, 3.0
        values = rssi(x, y, true_level(t_s)) + rng.normal(0.0, 2.0, len(AP_XY))
        readings = tuple(
            RadioReading(f"02:00:00:00:00:{k:02x}", float(round(v))) for k, v in enumerate(values)
        )
        events.append(WifiEvent(trace.t0_ms + int(1000 * t_s), readings))
    events.sort(key=lambda e: e.t_ms)
    return events, trace.t0_ms


def imu_event(block: Block) -> ImuEvent:
    return ImuEvent(
        block.t_ms,
        accel=block.accel,
        gyro=block.gyro,
        magnetic=block.magnetic,
        rotation=block.rotation,
        pressure=block.pressure,
    )


def run(engine: str, events: list[Event]) -> list[Fix]:
    spec = get_engine(engine)
    params = spec.params()
    state = spec.start(params)
    maps = two_floor_map()
    rng = np.random.default_rng(0)
    fixes: list[Fix] = []
    t0 = events[0].t_ms
    for k in range(0, math.ceil(DURATION_S)):  # one batch a second
        batch = [e for e in events if t0 + 1000 * k <= e.t_ms < t0 + 1000 * (k + 1)]
        state, out = spec.step(state, batch, maps, params, rng)
        fixes += out
    return fixes


def first_on(fixes: list[Fix], t0_ms: int, floor: int, after_s: float) -> float:
    """Seconds from ``after_s`` to the first fix on ``floor`` from which every fix until
    the next truth change is on it."""
    later = [f for f in fixes if f.t_ms >= t0_ms + 1000 * after_s]
    end = {STAIRS[1]: LIFT[1], LIFT[1]: DURATION_S}[after_s]
    within = [f for f in later if f.t_ms < t0_ms + 1000 * end]
    for i, f in enumerate(within):
        if all(g.floor == floor for g in within[i:]):
            return (f.t_ms - t0_ms) / 1000.0 - after_s
    return math.inf


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("phone", PHONES.values(), ids=PHONES.keys())
def test_floor_follows_stairs_and_lift_within_5_s(engine: str, phone: Sensors) -> None:
    events, t0 = walk(phone)
    fixes = run(engine, events)
    before = [f for f in fixes if f.t_ms < t0 + 1000 * STAIRS[0]]
    assert before
    assert before[-1].floor == 0
    assert first_on(fixes, t0, 1, STAIRS[1]) <= 5.0
    assert first_on(fixes, t0, 0, LIFT[1]) <= 5.0


def test_without_the_barometer_the_scans_take_longer() -> None:
    # the control: the same walk with its pressure rows removed
    events, t0 = walk(Sensors())
    bare = [
        ImuEvent(e.t_ms, accel=e.accel, gyro=e.gyro, magnetic=e.magnetic, rotation=e.rotation)
        if isinstance(e, ImuEvent)
        else e
        for e in events
    ]
    fixes = run("step_ekf", bare)
    assert first_on(fixes, t0, 1, STAIRS[1]) > 5.0
