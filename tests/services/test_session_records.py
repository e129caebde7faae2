"""A session's state blob keeps what the next batch is checked against."""

from __future__ import annotations

from server.positioning.engines.registry import get_engine
from server.services.session_records import SessionState
from server.storage.codec import decode_arrays, encode_arrays


def test_the_newest_event_time_survives_the_blob_and_older_blobs_have_none() -> None:
    spec = get_engine("wknn")
    state = SessionState(3, spec.start(spec.params()), (), b"", last_event_ms=1_700_000_000_123)
    blob = state.to_bytes(spec)
    assert SessionState.from_bytes(blob, spec).last_event_ms == 1_700_000_000_123
    arrays = decode_arrays(blob)
    del arrays["last_event_ms"]  # as the servers before it wrote them
    assert SessionState.from_bytes(encode_arrays(arrays), spec).last_event_ms == 0
