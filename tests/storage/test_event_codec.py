"""A batch's events survive the session log's encoding exactly, whatever they hold."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.model.events import (
    BleEvent,
    Event,
    GnssEvent,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)
from server.storage.codec import CodecError, encode_arrays
from server.storage.event_codec import decode_events, encode_events

times = st.integers(946_684_800_000, 4_102_444_799_999)
finite = st.floats(-1e6, 1e6, allow_nan=False)
optional = st.one_of(st.none(), finite)
emitters = st.text(min_size=1, max_size=24)
readings = st.lists(
    st.builds(RadioReading, emitters, finite, st.one_of(st.none(), st.floats(0, 1e5))),
    max_size=5,
)


def _samples(width: int) -> st.SearchStrategy[np.ndarray]:
    return st.integers(0, 4).map(
        lambda n: np.column_stack([np.arange(n, dtype=np.float64) * 10, np.ones((n, width - 1))])
    )


events = st.one_of(
    st.builds(StepEvent, times, finite, finite, finite),
    st.builds(WifiEvent, times, readings.map(tuple)),
    st.builds(BleEvent, times, readings.map(tuple)),
    st.builds(MagEvent, times, st.one_of(st.none(), st.tuples(finite, finite, finite)), optional),
    st.builds(GnssEvent, times, finite, finite, finite, optional),
    st.builds(
        ImuEvent,
        times,
        accel=_samples(4),
        gyro=_samples(4),
        magnetic=_samples(4),
        magnetic_calibrated=st.booleans(),
        rotation=_samples(5),
        pressure=_samples(2),
    ),
)


def _same(a: Event, b: Event) -> bool:
    if isinstance(a, ImuEvent) and isinstance(b, ImuEvent):
        pairs = zip(a.sensors().values(), b.sensors().values(), strict=True)
        same_flags = (a.t_ms, a.magnetic_calibrated) == (b.t_ms, b.magnetic_calibrated)
        return same_flags and all(np.array_equal(x, y) for x, y in pairs)
    return a == b


@given(st.lists(events, max_size=8))
def test_events_come_back_as_they_went(batch: list[Event]) -> None:
    back = decode_events(encode_events(batch))
    assert len(back) == len(batch)
    assert all(type(a) is type(b) and _same(a, b) for a, b in zip(batch, back, strict=True))


def test_arrays_it_did_not_make_are_refused() -> None:
    with pytest.raises(CodecError):
        decode_events(encode_arrays({"kind": np.array([0], dtype=np.uint8)}))
    with pytest.raises(CodecError):
        decode_events(b"not a container")
