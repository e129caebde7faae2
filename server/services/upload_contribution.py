"""What one upload adds to the maps (``mapping.walk_contribution``): its payload read as a
walk, its floor told, then its samples placed (CPU work, no I/O: the worker runs it in a
thread; ``uploads.settle`` folds the result in)."""

from __future__ import annotations

from server.positioning.mapping.walk_contribution import (
    AnchorContext,
    Contribution,
    walk_contribution,
)
from server.services.errors import Invalid
from server.services.upload_payloads import parse_payload
from server.storage.ilc_trace_format import floor_level
from server.storage.models import Upload


def contribution(
    upload: Upload,
    context: AnchorContext | None = None,
    *,
    inertial_selection: bool = False,
) -> Contribution:
    """The readings an upload adds to the maps; a ``rejected`` contribution saying why when
    its payload cannot be read or its floor told."""
    try:
        trace = parse_payload(upload.content_type, upload.payload, upload.id)
    except Invalid as exc:  # stored before a stricter reader: say why, do not retry
        return Contribution(None, rejected=exc.message)
    level = upload.floor_level
    if level is None:
        try:
            level = floor_level(trace.floor)
        except ValueError:
            return Contribution(None, rejected="no floor: give the floor hint (floor)")
    return walk_contribution(
        trace, level, context or AnchorContext(), inertial_selection=inertial_selection
    )
