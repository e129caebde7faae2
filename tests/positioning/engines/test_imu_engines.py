"""The PDR fusion engines ``two_stage_ekf`` and ``everywhere_ekf`` on scripted steps and
scans: their motion models, their EKF against a plain Kalman filter, PDR-aided selection
and the anchor calibration."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.engines import everywhere_ekf as ev
from server.positioning.engines import two_stage_ekf as ts
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.pdr_kalman import FilterState, step_motion
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.filters.kalman import predict
from server.positioning.model import state_codec
from server.positioning.model.events import BleEvent, Fix, RadioReading, WifiEvent, radio_key
from server.positioning.motion.step_tracker import Scan, Step
from server.positioning.plan.anchors import Anchor
from server.positioning.radio.fingerprints import RadioMap

NO_RNG = np.random.default_rng(0)  # the filters draw no random numbers

T0 = 1_700_000_000_000
FLOORS = (FloorRef("b", "f0", 0),)

# a 40 m x 6 m corridor surveyed every metre, eight access points along it
AP_XY = np.array([[x, y] for x in (0.0, 13.0, 26.0, 40.0) for y in (0.0, 6.0)])


def rssi(x_m: float, y_m: float) -> np.ndarray:
    d = np.maximum(np.hypot(AP_XY[:, 0] - x_m, AP_XY[:, 1] - y_m), 1.0)
    out: np.ndarray = -40.0 - 25.0 * np.log10(d)
    return out


def corridor_map() -> RadioMap:
    xy = np.array([[x, y] for x in range(41) for y in range(7)], dtype=np.float32)
    mean = np.array([rssi(float(x), float(y)) for x, y in xy], dtype=np.float32)
    return RadioMap(
        rp_xy=xy,
        rp_floor=np.zeros(len(xy), dtype=np.int32),
        mean_dbm=mean,
        var_db2=np.ones_like(mean),
        count=np.ones(mean.shape, dtype=np.int32),
        emitters=tuple(radio_key("wifi", f"02:00:00:00:00:{i:02x}") for i in range(len(AP_XY))),
    )


def scan_at(t_ms: int, x_m: float, y_m: float) -> WifiEvent:
    readings = tuple(
        RadioReading(f"02:00:00:00:00:{i:02x}", float(round(v)))
        for i, v in enumerate(rssi(x_m, y_m))
    )
    return WifiEvent(t_ms, readings)


def walk_east(n_steps: int, length_m: float, north_rad: float = math.pi / 2) -> list[Step]:
    return [
        Step(T0 + 500 * (i + 1), length_m, math.pi / 2, north_rad, True) for i in range(n_steps)
    ]


# ---------------------------------------------------------------- motion models


def numeric_jacobian(f: object, x: np.ndarray) -> np.ndarray:
    assert callable(f)
    eps = 1e-6
    cols = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = eps
        cols.append((f(x + dx) - f(x - dx)) / (2 * eps))
    return np.column_stack(cols)


@given(
    st.floats(-50, 50),
    st.floats(-50, 50),
    st.floats(-0.3, 0.3),
    st.floats(-3.0, 3.0),
    st.floats(0.3, 1.0),
    st.floats(-1.0, 1.0),
)
def test_motion_jacobians_match_finite_differences(
    x: float, y: float, s: float, h: float, d: float, turn: float
) -> None:
    state = np.array([x, y, s, h])
    _, A = ev.step_motion(state, d, turn)
    expected = numeric_jacobian(lambda v: ev.step_motion(v, d, turn)[0], state)
    np.testing.assert_allclose(A, expected, atol=1e-6)
    state = np.array([x, y, d, h])
    _, F = step_motion(state, turn)
    expected = numeric_jacobian(lambda v: step_motion(v, turn)[0], state)
    np.testing.assert_allclose(F, expected, atol=1e-6)


def test_ekf_step_equals_a_plain_kalman_filter_when_the_model_is_linear() -> None:
    """With the step length and heading known exactly, a step is a known displacement:
    the EKF prediction must be the linear KF's ``x + u``, ``P + Q``."""
    params = ev.EverywhereParams(q_scale=0.0, q_heading_rad2=0.0)
    state = ev.initial_state(params)
    P = np.diag([3.0, 2.0, 0.0, 0.0])
    P[0, 1] = P[1, 0] = 0.5
    x = np.array([5.0, 1.0, 0.1, 0.3])
    state = replace(
        state, x=x, P=P, initialized=True, heading_known=True, floor=0, last_phone_heading=0.3
    )
    maps = SiteMaps(FLOORS, None, "v")
    step = Step(T0, 0.7, 0.3 + 0.2, math.nan, True)  # a 0.2 rad turn
    new, _ = ev.SPEC.walk(state, [step], maps, params, NO_RNG)

    u = 1.1 * 0.7 * np.array([math.sin(0.5), math.cos(0.5), 0.0, 0.0])
    kf_x, kf_P = predict(x, P, np.eye(4), params.process_noise)
    np.testing.assert_allclose(new.x, kf_x + u + [0, 0, 0, 0.2], atol=1e-12)
    np.testing.assert_allclose(new.P, kf_P, atol=1e-12)


# ---------------------------------------------------------------- both engines on a walk


def apply_items(
    engine: str, items: Sequence[Step | Scan], maps: SiteMaps
) -> tuple[FilterState, list[Fix]]:
    """Steps and scans straight into a PDR fusion engine's filter, on its defaults."""
    if engine == "everywhere_ekf":
        ev_params = ev.EverywhereParams()
        return ev.SPEC.walk(ev.initial_state(ev_params), items, maps, ev_params, NO_RNG)
    ts_params = ts.TwoStageParams()
    return ts.SPEC.walk(ts.initial_state(ts_params), items, maps, ts_params, NO_RNG)


@pytest.mark.parametrize("engine", ["two_stage_ekf", "everywhere_ekf"])
def test_engine_follows_a_walk_with_scans(engine: str) -> None:
    """Steps east with the phone's compass and a scan every four steps: the estimate
    stays close to the truth and moves with the steps between scans."""
    spec = get_engine(engine)
    maps = SiteMaps(FLOORS, corridor_map(), "v")
    steps = walk_east(48, 0.7)
    items: list[Step | WifiEvent] = [scan_at(T0, 3.0, 3.0)]
    for i, step in enumerate(steps, start=1):
        items.append(step)
        if i % 4 == 0:
            items.append(scan_at(step.t_ms, 3.0 + 0.7 * i, 3.0))
    state, fixes = apply_items(engine, items, maps)
    assert fixes[0].source == "wifi"
    errors = [math.hypot(f.x_m - (3.0 + 0.7 * (f.t_ms - T0) / 500), f.y_m - 3.0) for f in fixes]
    assert max(errors[4:]) < 1.5, errors
    step_fixes = [f for f in fixes if f.source == "step"]
    assert len(step_fixes) == 48
    assert all(f.heading_rad is not None for f in step_fixes)
    # round trip of the whole state through arrays
    again = spec.decode(state_codec.to_arrays(state))
    for key, value in state_codec.to_arrays(state).items():
        np.testing.assert_array_equal(state_codec.to_arrays(again)[key], value, err_msg=key)


@pytest.mark.parametrize("engine", ["two_stage_ekf", "everywhere_ekf"])
def test_steps_before_a_known_heading_only_widen_the_uncertainty(engine: str) -> None:
    maps = SiteMaps(FLOORS, corridor_map(), "v")
    items: list[Step | Scan] = [scan_at(T0, 10.0, 3.0), *walk_east(4, 0.7, north_rad=math.nan)]
    _, fixes = apply_items(engine, items, maps)
    steps = [f for f in fixes if f.source == "step"]
    assert all(f.heading_rad is None for f in steps)
    assert all(math.hypot(f.x_m - fixes[0].x_m, f.y_m - fixes[0].y_m) < 1e-9 for f in steps)
    # each of the four steps adds about its length squared to each position variance
    assert steps[-1].cov[0] > fixes[0].cov[0] + 4 * 0.6**2


def test_two_stage_learns_the_heading_from_wifi_without_a_compass() -> None:
    """No north from the phone: the line through four WKNN positions gives psi."""
    params = ts.TwoStageParams()
    maps = SiteMaps(FLOORS, corridor_map(), "v")
    items: list[Step | WifiEvent] = [scan_at(T0, 3.0, 3.0)]
    for i, step in enumerate(walk_east(40, 0.7, north_rad=math.nan), start=1):
        items.append(step)
        if i % 3 == 0:
            items.append(scan_at(step.t_ms, 3.0 + 0.7 * i, 3.0))
    state, fixes = ts.SPEC.walk(ts.initial_state(params), items, maps, params, NO_RNG)
    assert state.heading_known
    assert abs(state.x[3] - math.pi / 2) < math.radians(10)
    assert any("wifi_heading_rad" in f.diagnostics for f in fixes)


# ---------------------------------------------------------------- PDR-aided selection


def test_aiding_penalty_is_eq_13_plus_eq_14() -> None:
    radio = corridor_map()
    fp = np.array([[0.0, 3.0], [5.0, 3.0]])  # walking east
    penalty = ev.aiding_penalty(radio.rp_xy.astype(float), fp, 3.0, ev.EverywhereParams())
    xy = radio.rp_xy.astype(float)
    ahead = int(np.flatnonzero((xy[:, 0] == 8) & (xy[:, 1] == 3))[0])
    behind = int(np.flatnonzero((xy[:, 0] == 2) & (xy[:, 1] == 3))[0])
    north = int(np.flatnonzero((xy[:, 0] == 5) & (xy[:, 1] == 6))[0])
    assert penalty[ahead] == pytest.approx(0.0, abs=1e-9)  # 3 m ahead, straight on
    assert penalty[behind] == pytest.approx(0.0 + math.pi)  # 3 m, but turned around
    assert penalty[north] == pytest.approx(0.0 + math.pi / 2)  # 3 m to the left


# ---------------------------------------------------------------- anchors (eq 18-22)


def test_anchors_calibrate_step_length_and_heading() -> None:
    """Steps 10 % too long and a compass 6 degrees off: walking straight between two
    beacons 21 m apart corrects both (eq 18-21), so the walk on to a third is right."""
    anchors = (
        Anchor(0, 2.0, 3.0, radio_key("ble", "beacon-a")),
        Anchor(0, 23.0, 3.0, radio_key("ble", "beacon-b")),
    )
    maps = SiteMaps(FLOORS, None, "v", anchors=anchors)
    params = ev.EverywhereParams()
    bias = math.radians(6.0)
    true_step = 0.7

    def beacon(t_ms: int, name: str) -> BleEvent:
        return BleEvent(t_ms, (RadioReading(name, -50.0),))

    items: list[Step | BleEvent] = [beacon(T0, "beacon-a")]
    steps = [
        Step(T0 + 500 * (i + 1), 1.1 * true_step, math.pi / 2 + bias, math.pi / 2 + bias, True)
        for i in range(60)
    ]
    items += steps[:30]  # 21 m of true walking
    items.append(beacon(steps[29].t_ms + 1, "beacon-b"))
    state, fixes = ev.SPEC.walk(ev.initial_state(params), items, maps, params, NO_RNG)
    calibrated = [f for f in fixes if "step_scale" in f.diagnostics]
    assert len(calibrated) == 1
    assert 1.0 + state.x[2] == pytest.approx(1 / 1.1, rel=0.02)
    assert state.x[3] == pytest.approx(math.pi / 2, abs=math.radians(1.0))

    state, fixes = ev.SPEC.walk(state, steps[30:], maps, params, NO_RNG)
    end = fixes[-1]
    assert math.hypot(end.x_m - (23.0 + 30 * true_step), end.y_m - 3.0) < 0.5


def test_a_weak_beacon_is_not_an_anchor() -> None:
    anchors = (Anchor(0, 2.0, 3.0, radio_key("ble", "beacon-a"), rssi_dbm=-65.0),)
    maps = SiteMaps(FLOORS, None, "v", anchors=anchors)
    params = ev.EverywhereParams()
    weak = BleEvent(T0, (RadioReading("beacon-a", -80.0),))
    state, fixes = ev.SPEC.walk(ev.initial_state(params), [weak], maps, params, NO_RNG)
    assert not state.initialized
    assert fixes == []
