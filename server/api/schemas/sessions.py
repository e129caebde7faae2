"""Sessions, their batches and the fixes they produce."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator

from server.api.schemas.common import LAX_ARRAY, DeviceModel, Id, Strict, StrictIn
from server.api.schemas.events import EventIn, ImuIn
from server.api.schemas.pages import NextCursor, PageCount
from server.api.schemas.routes import NavigationProgressOut

MAX_EVENTS_PER_BATCH = 2000
# a batch holds a minute of raw motion samples of all five sensors at 200 Hz
MAX_IMU_ROWS_PER_BATCH = 60_000

# ---------------------------------------------------------------- fixes


class ZoneEventOut(Strict):
    """A session entering or leaving a zone, confirmed by the fix that carries it."""

    type: Literal["enter", "exit"]
    zone_id: str
    zone_name: str
    floor_id: str
    level: int = Field(description="the zone's floor's ordinal")
    t: int = Field(description="time (ms) of the fix that confirmed it")
    since: int = Field(
        description="time (ms) of the first fix of the run that confirmed it: when the walker "
        "crossed the border"
    )
    dwell_s: float | None = Field(
        None, description="exit: how long the session was in the zone (s); null for enter"
    )
    reason: Literal["crossed", "session_ended"] = Field(
        "crossed",
        description="crossed: the fixes crossed the border; session_ended: the session "
        "ended inside (webhooks and the live socket only)",
    )


class FixOut(Strict):
    t: int
    x_m: float
    y_m: float
    floor: int | None = Field(description="floor level")
    building_id: str | None
    floor_id: str | None
    heading_rad: float | None
    cov_m2: Annotated[tuple[float, float, float, float], LAX_ARRAY] = Field(
        description="position covariance xx, xy, yx, yy in m²"
    )
    uncertainty_m: float = Field(
        description="root of the mean of the two position variances of cov_m2 (m)"
    )
    accuracy_68_m: float | None = Field(
        None,
        description="radius (m) that holds 68 % of the errors, calibrated on recorded walks "
        "(what Android reports as a location's accuracy)",
    )
    accuracy_95_m: float | None = Field(
        None,
        description="radius (m) that holds 95 % of the errors (what the W3C geolocation API "
        "reports as accuracy)",
    )
    floor_prob: float | None = Field(None, description="probability that the floor is right")
    source: str
    engine: str
    diagnostics: dict[str, float] = Field(default_factory=dict)
    lat: float | None = Field(
        None,
        description="WGS84 latitude (degrees) of x_m, y_m; null without a geo-referenced building",
    )
    lon: float | None = Field(None, description="WGS84 longitude (degrees); null likewise")
    level: int | None = Field(None, description="the floor's ordinal (0: ground floor)")
    accuracy_m: float | None = Field(
        None, description="the 68 % radius (m), as Android's Location accuracy"
    )
    heading_deg: float | None = Field(
        None,
        description="heading (degrees, clockwise from north by the building's rotation, "
        "[0, 360)); null without a heading",
    )
    zones: list[str] = Field(
        default_factory=list,
        description="ids of the zones the session is in after this fix (entered and not left: "
        "a border crossing counts once the fixes have stayed across it for the dwell time or "
        "distance)",
    )
    zone_events: list[ZoneEventOut] = Field(
        default_factory=list, description="the zone entries and exits this fix confirmed"
    )
    navigation: NavigationProgressOut | None = Field(
        None,
        description="while the session navigates (PUT /v1/sessions/{id}/navigation): where "
        "this fix stands on the route, the next instruction, and the events it made",
    )


# ---------------------------------------------------------------- sessions


class SessionCreate(StrictIn):
    site_id: Id
    engine: Annotated[
        str,
        Field(
            min_length=1,
            max_length=64,
            pattern=r"^[a-z0-9_]+$",
            description="the fusion engine (GET /v1/engines); auto picks one by what the "
            "phone sends: step_ekf for steps, everywhere_ekf for raw motion samples, wknn "
            "for scans alone",
        ),
    ] = "auto"
    contribute: bool = Field(
        False,
        description="offer this walk for map building: its batches are kept and, when the "
        "session ends, become one upload (anchored by the floor plan's beacons)",
    )
    device_model: DeviceModel | None = None
    params: dict[str, Any] | None = Field(
        None,
        description="overrides of the engine's parameters for this session, over the "
        "site's engine settings; nested as the defaults of GET /v1/engines are, e.g. "
        '{"particles": {"n": 500}}; checked, 422 naming the dotted field',
    )
    seed: int | None = Field(
        None,
        ge=0,
        lt=2**128,
        description="the entropy of the session's random stream (the particle filter's "
        "draws), for a replay that must reproduce a run: batch seq n draws from "
        "SeedSequence(seed, spawn_key=(n,)), as `indoorpos evaluate` does in process; "
        "fresh 128 bits by default",
    )


class SessionCreated(Strict):
    id: str
    token: str = Field(description="bearer token for this session only; shown once")
    site_id: str
    engine: str
    idle_timeout_s: int


class SessionRead(Strict):
    id: str
    site_id: str
    engine: str
    last_seq: int
    last_fix: FixOut | None
    idle_timeout_s: int


class SessionSummary(Strict):
    """A session as the list of sessions shows it (from its record, not its live state)."""

    id: str
    site_id: str
    engine: str
    contribute: bool
    device_model: str | None
    created_at: datetime
    last_active_at: datetime = Field(
        description="when a batch last refreshed it: lags the newest batch by up to half "
        "an idle timeout"
    )
    ended_at: datetime | None
    active: bool = Field(
        description="not ended and active within the last 1.5 idle timeouts: possibly "
        "live (what blocks deleting its site, buildings and floors)"
    )


class SessionList(Strict):
    items: list[SessionSummary]
    count: PageCount
    next_cursor: NextCursor


class SessionTrack(Strict):
    items: list[FixOut] = Field(description="the newest fixes of the session, oldest first")
    count: int
    max_fixes: int = Field(
        description="how many fixes the server keeps per session (INDOORPOS_SESSION_TRACK_LEN)"
    )


class BatchIn(StrictIn):
    seq: Annotated[int, Field(ge=1, description="1, 2, 3, ... per session")]
    events: Annotated[
        list[EventIn],
        Field(
            max_length=MAX_EVENTS_PER_BATCH,
            description=f"at most {MAX_IMU_ROWS_PER_BATCH} imu sample rows in all",
        ),
    ]

    @field_validator("events")
    @classmethod
    def _imu_rows(cls, events: list[Any]) -> list[Any]:
        n_rows = sum(e.n_rows for e in events if isinstance(e, ImuIn))
        if n_rows > MAX_IMU_ROWS_PER_BATCH:
            raise ValueError(
                f"{n_rows} imu sample rows: at most {MAX_IMU_ROWS_PER_BATCH} in one batch"
            )
        return events


class BatchOut(Strict):
    session_id: str
    seq: int
    replayed: bool = Field(description="true when this seq had been applied before")
    fixes: list[FixOut]
    reinitialised: bool = Field(
        False,
        description="true when the session had to be rebuilt before this batch (the "
        "server lost its state): the filter started again from this batch",
    )
    not_used: list[str] = Field(
        default_factory=list,
        description="kinds of events in this batch the session's engine does not read "
        "(accepted and ignored: e.g. step events for two_stage_ekf, which runs its own "
        "PDR on imu samples); GET /v1/engines lists what each engine reads",
    )


# ---------------------------------------------------------------- live socket


class LiveBatch(BatchIn):
    type: Literal["batch"]
