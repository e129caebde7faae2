"""A session's history: its fixes page by page in the floor frame, and the shapes of its
exports (GeoJSON and MF-JSON, written by ``services.track_export``; the models document
them and are not run over the answer)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from server.api.schemas.common import Strict
from server.api.schemas.sessions import FixOut

Position = tuple[float, float]


class SessionHistory(Strict):
    """A page of a session's history. The route writes the stored fixes as they were
    answered; this model documents them and is not run over the answer."""

    items: list[FixOut] = Field(description="fixes of whole batches, oldest first")
    count: int
    last_seq: int | None = Field(
        description="seq of the page's last batch: after_seq of the next page (null: an empty "
        "page; ask again with the same after_seq for batches applied since)"
    )
    more: bool = Field(
        description="the next page can be read already (false: none is kept yet, or a "
        "batch of a live session may still be on its way to SQL: ask again later)"
    )
    retention_days: float | None = Field(
        description="how long fixes are kept after they were made (INDOORPOS_HISTORY_"
        "RETENTION_DAYS; null: for good)"
    )


class TrackPoint(Strict):
    type: Literal["Point"]
    coordinates: Position = Field(description="[lon, lat], WGS84 degrees")


class TrackLine(Strict):
    type: Literal["LineString"]
    coordinates: list[Position] = Field(description="[lon, lat] of each fix, in time order")


class TrackRun(Strict):
    """What a run of fixes on one floor was: its floor, and per vertex the time and the
    accuracy."""

    session_id: str
    building_id: str | None
    floor_id: str | None
    level: int | None = Field(description="the floor's ordinal (0: ground floor)")
    start: str = Field(description="time of the first fix, ISO 8601 (UTC)")
    end: str = Field(description="time of the last fix, ISO 8601 (UTC)")
    times_ms: list[int] = Field(description="each vertex's time, ms since the epoch")
    coord_times: list[str] = Field(
        alias="coordTimes", description="each vertex's time, ISO 8601 (UTC)"
    )
    accuracy_m: list[float | None] = Field(
        description="each vertex's 68 % radius (m), as Android's Location accuracy"
    )


class TrackFeature(Strict):
    type: Literal["Feature"]
    geometry: Annotated[TrackPoint | TrackLine, Field(discriminator="type")]
    properties: TrackRun


class TrackGeoJSON(Strict):
    """RFC 7946: one Feature per run of consecutive fixes on one floor, a LineString (a
    Point for a run of one fix)."""

    type: Literal["FeatureCollection"]
    features: list[TrackFeature]


class TrackMovingFeatures(Strict):
    """OGC Moving Features JSON (19-045r3, Prism): one Feature, the session, with a
    ``temporalGeometry`` of type ``MovingPoint`` (``datetimes``, ``coordinates`` [lon, lat],
    ``interpolation`` Linear; a single fix: one instant, Discrete), ``temporalProperties``
    (``accuracy_m``, ``level``, ``floor_id``; one whose value some fixes lack has its own
    ``datetimes``), ``trs``, ``time``, ``bbox`` and its trajectory as a GeoJSON
    ``geometry`` (a Point for a single fix); none without fixes. Coordinates are in
    CRS84, MF-JSON's default."""

    type: Literal["FeatureCollection"]
    features: list[dict[str, Any]]
