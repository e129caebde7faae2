"""The batch service's checks that need no stores: event times against the session's
clock."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.model.events import StepEvent
from server.services.batches import check_event_times
from server.services.errors import Invalid

T0 = 1_700_000_000_000
SKEW_MS = 1000.0

times_near = st.integers(T0 - 3000, T0 + 3000)


def _strays(times: list[int], last_ms: int) -> int | None:
    """The first event at which a batch strays (None: it does not), by the rule's words:
    more than the skew from the session's newest time, or the batch so far spanning more."""
    for i, t in enumerate(times):
        seen = times[: i + 1]
        if (last_ms and abs(t - last_ms) > SKEW_MS) or max(seen) - min(seen) > SKEW_MS:
            return i
    return None


@given(times=st.lists(times_near, max_size=6), last_ms=st.one_of(st.just(0), times_near))
def test_a_batch_is_refused_at_the_first_event_that_strays(times: list[int], last_ms: int) -> None:
    events = [StepEvent(t, 0.7, 0.0) for t in times]
    first = _strays(times, last_ms)
    if first is None:
        check_event_times(events, last_ms, SKEW_MS)
    else:
        with pytest.raises(Invalid) as refused:
            check_event_times(events, last_ms, SKEW_MS)
        assert refused.value.field == f"events.{first}.t"
        assert refused.value.status == 422


def test_a_session_without_events_yet_bounds_only_the_span() -> None:
    check_event_times([StepEvent(T0 - 10**9, 0.7, 0.0)], 0, SKEW_MS)
    check_event_times([], T0, SKEW_MS)
    with pytest.raises(Invalid, match="span"):
        check_event_times([StepEvent(T0, 0.7, 0.0), StepEvent(T0 + 1001, 0.7, 0.0)], 0, SKEW_MS)
