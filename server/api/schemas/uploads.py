"""Crowdsourced walks offered for map building."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import Field

from server.api.schemas.common import Coordinate, Strict, StrictIn, TimestampMs
from server.api.schemas.events import EventIn
from server.api.schemas.pages import NextCursor, PageCount

MAX_UPLOAD_EVENTS = 200_000
MAX_UPLOAD_ANCHORS = 10_000


class UploadAnchorIn(StrictIn):
    """A place the walker was known to be at, at a time (a tap on the map, a QR code)."""

    t: TimestampMs
    x_m: Coordinate
    y_m: Coordinate


class UploadTraceIn(StrictIn):
    """A walk as our own events (as a session's batches carry them) and its anchors.
    Without two anchors the worker looks for passes by the floor plan's beacons."""

    events: Annotated[list[EventIn], Field(min_length=1, max_length=MAX_UPLOAD_EVENTS)]
    anchors: Annotated[list[UploadAnchorIn], Field(max_length=MAX_UPLOAD_ANCHORS)] = []


UploadStatus = Literal["queued", "processing", "done", "rejected", "failed"]


class UploadRead(Strict):
    id: str
    site_id: str
    building_id: str | None
    floor: int | None = Field(description="the floor hint given with the upload")
    device_model: str | None
    status: UploadStatus
    attempts: int
    report: dict[str, Any] | None = Field(
        description="what was used, what was not and why; the reason when rejected or failed"
    )
    created_at: datetime
    updated_at: datetime


class UploadList(Strict):
    items: list[UploadRead]
    count: PageCount
    next_cursor: NextCursor
