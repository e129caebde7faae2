"""The barometric floor-change detector on simulated phones: stairs, lifts, landings,
weather, phone offsets; the floor spacing learned from walks; the floor filter's shift."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from client_sim.imu import Sensors, synthesize_walk
from server.positioning.motion import barometer
from server.positioning.motion.barometer import BaroParams, FloorChange
from server.positioning.radio import floor_hmm

STOREY_M = 3.6  # 0.43 hPa near sea level
PHONES = {
    "offset up, weather rising, 25 Hz": Sensors(pressure_bias_hpa=0.4, weather_hpa_per_h=1.0),
    "offset down, weather falling, 5 Hz": Sensors(
        pressure_hz=5.0, pressure_bias_hpa=-0.3, weather_hpa_per_h=-0.8, pressure_noise_hpa=0.02
    ),
}


def pressure(
    height: list[tuple[float, float]] | None, duration_s: float, sensors: Sensors
) -> np.ndarray:
    trace = synthesize_walk(
        [[0.0, 0.0]], duration_s, np.random.default_rng(7), sensors=sensors, height=height
    )
    return trace.pressure


def detect(samples: np.ndarray, block: int = 25, spacing: float = 0.43) -> list[FloorChange]:
    state, changes = barometer.initial_barometer(), []
    for k in range(0, samples.shape[0], block):
        state, found = barometer.advance(state, samples[k : k + block], spacing, BaroParams())
        changes += found
    return changes


def seconds(change: FloorChange, samples: np.ndarray) -> float:
    return (change.t_ms - float(samples[0, 0])) / 1000.0


@pytest.mark.parametrize("phone", PHONES.values(), ids=PHONES.keys())
def test_up_the_stairs_and_down_by_lift(phone: Sensors) -> None:
    # stairs 30-42 s (0.3 m/s), floor 1 until the lift rides down 80-86 s
    height = [(30.0, 0.0), (42.0, STOREY_M), (80.0, STOREY_M), (86.0, 0.0)]
    samples = pressure(height, 120.0, phone)
    changes = detect(samples)
    assert [c.floors for c in changes] == [1, -1]
    assert 42.0 <= seconds(changes[0], samples) <= 47.0
    assert 86.0 <= seconds(changes[1], samples) <= 91.0


def test_a_landing_half_way_is_not_a_floor() -> None:
    # two flights with a 2 s landing between them: one floor, once
    height = [(20.0, 0.0), (26.0, 1.8), (28.0, 1.8), (34.0, STOREY_M)]
    samples = pressure(height, 60.0, Sensors())
    changes = detect(samples)
    assert [c.floors for c in changes] == [1]
    assert seconds(changes[0], samples) >= 34.0


def test_three_floors_by_lift_count_as_three() -> None:
    height = [(20.0, 0.0), (30.0, 3 * STOREY_M)]
    samples = pressure(height, 50.0, Sensors())
    assert [c.floors for c in detect(samples)] == [3]


def test_weather_alone_changes_no_floor() -> None:
    # half an hour on one floor while a storm front moves the pressure by 2 hPa
    samples = pressure(None, 1800.0, Sensors(pressure_hz=5.0, weather_hpa_per_h=-4.0))
    assert detect(samples, block=50) == []


@pytest.mark.parametrize(
    ("storey_m", "spacing"),
    [(2.6, barometer.DEFAULT_SPACING_HPA), (4.5, barometer.DEFAULT_SPACING_HPA), (5.0, 0.6)],
)
def test_storeys_taller_or_lower_than_the_spacing_count_one_by_one(
    storey_m: float, spacing: float
) -> None:
    # three flights up with a pause on each floor; the default spacing (a 3.2 m storey)
    # counts one floor right for storeys of 1.9-4.75 m, taller ones need the site's
    height = [
        (20.0 + 30.0 * k + d, (k + f) * storey_m) for k in range(3) for d, f in ((0, 0), (8, 1))
    ]
    samples = pressure(height, 120.0, Sensors())
    changes = detect(samples, spacing=spacing)
    assert [c.floors for c in changes] == [1, 1, 1]


def test_half_way_up_and_back_is_no_floor() -> None:
    height = [(20.0, 0.0), (25.0, 1.5), (35.0, 1.5), (40.0, 0.0)]
    samples = pressure(height, 60.0, Sensors(pressure_hz=5.0, pressure_noise_hpa=0.02))
    assert detect(samples) == []


def test_after_a_long_silence_the_weather_is_no_floor_change() -> None:
    # the phone stops sending for 20 minutes while the weather moves 0.33 hPa (1 hPa/h)
    samples = pressure(None, 1500.0, Sensors(pressure_hz=5.0, weather_hpa_per_h=1.0))
    t = (samples[:, 0] - samples[0, 0]) / 1000.0
    heard = samples[(t < 60.0) | (t > 1260.0)]
    assert detect(heard) == []


def test_live_once_the_anchor_has_held_and_while_samples_come() -> None:
    samples = pressure(None, 60.0, Sensors())
    params = BaroParams()
    state, _ = barometer.advance(barometer.initial_barometer(), samples, 0.43, params)
    t0 = int(samples[0, 0])
    assert not barometer.live(barometer.initial_barometer(), t0, params)
    assert not barometer.live(state, t0 + 20_000, params)  # anchored at about 2 s
    assert barometer.live(state, t0 + 40_000, params)
    assert not barometer.live(state, t0 + 75_000, params)  # nothing heard for 15 s


def test_a_block_sent_twice_counts_once() -> None:
    samples = pressure([(10.0, 0.0), (16.0, STOREY_M)], 30.0, Sensors())
    state, changes = barometer.initial_barometer(), []
    for k in range(0, samples.shape[0], 25):
        for _ in range(2):
            state, found = barometer.advance(state, samples[k : k + 25], 0.43, BaroParams())
            changes += found
    assert [c.floors for c in changes] == [1]


def test_floor_spacing_from_walks_that_change_floor() -> None:
    walks = []
    for bias, floors in ((0.5, (0, 1, 2)), (-0.4, (0, -1))):
        trace = synthesize_walk(
            [[0.0, 0.0]],
            90.0,
            np.random.default_rng(3),
            sensors=Sensors(pressure_bias_hpa=bias),
            height=[
                (28.0, 0.0),
                (32.0, floors[1] * STOREY_M),
                (58.0, floors[1] * STOREY_M),
                (62.0, floors[-1] * STOREY_M),
            ],
        )
        t = trace.t0_ms + 1000 * np.array([0, 25, 35, 55, 65, 88])
        level = np.array([floors[0], floors[0], floors[1], floors[1], floors[-1], floors[-1]])
        walks.append((trace.pressure, t, level))
    spacing = barometer.floor_spacing(walks)
    assert spacing is not None
    assert spacing == pytest.approx(0.43, abs=0.01)
    single = [(walks[0][0], walks[0][1][:2], walks[0][2][:2])]
    assert barometer.floor_spacing(single) is None
    # one walk whose floor labels are off cannot make the spacing absurd
    flat = [(walks[0][0], walks[0][1], walks[0][2] * 10)]
    assert barometer.floor_spacing(flat) == barometer.SPACING_RANGE_HPA[0]


@given(
    p=st.lists(st.floats(0.01, 1.0), min_size=3, max_size=3),
    floors=st.integers(-3, 3),
)
def test_shift_moves_each_floor_by_its_level(p: list[float], floors: int) -> None:
    logp = np.log(np.array(p) / sum(p))
    levels = np.array([-1, 0, 1])
    shifted = floor_hmm.shift(logp, floors, levels, np.zeros(3, dtype=np.int64))
    assert math.isclose(float(np.exp(shifted).sum()), 1.0, rel_tol=1e-9)
    if abs(floors) >= 3 or floors == 0:
        np.testing.assert_allclose(shifted, logp)
        return
    kept = [i for i in range(3) if 0 <= i + floors < 3]
    expected = np.zeros(3)
    expected[[i + floors for i in kept]] = np.exp(logp[kept]) / np.exp(logp[kept]).sum()
    np.testing.assert_allclose(np.exp(shifted), expected, atol=1e-12)


def test_shift_stays_in_the_building() -> None:
    # floor indices 0, 1 in building 0 at levels 0, 1; index 2 in building 1 at level 1
    logp = np.log(np.array([0.7, 0.1, 0.2]))
    shifted = floor_hmm.shift(logp, 1, np.array([0, 1, 1]), np.array([0, 0, 1]))
    np.testing.assert_allclose(np.exp(shifted), [0.0, 1.0, 0.0], atol=1e-12)
