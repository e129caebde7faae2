"""Replay: batches of phone time, and the IMU blocks only to engines that read them."""

from __future__ import annotations

import numpy as np

from lab import replay
from server.positioning.model.events import ImuEvent, RadioReading, StepEvent, WifiEvent
from tests.support.lab_fakes import ilc_trace


def test_batches_cut_phone_time() -> None:
    events = [StepEvent(t, 0.7, 0.0) for t in (0, 400, 999, 1000, 2600)]
    cut = replay.batches(events, batch_ms=1000)
    assert [[e.t_ms for e in b] for b in cut] == [[0, 400, 999], [1000], [2600]]


def _scan(t_ms: int) -> WifiEvent:
    return WifiEvent(t_ms, (RadioReading("02:00:00:00:00:01", -60.0),))


def test_imu_blocks_are_replayed_only_to_engines_that_read_them(imu_engine: str) -> None:
    t = np.arange(0, 3000, 20, dtype=np.float64)
    accel = np.column_stack([t, np.zeros_like(t), np.zeros_like(t), np.full_like(t, 9.8)])
    trace = ilc_trace(wifi=(_scan(0), _scan(2000)), accel=accel)
    assert replay.trace_events(trace, "step_ekf") == trace.radio_events()
    assert replay.trace_events(trace, "wknn") == trace.radio_events()
    events = replay.trace_events(trace, imu_engine)
    assert [(type(e).__name__, e.t_ms) for e in events] == [
        ("WifiEvent", 0),
        ("ImuEvent", 0),
        ("ImuEvent", 1000),
        ("WifiEvent", 2000),
        ("ImuEvent", 2000),
    ]
    blocks = [e for e in events if isinstance(e, ImuEvent)]
    np.testing.assert_array_equal(np.concatenate([b.accel for b in blocks]), accel)
    # a replay batch spans as much phone time as a block: one block per batch at most
    for batch in replay.batches(events):
        assert sum(isinstance(e, ImuEvent) for e in batch) <= 1
