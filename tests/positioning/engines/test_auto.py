"""The ``auto`` engine: what it picks for what the phone sends, that it then runs that
engine unchanged, and that its state round-trips."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from server.positioning.engines.auto import (
    SAMPLES,
    STEPS,
    UNDECIDED,
    WKNN,
    AutoParams,
    AutoState,
    choose,
)
from server.positioning.engines.registry import get_engine
from server.positioning.model.events import Event, Fix, ImuEvent, StepEvent, WifiEvent
from server.positioning.model.state_codec import StateError
from tests.support.loop_building import MAPS, loop_walk

SPEC = get_engine("auto")


def run(events: Sequence[Event], batch: int = 10) -> tuple[object, list[Fix]]:
    params = SPEC.params()
    state = SPEC.start(params)
    fixes: list[Fix] = []
    for i in range(0, len(events), batch):
        state = SPEC.decode(SPEC.encode(state))
        state, out = SPEC.step(state, events[i : i + batch], MAPS, params, np.random.default_rng(0))
        fixes.extend(out)
    return state, fixes


def test_rules() -> None:
    scan = WifiEvent(0, ())
    step = StepEvent(1, 0.7, 0.0)
    imu = ImuEvent(2, accel=np.array([[2.0, 0.0, 0.0, 9.8]]))
    barometer = ImuEvent(3, pressure=np.array([[3.0, 1013.0]]))  # beside the phone's steps
    assert choose([], UNDECIDED) == UNDECIDED
    assert choose([scan], UNDECIDED) == WKNN
    assert choose([scan, imu], UNDECIDED) == SAMPLES
    assert choose([scan, imu, step], UNDECIDED) == STEPS
    assert choose([scan, barometer], UNDECIDED) == WKNN
    assert choose([barometer, step], WKNN) == STEPS
    assert choose([], WKNN) == WKNN
    assert choose([step], WKNN) == STEPS  # moves up when the phone starts stepping
    assert choose([scan], STEPS) == STEPS
    assert choose([step], SAMPLES) == SAMPLES  # a filter is never swapped


def test_steps_run_step_ekf_exactly() -> None:
    walk = loop_walk(7, laps=1)
    state, fixes = run(walk.events)
    assert isinstance(state, AutoState)
    assert state.choice == STEPS
    ekf = get_engine("step_ekf")
    p = ekf.params()
    ref = ekf.start(p)
    expected = []
    for i in range(0, len(walk.events), 10):
        ref, out = ekf.step(ref, walk.events[i : i + 10], MAPS, p, np.random.default_rng(0))
        expected.extend(out)
    assert [(f.t_ms, f.x_m, f.y_m, f.accuracy_68_m) for f in fixes] == [
        (f.t_ms, f.x_m, f.y_m, f.accuracy_68_m) for f in expected
    ]
    assert all(f.diagnostics["auto_engine"] == STEPS for f in fixes)


def test_scans_first_then_steps() -> None:
    walk = loop_walk(8, laps=1)
    scans = [e for e in walk.events if isinstance(e, WifiEvent)][:5]
    state, fixes = run(scans, batch=5)
    assert isinstance(state, AutoState)
    assert state.choice == WKNN
    assert len(fixes) == 5
    later = [e for e in walk.events if e.t_ms > scans[-1].t_ms]
    state2, more = SPEC.step(state, later, MAPS, SPEC.params(), np.random.default_rng(0))
    assert isinstance(state2, AutoState)
    assert state2.choice == STEPS
    assert more


def test_nested_params_reach_the_chosen_engine() -> None:
    params = SPEC.params({"step_ekf": {"k": 7}})
    assert isinstance(params, AutoParams)
    assert params.step_ekf.k == 7
    assert params.wknn.k == 4


def test_bad_states_are_refused() -> None:
    walk = loop_walk(9, laps=1)
    state, _ = run(walk.events[:20])
    arrays = SPEC.encode(state)
    assert arrays["choice"] == STEPS
    with pytest.raises(StateError, match="choice"):
        SPEC.decode({**arrays, "choice": np.array(9)})
    with pytest.raises(StateError, match="choice"):
        SPEC.decode({**arrays, "choice": np.array(WKNN)})  # the states of another engine
    with pytest.raises(StateError):
        SPEC.decode({})
