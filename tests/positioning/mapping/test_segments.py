"""Segmentation of kept spans at outer anchors (``papers/003_*`` IV-C)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.mapping.segments import Segment, segment_trace


def test_segments_between_anchors() -> None:
    spans = [[0, 100], [200, 300], [400, 500]]
    #          span 1: anchors 20, 60, 80   span 2: one at 250   span 3: none
    anchors = [250, 80, 20, 60, 150, 300]  # 150 is in rejected data, 300 at an open end
    assert segment_trace(anchors, spans) == (
        Segment(0, 20, "open", (2,)),
        Segment(20, 80, "closed", (2, 3, 1)),
        Segment(80, 100, "open", (1,)),
        Segment(200, 250, "open", (0,)),
        Segment(250, 300, "open", (0,)),
        Segment(400, 500, "open", ()),
    )


def test_segment_with_anchors_at_both_ends() -> None:
    assert segment_trace([0, 50], [[0, 100]]) == (
        Segment(0, 50, "closed", (0, 1)),
        Segment(50, 100, "open", (1,)),
    )
    assert segment_trace([10], [[10, 100]]) == (Segment(10, 100, "open", (0,)),)


def test_simultaneous_anchors_do_not_close_a_segment() -> None:
    # a GNSS fix and a beacon peak at the same instant are one place, not two
    assert segment_trace([40, 40], [[0, 100]]) == (
        Segment(0, 40, "open", (0, 1)),
        Segment(40, 100, "open", (0, 1)),
    )


def test_no_spans_no_segments() -> None:
    assert segment_trace([1, 2], np.empty((0, 2))) == ()


@given(
    anchors=st.lists(st.integers(0, 1000), max_size=12),
    cuts=st.lists(st.integers(0, 1000), min_size=2, max_size=8, unique=True),
)
def test_segments_tile_their_spans(anchors: list[int], cuts: list[int]) -> None:
    edges = sorted(cuts)
    spans = [[a, b] for a, b in zip(edges[::2], edges[1::2], strict=False)]
    segments = segment_trace(anchors, spans)
    for s, e in spans:
        inside = [g for g in segments if s <= g.start_ms < e]
        assert inside[0].start_ms == s
        assert inside[-1].end_ms == e
        assert all(a.end_ms == b.start_ms for a, b in itertools.pairwise(inside))
        in_span = sorted(i for i, t in enumerate(anchors) if s <= t < e)
        closed = [g for g in inside if g.kind == "closed"]
        distinct = {anchors[i] for i in in_span}
        assert len(closed) == (1 if len(distinct) >= 2 else 0)
        if closed:
            assert sorted(closed[0].anchors) == in_span
            assert closed[0].start_ms == min(distinct)
            assert closed[0].end_ms == max(distinct)
        for g in inside:
            assert g.start_ms < g.end_ms
            assert all(g.start_ms <= anchors[i] <= g.end_ms for i in g.anchors)


def test_segment_bad_input() -> None:
    with pytest.raises(ValueError, match="kept_spans_ms must have shape"):
        segment_trace([1], [1, 2, 3])
    with pytest.raises(ValueError, match="kept_spans_ms must not overlap"):
        segment_trace([1], [[0, 10], [5, 20]])
    with pytest.raises(ValueError, match="anchor_t_ms must be finite"):
        segment_trace([np.nan], [[0, 10]])
