"""Walks from our events, joined from pieces, and through their byte encoding."""

from __future__ import annotations

import lzma

import numpy as np
import pytest

from server.positioning.model.events import (
    BleEvent,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)
from server.positioning.model.walk import Walk, join_traces, trace_from_events
from server.storage.codec import CodecError
from server.storage.ilc_trace_format import parse_trace_text
from server.storage.trace_codec import decode_trace, encode_trace
from tests.support.datasets import dataset_dir


def assert_same(a: Walk, b: Walk) -> None:
    for name in (
        "waypoint_t_ms", "waypoint_xy_m", "accel", "gyro", "magnetic", "rotation", "steps"
    ):  # fmt: skip
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.wifi == b.wifi
    assert a.ble == b.ble
    assert a.floor == b.floor
    assert a.uncalibrated == b.uncalibrated
    assert (a.t_first_ms, a.t_last_ms) == (b.t_first_ms, b.t_last_ms)


def test_a_recorded_trace_survives_its_encoding() -> None:
    path = next((dataset_dir("ilc20-sample") / "site2" / "F4" / "path_data_files").iterdir())
    trace = parse_trace_text(lzma.decompress(path.read_bytes()).decode(), "p", "F4")
    # float32 RSS on the way: ILC readings are whole dBm, exact in float32
    blob = encode_trace(trace)
    assert encode_trace(decode_trace(blob)) == blob  # deterministic
    assert_same(decode_trace(blob), trace)
    with pytest.raises(CodecError):
        decode_trace(b"not a trace")


def _imu(t0: int, n: int = 5, calibrated: bool = True) -> ImuEvent:
    t = t0 + 20 * np.arange(n, dtype=np.float64)
    rows = np.column_stack([t, np.ones(n), np.zeros(n), np.full(n, 9.8)])
    quat = np.column_stack([t, np.zeros(n), np.zeros(n), np.full(n, 0.6), np.full(n, -0.8)])
    return ImuEvent(
        t0, accel=rows, gyro=rows, magnetic=rows, magnetic_calibrated=calibrated, rotation=quat
    )


def test_events_become_a_walk_and_pieces_join() -> None:
    wifi = WifiEvent(1_000, (RadioReading("aa:bb", -60.0), RadioReading("cc:dd", -71.0)))
    ble = BleEvent(1_050, (RadioReading("uuid:1:2", -80.0),))
    first = trace_from_events(
        [_imu(1_000), wifi, StepEvent(1_090, 0.7, 0.0), MagEvent(1_095, (30.0, 0.0, -40.0))],
        [(1_000, 1.0, 2.0)],
    )
    assert first.wifi == (wifi,)
    assert first.ble == ()
    assert first.accel.shape == (5, 4)
    assert first.magnetic.shape == (6, 4)  # the IMU's five samples and the mag event's vector
    # the rotation keeps its vector part with the scalar part made non-negative
    np.testing.assert_allclose(first.rotation[0, 1:], [0.0, 0.0, -0.6])
    second = trace_from_events([_imu(1_080, calibrated=False), ble], [(1_200, 5.0, 2.0)])
    whole = join_traces([second, first], floor="F1")
    np.testing.assert_array_equal(whole.waypoint_t_ms, [1_000, 1_200])
    assert whole.ble == (ble,)
    assert whole.uncalibrated == frozenset({"magnetic"})
    # overlapping samples (a batch sent twice) are kept once, in time order
    assert np.all(np.diff(whole.accel[:, 0]) > 0)
    assert whole.accel.shape[0] == 9  # 1000..1080 and 1080..1160: 1080 once
    # the phone's steps are kept: [t, length, heading]
    np.testing.assert_array_equal(whole.steps, [[1_090, 0.7, 0.0]])
    assert second.steps.shape == (0, 3)
    assert_same(decode_trace(encode_trace(whole)), whole)
