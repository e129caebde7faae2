"""Trace segmentation at outer anchors (``papers/003_*`` section IV-C).

The kept spans of the inertial selection (``mapping.selection``, IV-A) are cut at the
outer anchors (GNSS fixes, BLE beacons at elevators and entrances, ``mapping/anchors.py``)
that fall inside them. In a kept span ``[s, e)`` holding anchors at times
``a_1 <= ... <= a_n``:

* ``[a_1, a_n)`` is a *closed* segment when ``a_1 < a_n`` ("collected between two or
  more ANs"); it lists all ``n`` anchors, which give the alignment its point pairs
  (eq 5-7);
* ``[s, a_1)`` and ``[a_n, e)`` (when not empty) are *open* segments anchored at one
  end; a span without anchors is one open segment with none ("between less than two
  ANs"). Open segments become closed in later generations, when internal WiFi anchors
  are known: run ``segment_trace`` again with them added.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

SegmentKind = Literal["closed", "open"]


@dataclass(frozen=True)
class Segment:
    """A piece of a kept span, ``[start_ms, end_ms)``.

    ``anchors`` are indices into the ``anchor_t_ms`` given to ``segment_trace``, in time
    order: all anchors of the span for a closed segment; for an open segment the anchors
    at its anchored end (none for a span without anchors).
    """

    start_ms: int
    end_ms: int
    kind: SegmentKind
    anchors: tuple[int, ...]


def segment_trace(anchor_t_ms: ArrayLike, kept_spans_ms: ArrayLike) -> tuple[Segment, ...]:
    """Cut kept spans into closed and open segments at their outer anchors (IV-C).

    Parameters
    ----------
    anchor_t_ms : array_like, shape (n_anchors,)
        Times of the anchors detected along the trace (GNSS, BLE), any order. Anchors
        outside every kept span are ignored (they lie in rejected data).
    kept_spans_ms : array_like, shape (n_spans, 2)
        ``[start, end)`` of the kept spans, e.g. ``InertialSelection.kept_spans_ms``.

    Returns
    -------
    tuple of Segment
        In time order; the segments of a span tile it (see the module docstring).

    Raises
    ------
    ValueError
        When an argument is malformed (naming it).
    """
    t = np.asarray(anchor_t_ms, dtype=np.float64).reshape(-1)
    spans = np.asarray(kept_spans_ms, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise ValueError("anchor_t_ms must be finite")
    if spans.size == 0:
        return ()
    if spans.ndim != 2 or spans.shape[1] != 2:
        raise ValueError(f"kept_spans_ms must have shape (n_spans, 2), got {spans.shape}")
    if not np.all(np.isfinite(spans)) or np.any(spans[:, 1] <= spans[:, 0]):
        raise ValueError("kept_spans_ms must hold finite spans with start < end")
    spans = spans[np.argsort(spans[:, 0], kind="stable")]
    if np.any(spans[1:, 0] < spans[:-1, 1]):
        raise ValueError("kept_spans_ms must not overlap")

    order = np.argsort(t, kind="stable")
    ts = t[order]
    lo = np.searchsorted(ts, spans[:, 0], side="left")
    hi = np.searchsorted(ts, spans[:, 1], side="left")  # half-open: an anchor at end is out
    out: list[Segment] = []
    for (s, e), i0, i1 in zip(spans, lo, hi, strict=True):
        start, end = int(s), int(e)
        if i0 == i1:
            out.append(Segment(start, end, "open", ()))
            continue
        first, last = float(ts[i0]), float(ts[i1 - 1])
        at_first = tuple(int(k) for k in order[i0:i1][ts[i0:i1] == first])
        at_last = tuple(int(k) for k in order[i0:i1][ts[i0:i1] == last])
        if first > s:
            out.append(Segment(start, int(first), "open", at_first))
        if last > first:
            out.append(
                Segment(int(first), int(last), "closed", tuple(int(k) for k in order[i0:i1]))
            )
        out.append(Segment(int(last), end, "open", at_last))
    return tuple(out)
