"""Every engine follows a walk up the stairs and back down by lift within 5 s of the truth,
on two phones (different pressure offsets, weather drifts, rates and noise), where the
scans alone tell the floors apart only slowly (the two floors hear the same access
points, 3 dB apart). ``map_markov`` is left out: it needs a floor plan's graph."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from client_sim.imu import T0_MS, Block, Sensors, blocks, synthesize_walk
from server.positioning.engines import fai_ekf, pf_magnetic
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.model.events import (
    Event,
    Fix,
    ImuEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
    radio_key,
)
from server.positioning.motion.barometer import FloorChange
from server.positioning.radio.fingerprints import RadioMap

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
        pressure_hz=5.0, pressure_bias_hpa=-0.3, weather_hpa_per_h=-0.8, pressure_noise_hpa=0.02
    ),
}
# engine, and whether the phone posts raw motion samples or its own steps (and pressure)
ENGINES = (
    ("wknn", "steps"),
    ("step_ekf", "steps"),
    ("fai_ekf", "steps"),
    ("auto", "steps"),
    ("auto", "raw"),
    ("everywhere_ekf", "raw"),
    ("two_stage_ekf", "raw"),
    ("pf_magnetic", "raw"),
)


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


def walk(phone: Sensors, motion: str = "raw") -> tuple[list[Event], int]:
    """Back and forth along the corridor (east 20 s, west 20 s, ...), standing in the lift;
    a scan every 2 s from the true floor; blocks of a second with the barometer and, with
    ``motion="raw"``, the motion samples, else the phone's steps."""
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
    events: list[Event] = [imu_event(b, motion == "raw") for b in blocks(trace)]
    if motion == "steps":
        heading = np.interp(trace.step_t_ms, trace.t_ms, np.unwrap(trace.heading))
        events += [
            StepEvent(int(t), 0.7, float(h)) for t, h in zip(trace.step_t_ms, heading, strict=True)
        ]
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


def imu_event(block: Block, motion: bool) -> ImuEvent:
    if not motion:
        return ImuEvent(block.t_ms, pressure=block.pressure)
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


@pytest.mark.parametrize(("engine", "motion"), ENGINES)
@pytest.mark.parametrize("phone", PHONES.values(), ids=PHONES.keys())
def test_floor_follows_stairs_and_lift_within_5_s(engine: str, motion: str, phone: Sensors) -> None:
    events, t0 = walk(phone, motion)
    fixes = run(engine, events)

    def floors(start_s: float, end_s: float) -> set[int]:
        return {f.floor for f in fixes if t0 + 1000 * start_s <= f.t_ms < t0 + 1000 * end_s}

    assert floors(5.0, STAIRS[0]) == {0}
    assert 1 not in floors(0.0, (STAIRS[0] + STAIRS[1]) / 2)  # not before half the stairs
    assert first_on(fixes, t0, 1, STAIRS[1]) <= 5.0
    assert first_on(fixes, t0, 0, LIFT[1]) <= 5.0


@pytest.mark.parametrize(("engine", "motion"), ENGINES)
def test_without_the_barometer_the_scans_take_longer(engine: str, motion: str) -> None:
    # the control: the same walk with its pressure rows removed
    events, t0 = walk(Sensors(), motion)
    bare = [
        ImuEvent(e.t_ms, accel=e.accel, gyro=e.gyro, magnetic=e.magnetic, rotation=e.rotation)
        if isinstance(e, ImuEvent)
        else e
        for e in events
    ]
    fixes = run(engine, bare)
    assert first_on(fixes, t0, 1, STAIRS[1]) > 5.0
    assert first_on(fixes, t0, 0, LIFT[1]) > 5.0


def test_a_change_while_the_cloud_is_dead_moves_the_floor_filter() -> None:
    maps = two_floor_map()
    params = pf_magnetic.PfMagneticParams()
    state = replace(pf_magnetic.initial_state(params), floor_logp=np.log([0.9, 0.1]))
    assert state.cloud is None
    moved, fix = pf_magnetic._on_floor_change(
        state, FloorChange(T0_MS, 1), maps, params, np.random.default_rng(0)
    )
    assert fix is None
    np.testing.assert_allclose(np.exp(moved.floor_logp), [0.0, 1.0], atol=1e-12)


def test_fai_ekf_starts_a_new_profile_on_the_new_floor() -> None:
    maps = two_floor_map()
    params, rng = fai_ekf.FaiEkfParams(), np.random.default_rng(0)
    state = replace(
        fai_ekf.initial_state(params),
        floor=0,
        initialized=True,
        floor_logp=np.log([0.8, 0.2]),
        profile_xy=np.zeros((3, 2)),
        profile_ut=np.full(3, 45.0),
    )
    moved, fix = fai_ekf._on_floor_change(state, FloorChange(T0_MS, 1), maps, params, rng)
    assert fix is None
    assert moved.floor == 1
    assert moved.profile_ut.size == 0
    assert moved.profile_xy.shape == (0, 2)
    # a change to a floor the building does not have leaves the estimate where it was
    kept, _ = fai_ekf._on_floor_change(state, FloorChange(T0_MS, 3), maps, params, rng)
    assert kept.floor == 0
    assert kept.profile_ut.size == 3
