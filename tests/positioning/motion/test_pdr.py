"""Step detection and step lengths on synthetic raw IMU.

The walks come from ``client_sim.imu``: a phone held in front, its top edge raised 20 deg,
swaying a few degrees; one vertical bounce cycle (2.5 m/s²) per step at 1.8 Hz, a
forward surge and a sideways sway; 50 Hz accelerometer with 0.05 m/s² of noise. The true
step time is the valley of each bounce cycle (what ``"mansour"`` reports), its peak half a
cycle earlier (what ``"cui"`` and ``"wang"`` report).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from client_sim.imu import Gait, ImuTrace, Sensors, synthesize_walk
from server.positioning.model import state_codec
from server.positioning.motion.pdr import (
    Detector,
    DetectorState,
    G,
    PdrParams,
    Steps,
    calibrated_step_m,
    detect_steps,
    initial_detector,
    step_lengths,
)

FloatArray = NDArray[np.float64]

DETECTORS: tuple[Detector, ...] = ("mansour", "cui", "wang")
HAND_HELD = Gait(
    tilt_x_rad=math.radians(20.0),
    heading_sway_rad=math.radians(3.0),
    sway_x_rad=math.radians(2.0),
    sway_y_rad=math.radians(2.0),
)


@cache
def walk(
    walking: tuple[tuple[float, float], ...] = ((2.0, 62.0),),
    duration_s: float = 64.0,
    seed: int = 0,
) -> ImuTrace:
    return synthesize_walk(
        [(0.0, 0.3)], duration_s, np.random.default_rng(seed), walking=walking, gait=HAND_HELD
    )


def reported_instant(trace: ImuTrace, detector: Detector) -> NDArray[np.int64]:
    return trace.step_t_ms if detector == "mansour" else trace.peak_t_ms  # cui, wang: peaks


def detect_in_chunks(
    accel: FloatArray, cuts: list[int], params: PdrParams
) -> tuple[DetectorState, list[Steps]]:
    state = initial_detector()
    found = []
    for lo, hi in zip([0, *cuts], [*cuts, accel.shape[0]], strict=True):
        state, steps = detect_steps(state, accel[lo:hi], params)
        found.append(steps)
    return state, found


def joined(found: list[Steps]) -> Steps:
    return Steps(
        np.concatenate([s.t_ms for s in found]),
        np.concatenate([s.accel_range for s in found]),
        np.concatenate([s.gravity for s in found]),
    )


def assert_same_steps(a: Steps, b: Steps) -> None:
    np.testing.assert_array_equal(a.t_ms, b.t_ms)
    np.testing.assert_array_equal(a.accel_range, b.accel_range)
    np.testing.assert_array_equal(a.gravity, b.gravity)


# --- step detection -------------------------------------------------------------------------


@pytest.mark.parametrize("detector", DETECTORS)
@pytest.mark.parametrize(
    "walking",
    [((2.0, 62.0),), ((3.0, 13.0), (20.0, 31.5), (40.0, 60.0))],
    ids=["60 s walk", "walk and stand"],
)
def test_every_step_of_a_clean_walk_is_counted_once(
    detector: Detector, walking: tuple[tuple[float, float], ...]
) -> None:
    trace = walk(walking)
    _, steps = detect_steps(initial_detector(), trace.accel, PdrParams(detector=detector))
    if walking == ((2.0, 62.0),):
        assert trace.n_steps == 108  # 60 s at 1.8 Hz
    assert len(steps) == trace.n_steps
    # at the extreme of the bounce cycle, to within the 20 ms grid
    assert np.max(np.abs(steps.t_ms - reported_instant(trace, detector))) <= 40
    assert np.all(steps.accel_range > 2.0 * PdrParams().threshold_ms2)
    np.testing.assert_allclose(steps.gravity, G, atol=0.1)


@pytest.mark.parametrize("detector", DETECTORS)
def test_no_steps_while_standing_with_hand_tremor(detector: Detector) -> None:
    trace = synthesize_walk(
        [(0.0, 1.0)],
        30.0,
        np.random.default_rng(5),
        walking=[],
        gait=Gait(tilt_x_rad=math.radians(30.0), tremor_ms2=0.5),
        sensors=Sensors(accel_noise_ms2=0.15),
    )
    _, steps = detect_steps(initial_detector(), trace.accel, PdrParams(detector=detector))
    assert len(steps) == 0


@cache
def short_walk() -> ImuTrace:
    return walk(((1.0, 9.0),), duration_s=10.0, seed=3)


@pytest.mark.parametrize("detector", DETECTORS)
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_steps_do_not_depend_on_how_the_samples_are_cut(
    detector: Detector, data: st.DataObject
) -> None:
    accel = short_walk().accel
    params = PdrParams(detector=detector)
    _, whole = detect_steps(initial_detector(), accel, params)
    cuts = sorted(data.draw(st.lists(st.integers(0, accel.shape[0]), max_size=12)))
    _, found = detect_in_chunks(accel, cuts, params)
    assert len(whole) == short_walk().n_steps
    assert_same_steps(joined(found), whole)


@pytest.mark.parametrize("detector", DETECTORS)
def test_a_step_straddling_two_batches_is_found_once(detector: Detector) -> None:
    trace = short_walk()
    params = PdrParams(detector=detector)
    _, whole = detect_steps(initial_detector(), trace.accel, params)
    t = trace.accel[:, 0]
    peak, valley = trace.peak_t_ms[5], trace.step_t_ms[5]
    # between the step's peak and valley; just after the reported extreme, before it is sure
    for cut_ms in (0.5 * (peak + valley), reported_instant(trace, detector)[5] + 20):
        cut = int(np.searchsorted(t, cut_ms))
        _, (first, second) = detect_in_chunks(trace.accel, [cut], params)
        assert_same_steps(joined([first, second]), whole)
        reported = int(whole.t_ms[5])
        assert (reported in first.t_ms) != (reported in second.t_ms)


@pytest.mark.parametrize("detector", DETECTORS)
def test_detector_state_round_trips_mid_walk(detector: Detector) -> None:
    accel = short_walk().accel
    params = PdrParams(detector=detector)
    cut = int(np.searchsorted(accel[:, 0], short_walk().step_t_ms[6] - 30))
    state, _ = detect_steps(initial_detector(), accel[:cut], params)
    arrays = {k: np.array(v) for k, v in state_codec.to_arrays(state).items()}
    restored = state_codec.from_arrays(DetectorState, arrays)
    for key, value in state_codec.to_arrays(restored).items():
        np.testing.assert_array_equal(value, arrays[key])
    _, direct = detect_steps(state, accel[cut:], params)
    _, resumed = detect_steps(restored, accel[cut:], params)
    assert len(direct) > 0
    assert_same_steps(resumed, direct)
    with pytest.raises(ValueError, match="machine must have shape"):
        state_codec.from_arrays(DetectorState, {**arrays, "machine": np.zeros(3)})


def test_no_samples_change_nothing() -> None:
    state = initial_detector()
    again, steps = detect_steps(state, np.empty((0, 4)), PdrParams())
    assert again is state
    assert len(steps) == 0


def test_a_long_gap_restarts_the_detector() -> None:
    trace = walk(((1.0, 9.0), (13.0, 21.0)), duration_s=22.0, seed=4)
    t_s = (trace.accel[:, 0] - trace.t0_ms) / 1000.0
    gap = (t_s > 9.5) & (t_s < 12.5)  # standing there anyway
    _, steps = detect_steps(initial_detector(), trace.accel[~gap], PdrParams())
    assert len(steps) == trace.n_steps


# --- step length ---------------------------------------------------------------------------


def steps_with(accel_range: list[float], gravity: float = math.nan) -> Steps:
    n = len(accel_range)
    return Steps(np.arange(n, dtype=np.int64), np.array(accel_range), np.full(n, gravity))


def test_weinberg_step_length_by_hand() -> None:
    params = PdrParams(length_model="weinberg")
    # S = K (Δa / g)^(1/4): Δa = g / 16 gives K / 2; the gravity of the step when known
    lengths = step_lengths(steps_with([G / 16.0, 0.0]), params)
    np.testing.assert_allclose(lengths, [0.861 / 2.0, 0.0])
    lengths = step_lengths(steps_with([9.7 / 16.0], gravity=9.7), params, scale=1.2)
    np.testing.assert_allclose(lengths, [1.2 * 0.861 / 2.0])
    # the paper's trained 0.6 m step: Δa = (0.6 / 0.861)^4 g
    assert step_lengths(steps_with([(0.6 / 0.861) ** 4 * G]), params)[0] == pytest.approx(0.6)


def test_mansour_step_length_by_hand_and_clamped() -> None:
    params = PdrParams(length_model="mansour")
    ranges = [2.0, 3.0, 0.5, 16.0, 0.0, -1.0]
    expected = [0.55 * 2.0**0.25, 0.55 * 3.0**0.25, 0.6, 0.9, 0.6, 0.6]
    np.testing.assert_allclose(step_lengths(steps_with(ranges), params), expected)
    # scale multiplies m and the clamp: [0.72, 1.08] m at 1.2
    scaled = step_lengths(steps_with(ranges), params, scale=1.2)
    np.testing.assert_allclose(scaled, [1.2 * e for e in expected])
    narrow = PdrParams(min_step_m=0.7, max_step_m=0.7)
    np.testing.assert_allclose(step_lengths(steps_with(ranges), narrow), 0.7)


def test_calibrated_step_length() -> None:
    assert calibrated_step_m(14.0, 20) == pytest.approx(0.7)
    with pytest.raises(ValueError, match="n_steps"):
        calibrated_step_m(14.0, 0)
    for bad in (0.0, -3.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="distance_m"):
            calibrated_step_m(bad, 20)


# --- parameters ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"detector": "peaks"}, "detector"),
        ({"length_model": "stride"}, "length_model"),
        ({"grid_ms": 0}, "grid_ms"),
        ({"half_window": 0}, "half_window"),
        ({"min_step_m": 0.9, "max_step_m": 0.6}, "min_step_m"),
    ],
)
def test_pdr_params_are_validated(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        PdrParams(**kwargs)  # type: ignore[arg-type]
