"""Request and response bodies of the public API (the wire format).

Units are in the names: metres (``_m``), radians clockwise from north (``_rad``),
dBm (``rssi_dbm``), µT (``_ut``); ``t`` is milliseconds since the epoch (phone clock).
Floors on the wire are integer levels; buildings and floors are ids.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

MAX_EVENTS_PER_BATCH = 2000
MAX_READINGS_PER_SCAN = 2048  # malls with every SSID per radio reach 500+

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
# below 2**53: exact as a float, and far inside int64
TimestampMs = Annotated[int, Field(ge=0, le=2**53, description="milliseconds since the epoch")]
# local coordinates: a building frame is never 100 km across
Coordinate = Annotated[float, Field(ge=-100_000, le=100_000, allow_inf_nan=False)]
# ids we hand out are 32 hex characters
Id = Annotated[str, Field(pattern=r"^[0-9a-f]{32}$", description="an id this service made")]
# emitter ids: printable ASCII without spaces (BSSIDs, "uuid:major:minor")
EmitterId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[!-~]+$")]


def _plain_text(value: str) -> str:
    if any(ord(c) < 32 or ord(c) == 127 or 0xD800 <= ord(c) <= 0xDFFF for c in value):
        raise ValueError("control characters and unpaired surrogates are not allowed")
    return value


Name = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(_plain_text)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", ser_json_inf_nan="null")


# ---------------------------------------------------------------- sites, buildings, floors


class SiteCreate(Strict):
    name: Name


class SiteRead(Strict):
    id: str
    name: str
    created_at: datetime


class SiteList(Strict):
    items: list[SiteRead]
    count: int


class BuildingCreate(Strict):
    name: Name
    origin_lat: Annotated[float | None, Field(ge=-90, le=90, allow_inf_nan=False)] = None
    origin_lon: Annotated[float | None, Field(ge=-180, le=180, allow_inf_nan=False)] = None
    rotation_rad: FiniteFloat = Field(
        0.0, description="angle from geographic north to the local y axis, clockwise"
    )


class BuildingRead(Strict):
    id: str
    site_id: str
    name: str
    origin_lat: float | None
    origin_lon: float | None
    rotation_rad: float
    created_at: datetime


class BuildingList(Strict):
    items: list[BuildingRead]
    count: int


class FloorCreate(Strict):
    level: Annotated[int, Field(ge=-20, le=200)]
    name: Name | None = None


class FloorRead(Strict):
    id: str
    building_id: str
    level: int
    name: str | None
    has_plan: bool
    created_at: datetime


class FloorList(Strict):
    items: list[FloorRead]
    count: int


class FloorPlan(BaseModel):
    """A GeoJSON FeatureCollection in the building's local metric frame."""

    model_config = ConfigDict(extra="allow")
    type: Literal["FeatureCollection"]
    features: Annotated[list[dict[str, Any]], Field(max_length=100_000)]


# ---------------------------------------------------------------- radio readings and events


class WifiReading(Strict):
    bssid: EmitterId
    rssi_dbm: Annotated[float, Field(ge=-130, le=0, allow_inf_nan=False)]


class BleReading(Strict):
    id: EmitterId
    rssi_dbm: Annotated[float, Field(ge=-130, le=0, allow_inf_nan=False)]


class StepIn(Strict):
    type: Literal["step"]
    t: TimestampMs
    length_m: Annotated[float, Field(gt=0, le=3.0, allow_inf_nan=False)]
    heading_rad: FiniteFloat
    confidence: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 1.0


class WifiIn(Strict):
    type: Literal["wifi"]
    t: TimestampMs
    readings: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)]


class BleIn(Strict):
    type: Literal["ble"]
    t: TimestampMs
    readings: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)]


class MagIn(Strict):
    type: Literal["mag"]
    t: TimestampMs
    field_ut: tuple[FiniteFloat, FiniteFloat, FiniteFloat] | None = None
    magnitude_ut: Annotated[float | None, Field(ge=0, le=2000, allow_inf_nan=False)] = None

    @model_validator(mode="after")
    def _has_field(self) -> MagIn:
        if self.field_ut is None and self.magnitude_ut is None:
            raise ValueError("field_ut or magnitude_ut is required")
        return self


EventIn = Annotated[StepIn | WifiIn | BleIn | MagIn, Field(discriminator="type")]


# ---------------------------------------------------------------- fixes


class FixOut(Strict):
    t: int
    x_m: float
    y_m: float
    floor: int | None = Field(description="floor level")
    building_id: str | None
    floor_id: str | None
    heading_rad: float | None
    cov_m2: tuple[float, float, float, float] = Field(
        description="position covariance xx, xy, yx, yy in m²"
    )
    uncertainty_m: float
    source: str
    engine: str
    diagnostics: dict[str, float] = Field(default_factory=dict)


# ---------------------------------------------------------------- sessions


class SessionCreate(Strict):
    site_id: Id
    engine: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[a-z0-9_]+$")] = "step_ekf"


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


class BatchIn(Strict):
    seq: Annotated[int, Field(ge=1, description="1, 2, 3, ... per session")]
    events: Annotated[list[EventIn], Field(max_length=MAX_EVENTS_PER_BATCH)]


class BatchOut(Strict):
    session_id: str
    seq: int
    replayed: bool = Field(description="true when this seq had been applied before")
    fixes: list[FixOut]


# ---------------------------------------------------------------- surveys and maps


class SurveyPoint(Strict):
    x_m: Coordinate
    y_m: Coordinate
    floor: int = Field(description="floor level")
    t: TimestampMs | None = None
    wifi: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    ble: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    mag_ut: tuple[FiniteFloat, FiniteFloat, FiniteFloat] | None = None


class SurveyIn(Strict):
    points: Annotated[list[SurveyPoint], Field(min_length=1, max_length=100_000)]


class RadioMapRead(Strict):
    id: str
    building_id: str
    version: int
    cell_m: float
    n_reference_points: int
    n_emitters: int
    n_survey_points: int
    created_at: datetime


class RadioMapList(Strict):
    items: list[RadioMapRead]
    count: int


# ---------------------------------------------------------------- locate


class LocateIn(Strict):
    site_id: Id
    wifi: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    ble: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []


class LocateOut(Strict):
    x_m: float
    y_m: float
    floor: int
    building_id: str
    floor_id: str
    cov_m2: tuple[float, float, float, float]
    uncertainty_m: float


# ---------------------------------------------------------------- live socket


class LiveBatch(BatchIn):
    type: Literal["batch"]


class ApiKeyCreated(Strict):
    id: str
    key: str
