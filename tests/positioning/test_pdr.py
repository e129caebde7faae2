"""Step detection, step lengths, turns and straight lines on synthetic raw IMU.

The walks come from ``client_sim.imu``: a phone held in front, its top edge raised 20 deg,
swaying a few degrees; one vertical bounce cycle (2.5 m/s²) per step at 1.8 Hz, a
forward surge and a sideways sway; 50 Hz accelerometer with 0.05 m/s² of noise. The true
step time is the valley of each bounce cycle (what ``"mansour"`` reports), its peak half a
cycle earlier (what ``"cui"`` reports).
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
from server.positioning.pdr import (
    STRAIGHT,
    SUSPECT,
    TURN,
    Detector,
    DetectorState,
    G,
    PdrParams,
    Steps,
    TurnParams,
    TurnState,
    calibrated_step_m,
    classify_steps,
    detect_steps,
    initial_detector,
    initial_turns,
    project_to_line,
    ransac_line,
    step_lengths,
    straighten_track,
)

FloatArray = NDArray[np.float64]

DETECTORS: tuple[Detector, ...] = ("mansour", "cui")
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
    return trace.step_t_ms if detector == "mansour" else trace.peak_t_ms


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
    arrays = {k: np.array(v) for k, v in state.to_arrays().items()}
    restored = DetectorState.from_arrays(arrays)
    for key, value in restored.to_arrays().items():
        np.testing.assert_array_equal(value, arrays[key])
    _, direct = detect_steps(state, accel[cut:], params)
    _, resumed = detect_steps(restored, accel[cut:], params)
    assert len(direct) > 0
    assert_same_steps(resumed, direct)
    with pytest.raises(ValueError, match="wrong shape"):
        DetectorState.from_arrays({**arrays, "machine": np.zeros(3)})


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


# --- turns ---------------------------------------------------------------------------------


def classify(
    headings_deg: list[float], params: TurnParams | None = None
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    params = params or TurnParams()
    _, status, segment = classify_steps(initial_turns(params), np.radians(headings_deg), params)
    return status, segment


def test_a_straight_walk_is_straight() -> None:
    rng = np.random.default_rng(1)
    headings = list(40.0 + rng.uniform(-2.0, 2.0, 60))
    status, segment = classify(headings)
    assert (status == STRAIGHT).all()
    assert (segment == 0).all()


def test_a_straight_walk_across_the_wrap_is_straight() -> None:
    status, _ = classify([178.0, -179.0, 179.0, -178.0, 180.0, -180.0, 177.0])
    assert (status == STRAIGHT).all()


def test_a_slow_sway_of_5_degrees_stays_straight() -> None:
    headings = list(90.0 + 5.0 * np.sin(2.0 * np.pi * np.arange(80) / 20.0))
    status, segment = classify(headings)
    assert (status == STRAIGHT).all()
    assert (segment == 0).all()


def test_a_right_angle_turn_is_a_turn_and_starts_a_segment() -> None:
    headings = [0.0] * 20 + [30.0, 60.0, 90.0] + [90.0] * 20
    status, segment = classify(headings)
    assert (status[:20] == STRAIGHT).all()
    assert status[20] == SUSPECT  # 30 deg from the last straight step: not more than λ_h
    assert (status[21:23] == TURN).all()
    # the turn lasts while the window still holds pre-turn headings
    assert (status[23:26] == TURN).all()
    assert (status[26:] == STRAIGHT).all()
    assert (segment[:26] == 0).all()
    assert (segment[26:] == 1).all()


def test_a_suspected_turn_that_comes_back_starts_a_new_segment() -> None:
    headings = [0.0] * 10 + [15.0, 0.0] + [0.0] * 10
    status, segment = classify(headings)
    assert (status[10:12] == SUSPECT).all()
    assert segment[-1] == 1
    assert (status[-1:] == STRAIGHT).all()


def test_turn_classification_is_incremental() -> None:
    rng = np.random.default_rng(2)
    headings = np.radians(
        np.concatenate([np.zeros(15), np.linspace(0, 90, 6), np.full(15, 90.0)])
        + rng.normal(0.0, 1.0, 36)
    )
    params = TurnParams()
    _, status, segment = classify_steps(initial_turns(params), headings, params)
    state = initial_turns(params)
    parts = []
    for chunk in np.array_split(headings, [4, 17, 18, 30]):
        state, s, g = classify_steps(TurnState.from_arrays(state.to_arrays()), chunk, params)
        parts.append((s, g))
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), status)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), segment)


# --- straight lines ------------------------------------------------------------------------


def same_line(
    got: tuple[float, float, float] | None, want: tuple[float, float, float], atol: float = 1e-9
) -> None:
    """``a x + b y + c = 0`` lines equal up to scale and sign; ``got`` normalised."""
    assert got is not None
    a, b, c = want
    want_unit = np.array([a, b, c]) / math.hypot(a, b)
    assert math.hypot(got[0], got[1]) == pytest.approx(1.0)
    sign = np.sign(np.dot(got, want_unit))
    np.testing.assert_allclose(sign * np.array(got), want_unit, rtol=0.0, atol=atol)


def total_least_squares(points: FloatArray) -> tuple[float, float, float]:
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre)
    a, b = vt[-1]
    return float(a), float(b), float(-(a * centre[0] + b * centre[1]))


def test_ransac_recovers_a_line_among_outliers() -> None:
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 20.0, 25)
    on_line = np.column_stack([x, 0.5 * x + 1.0 + rng.normal(0.0, 0.1, x.size)])
    outliers = np.array([[5.0, 10.0], [10.0, -6.0], [15.0, 16.0], [2.0, -5.0]])
    points = np.vstack([on_line, outliers])
    line = ransac_line(points)
    same_line(line, total_least_squares(on_line))  # refitted to exactly the inliers
    same_line(line, (0.5, -1.0, 1.0), atol=0.1)  # 0.5 x - y + 1 = 0
    # more pairs than max_pairs: sampled with the generator
    sampled = ransac_line(points, max_pairs=50, rng=np.random.default_rng(0))
    same_line(sampled, total_least_squares(on_line))
    with pytest.raises(ValueError, match="rng"):
        ransac_line(points, max_pairs=50)


def test_ransac_needs_two_distinct_points() -> None:
    assert ransac_line(np.empty((0, 2))) is None
    assert ransac_line(np.array([[1.0, 2.0]])) is None
    assert ransac_line(np.array([[1.0, 2.0], [1.0, 2.0]])) is None
    same_line(ransac_line(np.array([[0.0, 0.0], [3.0, 0.0]])), (0.0, 1.0, 0.0))


@pytest.mark.parametrize("line", [(0.0, 1.0, 0.0), (0.0, 2.0, 0.0)], ids=["unit", "scaled"])
def test_only_far_points_are_projected_onto_the_line(line: tuple[float, float, float]) -> None:
    points = np.array([[1.0, 0.5], [2.0, 3.0], [3.0, -2.0], [4.0, -1.5]])
    before = points.copy()
    moved = project_to_line(points, line)
    np.testing.assert_allclose(moved, [[1.0, 0.5], [2.0, 0.0], [3.0, 0.0], [4.0, -1.5]])
    np.testing.assert_array_equal(points, before)  # the input is left alone


def test_projection_is_the_foot_of_the_perpendicular() -> None:
    line = (1.0, 1.0, -2.0)  # x + y = 2, not normalised
    moved = project_to_line(np.array([[4.0, 4.0], [1.5, 1.0]]), line, threshold_m=1.0)
    # (4, 4) is 6 / sqrt(2) = 4.2 m away: its foot is (1, 1); (1.5, 1) is 0.35 m away
    np.testing.assert_allclose(moved, [[1.0, 1.0], [1.5, 1.0]])


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


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"window_steps": 1}, "window_steps"),
        ({"lambda_low_rad": 0.0}, "lambda_low_rad < lambda_high_rad"),
        ({"lambda_low_rad": 0.6, "lambda_high_rad": 0.5}, "lambda_low_rad < lambda_high_rad"),
    ],
)
def test_turn_params_are_validated(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TurnParams(**kwargs)  # type: ignore[arg-type]


def test_straighten_track_moves_only_outliers_of_long_straight_stretches() -> None:
    # ten straight steps along y = 0 with one 3 m off; a turn; then a 3-step stretch
    xy = np.array(
        [[float(i), 0.0] for i in range(10)] + [[10.0, 1.0], [10.0, 2.0], [10.0, 3.0], [10.0, 9.0]]
    )
    xy[4, 1] = 3.0
    status = np.array([STRAIGHT] * 10 + [TURN] + [STRAIGHT] * 3)
    segment = np.array([0] * 10 + [0] + [1] * 3)
    out = straighten_track(xy, status, segment, np.random.default_rng(0))
    np.testing.assert_allclose(out[4], [4.0, 0.0], atol=1e-9)  # onto the line (eq 3)
    np.testing.assert_allclose(np.delete(out[:10], 4, axis=0), np.delete(xy[:10], 4, axis=0))
    np.testing.assert_array_equal(out[10:], xy[10:])  # a turn and a short stretch: as they were
