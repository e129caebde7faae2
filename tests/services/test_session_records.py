"""A session's state blob keeps what the next batch is checked against."""

from __future__ import annotations

from server.positioning.engines.registry import get_engine
from server.positioning.plan.zone_presence import Presence
from server.services.session_records import (
    LogEntry,
    SessionState,
    navigation_after,
    navigation_delta,
    presence_from_bytes,
    presence_to_bytes,
)
from server.storage.codec import decode_arrays, encode_arrays


def test_the_newest_event_time_survives_the_blob_and_older_blobs_have_none() -> None:
    spec = get_engine("wknn")
    state = SessionState(3, spec.start(spec.params()), (), b"", last_event_ms=1_700_000_000_123)
    blob = state.to_bytes(spec)
    assert SessionState.from_bytes(blob, spec).last_event_ms == 1_700_000_000_123
    arrays = decode_arrays(blob)
    del arrays["last_event_ms"]  # as the servers before it wrote them
    assert SessionState.from_bytes(encode_arrays(arrays), spec).last_event_ms == 0


def test_zone_presence_survives_the_blob_the_log_and_older_blobs_have_none() -> None:
    spec = get_engine("wknn")
    presence = {
        "f/a": Presence(True, 1_700_000_000_000),
        "f/b": Presence(False, 1_700_000_000_500, 1_700_000_001_000, 3),
    }
    zones = presence_to_bytes(presence)
    assert presence_from_bytes(zones) == presence
    assert presence_to_bytes({}) == b""
    assert presence_from_bytes(b"") == {}
    state = SessionState(3, spec.start(spec.params()), (), b"", zones=zones)
    blob = state.to_bytes(spec)
    assert SessionState.from_bytes(blob, spec).zones == zones
    arrays = decode_arrays(blob)
    del arrays["zones"]  # as the servers before zones wrote them
    assert SessionState.from_bytes(encode_arrays(arrays), spec).zones == b""
    # a logged batch carries the presence after it, and applying it takes that on
    entry = LogEntry(4, b"\0" * 32, (), b"[]", b"", 0, presence_to_bytes({"f/a": presence["f/a"]}))
    again = LogEntry.from_bytes(entry.to_bytes())
    assert again == entry
    assert state.applied(again, 8).zones == entry.zones


def test_a_log_entry_keeps_a_navigations_course_only_when_it_changed() -> None:
    """``navigation_delta`` drops the course a batch did not change, and
    ``navigation_after`` puts it back; a new course is kept whole."""
    old = b'{"layout":1,"course":"{\\"legs\\":[1,2]}","progress":{"leg":0,"along_m":1.0}}'
    new = b'{"layout":1,"course":"{\\"legs\\":[1,2]}","progress":{"leg":0,"along_m":2.5}}'
    delta = navigation_delta(old, new)
    assert delta == b'{"layout":1,"course":null,"progress":{"leg":0,"along_m":2.5}}'
    assert navigation_after(old, delta) == new
    rerouted = b'{"layout":1,"course":"{\\"legs\\":[3]}","progress":{"leg":0,"along_m":0.0}}'
    assert navigation_delta(old, rerouted) == rerouted
    assert navigation_after(old, rerouted) == rerouted
    assert navigation_delta(b"", new) == new  # started: whole
    assert navigation_delta(old, b"") == b""  # ended
    assert navigation_after(old, b"") == b""
    assert navigation_after(b"", delta) == b""  # a course lost: the navigation ends
