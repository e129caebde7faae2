"""A walk's views as events (IMU blocks, merged scans) on the ILC site2 sample trace."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from server.positioning.model.events import ImuEvent, RadioReading, WifiEvent
from server.positioning.model.walk import Walk
from server.storage.ilc_trace_format import read_trace


def streams_of(trace: Walk) -> dict[str, NDArray[np.float64]]:
    return {
        "accel": trace.accel,
        "gyro": trace.gyro,
        "magnetic": trace.magnetic,
        "rotation": trace.rotation,
    }


def joined(blocks: list[ImuEvent], sensor: str) -> NDArray[np.float64]:
    return np.concatenate([b.sensors()[sensor] for b in blocks])


@pytest.mark.parametrize("block_ms", [1, 250, 1000, 60_000])
def test_imu_blocks_hold_every_sample_once(raw_trace: Walk, block_ms: int) -> None:
    blocks = raw_trace.imu_events(block_ms)
    t0 = min(a[0, 0] for a in streams_of(raw_trace).values())
    starts = [b.t_ms for b in blocks]
    assert starts[0] == t0
    assert all(b > a for a, b in itertools.pairwise(starts))
    assert all((s - t0) % block_ms == 0 for s in starts)
    for block in blocks:
        times = [a[:, 0] for a in block.sensors().values() if a.shape[0]]
        assert times, "a block without samples"
        for t in times:
            assert block.t_ms <= t[0]
            assert t[-1] < block.t_ms + block_ms
            assert np.all(np.diff(t) > 0)
        assert block.pressure.shape == (0, 2)
        assert block.magnetic_calibrated
    for name, samples in streams_of(raw_trace).items():
        got = joined(blocks, name)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got[:, :4], samples)
    # the sample trace: 6.5 s of phone time
    if block_ms == 1000:
        assert len(blocks) == 7


def test_imu_blocks_complete_the_rotation_quaternion(raw_trace: Walk) -> None:
    rotation = joined(raw_trace.imu_events(), "rotation")
    assert rotation.shape == (raw_trace.rotation.shape[0], 5)
    xyz, w = rotation[:, 1:4], rotation[:, 4]
    assert np.all(w >= 0)
    np.testing.assert_allclose(w, np.sqrt(1.0 - np.sum(xyz**2, axis=1)))
    np.testing.assert_allclose(np.linalg.norm(rotation[:, 1:], axis=1), 1.0, atol=1e-7)


def test_imu_blocks_of_an_uncalibrated_magnetometer_are_calibrated(
    tmp_path: Path, raw_lines: list[str]
) -> None:
    # the reader subtracts the phone's hard-iron estimate from uncalibrated records
    path = tmp_path / "no_magnetometer.txt"
    kept = [line for line in raw_lines if "\tTYPE_MAGNETIC_FIELD\t" not in line]
    path.write_text("\n".join(kept) + "\n", encoding="utf-8")
    tr = read_trace(path)
    assert tr.uncalibrated == frozenset({"magnetic"})
    blocks = tr.imu_events()
    assert all(b.magnetic_calibrated for b in blocks)
    np.testing.assert_array_equal(joined(blocks, "magnetic"), tr.magnetic)


def test_imu_blocks_keep_one_sample_per_millisecond(raw_trace: Walk) -> None:
    # a second row at the time of row 10, other values: the first one is kept
    repeated = np.insert(raw_trace.accel, 11, raw_trace.accel[10] + [0.0, 1.0, 1.0, 1.0], axis=0)
    blocks = replace(raw_trace, accel=repeated).imu_events()
    np.testing.assert_array_equal(joined(blocks, "accel"), raw_trace.accel)


def test_imu_blocks_need_a_positive_length(raw_trace: Walk) -> None:
    with pytest.raises(ValueError, match="block_ms"):
        raw_trace.imu_events(0)


def test_trace_without_motion_samples_has_no_imu_blocks(raw_trace: Walk) -> None:
    none = np.zeros((0, 4))
    still = replace(raw_trace, accel=none, gyro=none, magnetic=none, rotation=none)
    assert still.imu_events() == []
    assert still.events(imu=True) == still.radio_events()


def test_events_merge_scans_and_imu_blocks_by_time(raw_trace: Walk) -> None:
    assert raw_trace.events() == raw_trace.radio_events()
    assert raw_trace.events(imu=False) == raw_trace.radio_events()
    blocks = raw_trace.imu_events()
    # a scan at the very start of a block comes before it
    scan_at_block = WifiEvent(blocks[2].t_ms, (RadioReading("02:00:00:00:00:01", -50.0),))
    trace = replace(raw_trace, wifi=(*raw_trace.wifi, scan_at_block))
    merged = trace.events(imu=True)
    assert [e.t_ms for e in merged] == sorted(e.t_ms for e in merged)
    assert [e for e in merged if not isinstance(e, ImuEvent)] == trace.radio_events()
    merged_blocks = [e for e in merged if isinstance(e, ImuEvent)]
    assert [b.t_ms for b in merged_blocks] == [b.t_ms for b in blocks]
    assert merged.index(scan_at_block) + 1 == next(
        i for i, e in enumerate(merged) if e.t_ms == scan_at_block.t_ms and isinstance(e, ImuEvent)
    )
