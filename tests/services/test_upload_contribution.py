"""What one upload adds to the maps, as the service reads it: its payload read as a walk
(rejected with the reader's message when it cannot be), its floor told from the upload's
hint or the walk's floor name, then placed by ``mapping.walk_contribution`` (whose own
tests, tests/positioning/mapping/test_walk_contribution.py, cover the placement)."""

from __future__ import annotations

import lzma
import math
from functools import cache

import pytest

from server.positioning.mapping.walk_contribution import (
    AnchorContext,
    Contribution,
    walk_contribution,
)
from server.positioning.model.events import RadioReading, StepEvent, WifiEvent
from server.positioning.model.walk import trace_from_events
from server.positioning.plan.geojson_plan import PLAN_MARGIN_M
from server.services.upload_contribution import contribution
from server.storage.ilc_trace_format import parse_trace_text
from server.storage.models import Upload
from server.storage.trace_codec import CONTENT_TYPE, encode_trace
from tests.support.datasets import dataset_dir

T0 = 1_700_000_000_000


@cache
def _ilc_text() -> bytes:
    """A recorded walk of site2's floor F4 (level 3), as an ILC path file."""
    path = sorted((dataset_dir("ilc20-sample") / "site2" / "F4" / "path_data_files").iterdir())[0]
    return lzma.decompress(path.read_bytes())


def _upload(level: int | None, content_type: str = "text/plain", payload: bytes = b"") -> Upload:
    return Upload(
        id="u",
        site_id="s",
        content_type=content_type,
        payload=payload or _ilc_text(),
        floor_level=level,
    )


def _json_upload(floor: str, level: int | None) -> Upload:
    """A walk of our own events on ``floor`` (its name): 20 steps east, a scan after each."""
    steps = [StepEvent(T0 + 500 * (k + 1), 0.7, math.pi / 2) for k in range(20)]
    scans = [WifiEvent(s.t_ms + 100, (RadioReading("aa", -60.0),)) for s in steps[:-1]]
    anchors = [(T0, 0.0, 0.0), (steps[-1].t_ms, 14.0, 0.0)]
    walk = trace_from_events([*steps, *scans], anchors, floor=floor)
    return _upload(level, CONTENT_TYPE, encode_trace(walk))


@pytest.mark.parametrize(
    ("content_type", "payload", "message"),
    [
        ("text/plain", b"\xff\xfe", "byte 0: the trace is not UTF-8 text"),
        ("text/plain", b"\n", "the trace holds no records"),
        ("text/plain", b"abc\tTYPE_WIFI\n", "line 1: unreadable 'TYPE_WIFI' record (2 fields)"),
        (
            "image/png",
            b"x",
            "unsupported content type 'image/png': send text/plain (ILC 2.0), "
            "application/x-xz or application/json (our events)",
        ),
    ],
)
def test_an_unreadable_payload_is_rejected_with_the_reader_s_message(
    content_type: str, payload: bytes, message: str
) -> None:
    found = contribution(_upload(3, content_type, payload))
    assert found == Contribution(None, rejected=message)


def test_an_unreadable_stored_trace_is_rejected_with_the_codec_s_message() -> None:
    found = contribution(_upload(0, CONTENT_TYPE, b"garbage"))
    assert found.floor_level is None
    assert found.rejected is not None
    assert found.rejected.startswith("not a stored trace: ")
    assert (found.points, found.magnetic, found.report) == ((), None, {})


@pytest.mark.parametrize(("hint", "level"), [(None, 3), (3, 3), (1, 1), (-2, -2)])
def test_the_floor_is_the_upload_s_hint_else_the_walk_s_floor_name(
    hint: int | None, level: int
) -> None:
    found = contribution(_upload(hint))
    assert found.rejected is None
    assert found.floor_level == level
    assert found.points
    assert {p.floor_level for p in found.points} == {level}


@pytest.mark.parametrize(("floor", "hint", "level"), [("B1", None, -1), ("", 2, 2), ("F1", 4, 4)])
def test_the_floor_of_a_walk_of_our_events(floor: str, hint: int | None, level: int) -> None:
    found = contribution(_json_upload(floor, hint))
    assert found.rejected is None
    assert found.floor_level == level
    assert len(found.points) == 19


@pytest.mark.parametrize("floor", ["", "F0", "lobby"])
def test_no_floor_hint_and_no_floor_name_it_tells_is_rejected(floor: str) -> None:
    found = contribution(_json_upload(floor, None))
    assert found == Contribution(None, rejected="no floor: give the floor hint (floor)")


def test_the_walk_is_placed_with_the_context_and_selection_given() -> None:
    trace = parse_trace_text(_ilc_text().decode(), "u")
    # no context: an empty one (no beacons, no extents)
    plain = contribution(_upload(None))
    assert plain.report == walk_contribution(trace, 3, AnchorContext()).report
    assert plain.points == walk_contribution(trace, 3, AnchorContext()).points
    # a floor plan ending where half the scans are: fewer of them used
    xs = sorted(p.x_m for p in plain.points)
    context = AnchorContext(extents={3: (-1e4, -1e4, xs[len(xs) // 2] - PLAN_MARGIN_M, 1e4)})
    for selection in (False, True):
        found = contribution(_upload(None), context, inertial_selection=selection)
        direct = walk_contribution(trace, 3, context, inertial_selection=selection)
        assert found.report == direct.report
        assert found.points == direct.points
        assert 0 < found.report["scans"] < plain.report["scans"]
        assert ("inertial_selection_kept" in found.report) is selection
