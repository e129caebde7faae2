"""Request and response bodies of the public API (the wire format).

Units are in the names: metres (``_m``), radians clockwise from north (``_rad``),
dBm (``rssi_dbm``), µT (``_ut``); ``t`` is milliseconds since the epoch (phone clock).
Floors on the wire are integer levels; buildings and floors are ids.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic import (
    Strict as StrictMode,
)

MAX_EVENTS_PER_BATCH = 2000
MAX_READINGS_PER_SCAN = 2048  # malls with every SSID per radio reach 500+
# raw motion samples: one sensor at 200 Hz for a whole minute fits an event, and a batch
# holds a minute of all five sensors at 200 Hz
MAX_IMU_ROWS_PER_SENSOR = 12_000
MAX_IMU_ROWS_PER_BATCH = 60_000
MAX_IMU_SPAN_MS = 60_000  # no sample later than t + this
MAX_IMU_RATE_HZ = 500  # mean rate of one sensor over its samples in one event

FiniteFloat = Annotated[float, StrictMode(), Field(allow_inf_nan=False)]
# below 2**53: exact as a float, and far inside int64
TimestampMs = Annotated[
    int, StrictMode(), Field(ge=0, le=2**53, description="milliseconds since the epoch")
]
# local coordinates: a building frame is never 100 km across
Coordinate = Annotated[float, StrictMode(), Field(ge=-100_000, le=100_000, allow_inf_nan=False)]
# ids we hand out are 32 hex characters
Id = Annotated[str, Field(pattern=r"^[0-9a-f]{32}$", description="an id this service made")]
# emitter ids: printable ASCII without spaces (BSSIDs, "uuid:major:minor")
EmitterId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[!-~]+$")]


def _plain_text(value: str) -> str:
    # C0 and C1 controls (ANSI escapes start with ESC or CSI), unpaired surrogates
    if any(ord(c) < 32 or 127 <= ord(c) <= 159 or 0xD800 <= ord(c) <= 0xDFFF for c in value):
        raise ValueError("control characters and unpaired surrogates are not allowed")
    return value


Name = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(_plain_text)]
DeviceModel = Annotated[
    str,
    Field(min_length=1, max_length=128, description="the phone's model name, plain text"),
    AfterValidator(_plain_text),
]


# a JSON array fills a tuple; its items keep their own strict types
LAX_ARRAY = StrictMode(False)


class Strict(BaseModel):
    """Every wire model: unknown fields refused."""

    model_config = ConfigDict(extra="forbid", ser_json_inf_nan="null")


class StrictIn(Strict):
    """What clients send: no coercion either (``"1"``, ``true`` or ``1.0`` is not an
    integer, ``"1"`` or ``true`` not a number; JSON arrays still fill tuples)."""

    model_config = ConfigDict(strict=True)


# ---------------------------------------------------------------- errors


class ErrorItem(Strict):
    loc: list[str | int] = Field(description="the field, as a path into the request")
    msg: str
    type: str | None = None


class ErrorOut(Strict):
    """Every refusal: what is wrong with which field (``message`` is ``field: text``)."""

    detail: list[ErrorItem]
    message: str


# ---------------------------------------------------------------- sites, buildings, floors


class SiteCreate(StrictIn):
    name: Name


class SiteRead(Strict):
    id: str
    name: str
    created_at: datetime


class SiteList(Strict):
    items: list[SiteRead]
    count: int


class BuildingCreate(StrictIn):
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


class FloorCreate(StrictIn):
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


class WifiReading(StrictIn):
    bssid: EmitterId
    rssi_dbm: Annotated[float, Field(ge=-130, le=0, allow_inf_nan=False)]


class BleReading(StrictIn):
    id: EmitterId
    rssi_dbm: Annotated[float, Field(ge=-130, le=0, allow_inf_nan=False)]


class StepIn(StrictIn):
    type: Literal["step"]
    t: TimestampMs
    length_m: Annotated[float, Field(gt=0, le=3.0, allow_inf_nan=False)]
    heading_rad: FiniteFloat
    confidence: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 1.0


class WifiIn(StrictIn):
    type: Literal["wifi"]
    t: TimestampMs
    readings: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)]


class BleIn(StrictIn):
    type: Literal["ble"]
    t: TimestampMs
    readings: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)]


class MagIn(StrictIn):
    type: Literal["mag"]
    t: TimestampMs
    field_ut: Annotated[tuple[FiniteFloat, FiniteFloat, FiniteFloat], LAX_ARRAY] | None = None
    magnitude_ut: Annotated[float | None, Field(ge=0, le=2000, allow_inf_nan=False)] = None

    @model_validator(mode="after")
    def _has_field(self) -> MagIn:
        if self.field_ut is None and self.magnitude_ut is None:
            raise ValueError("field_ut or magnitude_ut is required")
        return self


# plausible ranges: accelerometers saturate at 16 g, gyroscopes at 2000 °/s; raw
# (uncalibrated) magnetometers report several hundred µT of hard-iron bias
Accel = Annotated[float, StrictMode(), Field(ge=-160, le=160, allow_inf_nan=False)]
Gyro = Annotated[float, StrictMode(), Field(ge=-35, le=35, allow_inf_nan=False)]
Magnetic = Annotated[float, StrictMode(), Field(ge=-5000, le=5000, allow_inf_nan=False)]
Quaternion = Annotated[float, StrictMode(), Field(ge=-1, le=1, allow_inf_nan=False)]
Pressure = Annotated[float, StrictMode(), Field(ge=300, le=1100, allow_inf_nan=False)]
UNIT_NORM_TOLERANCE = 0.1  # how far |q| of a rotation row may be from 1


class ImuIn(StrictIn):
    """Raw motion samples of the phone from ``t`` on, for engines that detect steps and
    track the attitude themselves (the others accept and ignore them).

    Each sensor is a list of rows, the sample time (integer ms since the epoch, phone
    clock) first; per sensor the times increase strictly, lie in ``[t, t + 60000]`` and
    come at most 500 Hz on average. Axes are the phone's (Android: x right, y towards the
    top edge, z out of the screen). A sensor not sent is an empty list; the event holds at
    least one sample. Send each stretch of time's samples of all sensors in one event: the
    heading filters read the accelerometer and magnetometer samples of events that also
    carry gyroscope samples. Samples at or before ones already sent are ignored, and an
    uncalibrated magnetometer (``magnetic_calibrated`` false) is not used for the heading.
    """

    type: Literal["imu"]
    t: TimestampMs = Field(description="start of the block: no sample is earlier")
    accel: list[Annotated[tuple[TimestampMs, Accel, Accel, Accel], LAX_ARRAY]] = Field(
        [],
        max_length=MAX_IMU_ROWS_PER_SENSOR,
        description="[t, x, y, z]: specific force in m/s², gravity included",
    )
    gyro: list[Annotated[tuple[TimestampMs, Gyro, Gyro, Gyro], LAX_ARRAY]] = Field(
        [], max_length=MAX_IMU_ROWS_PER_SENSOR, description="[t, x, y, z]: angular rate in rad/s"
    )
    magnetic: list[Annotated[tuple[TimestampMs, Magnetic, Magnetic, Magnetic], LAX_ARRAY]] = Field(
        [], max_length=MAX_IMU_ROWS_PER_SENSOR, description="[t, x, y, z]: magnetic field in µT"
    )
    magnetic_calibrated: bool = Field(
        True, description="false when magnetic still holds the hard-iron bias (uncalibrated)"
    )
    rotation: list[
        Annotated[tuple[TimestampMs, Quaternion, Quaternion, Quaternion, Quaternion], LAX_ARRAY]
    ] = Field(
        [],
        max_length=MAX_IMU_ROWS_PER_SENSOR,
        description="[t, x, y, z, w]: unit quaternion (norm 1 ± 0.1) of the phone in the "
        "east-north-up frame: Android's rotation vector, with w = sqrt(1 - x² - y² - z²) "
        "when the phone gives only x, y, z",
    )
    pressure: list[Annotated[tuple[TimestampMs, Pressure], LAX_ARRAY]] = Field(
        [], max_length=MAX_IMU_ROWS_PER_SENSOR, description="[t, hPa]: barometric pressure"
    )

    @field_validator("accel", "gyro", "magnetic", "rotation", "pressure")
    @classmethod
    def _times(cls, rows: list[tuple[Any, ...]], info: ValidationInfo) -> list[tuple[Any, ...]]:
        if not rows:
            return rows
        times = [row[0] for row in rows]
        t = info.data.get("t")  # absent when t itself is invalid
        if t is not None and not t <= times[0] <= times[-1] <= t + MAX_IMU_SPAN_MS:
            raise ValueError(
                f"sample times must lie in [t, t + {MAX_IMU_SPAN_MS}]: t = {t}, "
                f"samples from {times[0]} to {times[-1]}"
            )
        for i in range(1, len(times)):
            if times[i] <= times[i - 1]:
                raise ValueError(f"sample times must increase (monotonic time): row {i}")
        span_ms = times[-1] - times[0]
        if (len(times) - 1) * 1000 > MAX_IMU_RATE_HZ * span_ms:
            rate = (len(times) - 1) * 1000 / span_ms
            raise ValueError(f"{rate:.0f} Hz: more than {MAX_IMU_RATE_HZ} Hz on average")
        return rows

    @field_validator("rotation")
    @classmethod
    def _unit(
        cls, rows: list[tuple[int, float, float, float, float]]
    ) -> list[tuple[int, float, float, float, float]]:
        for i, (_, x, y, z, w) in enumerate(rows):
            if abs(math.sqrt(x * x + y * y + z * z + w * w) - 1.0) > UNIT_NORM_TOLERANCE:
                raise ValueError(f"row {i} is not a unit quaternion")
        return rows

    @model_validator(mode="after")
    def _has_samples(self) -> ImuIn:
        if not self.n_rows:
            raise ValueError("an imu event holds at least one sample")
        return self

    @property
    def n_rows(self) -> int:
        """Samples of all sensors."""
        sensors = (self.accel, self.gyro, self.magnetic, self.rotation, self.pressure)
        return sum(len(rows) for rows in sensors)


class GnssIn(StrictIn):
    """A satellite fix; near an entrance it anchors a walk offered for map building
    (``accuracy_m`` < 5 m and ``hdop`` < 20, Mansour IV-B; without ``hdop``, never)."""

    type: Literal["gnss"]
    t: TimestampMs
    lat_deg: Annotated[float, Field(ge=-90, le=90, allow_inf_nan=False)]
    lon_deg: Annotated[float, Field(ge=-180, le=180, allow_inf_nan=False)]
    accuracy_m: Annotated[float, Field(gt=0, le=10_000, allow_inf_nan=False)]
    hdop: Annotated[float | None, Field(gt=0, le=100, allow_inf_nan=False)] = None


EventIn = Annotated[StepIn | WifiIn | BleIn | MagIn | ImuIn | GnssIn, Field(discriminator="type")]


# ---------------------------------------------------------------- fixes


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
    uncertainty_m: float
    source: str
    engine: str
    diagnostics: dict[str, float] = Field(default_factory=dict)


# ---------------------------------------------------------------- sessions


class SessionCreate(StrictIn):
    site_id: Id
    engine: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[a-z0-9_]+$")] = "step_ekf"
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


# ---------------------------------------------------------------- surveys and maps


class SurveyPoint(StrictIn):
    x_m: Coordinate
    y_m: Coordinate
    floor: int = Field(description="floor level")
    t: TimestampMs | None = None
    wifi: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    ble: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    mag_ut: Annotated[tuple[FiniteFloat, FiniteFloat, FiniteFloat], LAX_ARRAY] | None = None


class SurveyIn(StrictIn):
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
    activated_at: datetime = Field(description="the current version is the one activated last")


class RadioMapList(Strict):
    items: list[RadioMapRead]
    count: int


# Survey readings must come from a calibrated magnetometer: indoor fields stay far below
# this, the hard-iron bias of an uncalibrated one often does not
SurveyField = Annotated[float, StrictMode(), Field(ge=-500, le=500, allow_inf_nan=False)]
MAX_MAGNETIC_SAMPLES = 200_000  # per request, points and line samples together


class MagneticPointIn(StrictIn):
    """The field measured standing at a marked spot."""

    x_m: Coordinate
    y_m: Coordinate
    field_ut: Annotated[tuple[SurveyField, SurveyField, SurveyField], LAX_ARRAY] | None = Field(
        None, description="calibrated field in the phone frame (µT); its norm is the magnitude"
    )
    magnitude_ut: Annotated[float | None, Field(ge=0, le=500, allow_inf_nan=False)] = None
    horizontal_ut: Annotated[float | None, Field(ge=0, le=500, allow_inf_nan=False)] = None
    vertical_ut: SurveyField | None = None

    @model_validator(mode="after")
    def _one_magnitude(self) -> MagneticPointIn:
        if (self.field_ut is None) == (self.magnitude_ut is None):
            raise ValueError("give exactly one of field_ut and magnitude_ut")
        return self


MAX_LINE_M = 1000.0  # one walked survey line: a corridor, not a city


class MagneticLineIn(StrictIn):
    """A survey line walked at constant speed from ``start`` (at ``t_start``) to ``end``
    (at ``t_end``); samples are placed along it by their time, those outside dropped."""

    start: Annotated[tuple[Coordinate, Coordinate], LAX_ARRAY]
    end: Annotated[tuple[Coordinate, Coordinate], LAX_ARRAY]
    t_start: TimestampMs
    t_end: TimestampMs
    samples: Annotated[
        list[Annotated[tuple[TimestampMs, SurveyField, SurveyField, SurveyField], LAX_ARRAY]],
        Field(min_length=1, max_length=MAX_MAGNETIC_SAMPLES),
    ] = Field(description="[t, x, y, z]: calibrated field in the phone frame (µT)")

    @model_validator(mode="after")
    def _ordered(self) -> MagneticLineIn:
        if self.t_end <= self.t_start:
            raise ValueError("t_end must be after t_start")
        length = math.dist(self.start, self.end)
        if length > MAX_LINE_M:
            raise ValueError(f"the line is {length:.0f} m long; at most {MAX_LINE_M:g} m")
        return self


class MagneticSurveyIn(StrictIn):
    points: Annotated[list[MagneticPointIn], Field(max_length=MAX_MAGNETIC_SAMPLES)] = []
    lines: Annotated[list[MagneticLineIn], Field(max_length=10_000)] = []

    @model_validator(mode="after")
    def _bounded(self) -> MagneticSurveyIn:
        total = len(self.points) + sum(len(line.samples) for line in self.lines)
        if total == 0:
            raise ValueError("points or lines must hold at least one sample")
        if total > MAX_MAGNETIC_SAMPLES:
            raise ValueError(f"at most {MAX_MAGNETIC_SAMPLES} samples per request, got {total}")
        return self


class MagneticMapRead(Strict):
    id: str
    floor_id: str
    version: int
    origin_x_m: float
    origin_y_m: float
    resolution_m: float
    n_rows: int
    n_cols: int
    n_samples: int
    known_cells: int
    source: str
    created_at: datetime
    activated_at: datetime = Field(description="the current version is the one activated last")


class MagneticMapList(Strict):
    items: list[MagneticMapRead]
    count: int


class DeviceOffsetRead(Strict):
    device_model: str = Field(description="(surveyed): the admin API's survey points")
    offset_db: float = Field(description="what this model reads above the map's common level")
    n_pairs: int = Field(description="co-located (cell, emitter) pairs behind the estimate")
    std_db: float


class DeviceOffsetList(Strict):
    items: list[DeviceOffsetRead]
    count: int


# ---------------------------------------------------------------- uploads


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


class UploadRead(Strict):
    id: str
    site_id: str
    building_id: str | None
    floor: int | None = Field(description="the floor hint given with the upload")
    device_model: str | None
    status: Literal["queued", "processing", "done", "rejected", "failed"]
    attempts: int
    report: dict[str, Any] | None = Field(
        description="what was used, what was not and why; the reason when rejected or failed"
    )
    created_at: datetime
    updated_at: datetime


# ---------------------------------------------------------------- locate


class LocateIn(StrictIn):
    site_id: Id
    wifi: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    ble: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []


class LocateOut(Strict):
    x_m: float
    y_m: float
    floor: int
    building_id: str
    floor_id: str
    cov_m2: Annotated[tuple[float, float, float, float], LAX_ARRAY]
    uncertainty_m: float


# ---------------------------------------------------------------- live socket


class LiveBatch(BatchIn):
    type: Literal["batch"]


Scope = Literal["admin", "maps:write", "viewer", "device", "contribute"]


class ApiKeyCreate(StrictIn):
    name: Name
    scopes: Annotated[list[Scope], Field(min_length=1, max_length=5)] = Field(
        description="admin: everything; maps:write: plans, surveys, uploads, map versions; "
        "viewer: reading; device: sessions and locate; contribute: sessions whose walk "
        "feeds the maps (with device)"
    )
    site_id: Id | None = Field(None, description="the one site the key is for; none: all")


class ApiKeyRead(Strict):
    id: str
    name: str
    scopes: list[str]
    site_id: str | None
    created_at: datetime
    rotated_at: datetime | None
    revoked_at: datetime | None


class ApiKeyList(Strict):
    items: list[ApiKeyRead]
    count: int


class ApiKeyCreated(ApiKeyRead):
    key: str = Field(description="the secret: shown this once, only its digest is kept")


# ---------------------------------------------------------------- map quality


class MapVersionRef(Strict):
    id: str
    version: int


class Percentiles(Strict):
    p10: float
    p50: float
    p90: float


class MapCoverage(Strict):
    radio: float | None = Field(
        description="share of the walkable 1 m cells (centre walkable) holding a reference "
        "point of this floor; without a plan, of the 1 m cells of the reference points' "
        "bounding box; null when the plan has no walkable cell"
    )
    magnetic: float | None = Field(
        description="share of the walkable cells of the magnetic grid's lattice (0.5 m, "
        "centre walkable) whose field is known; without a plan, of the grid's own cells"
    )
    walkable_area_known: bool = Field(
        description="the floor has a usable plan, so the shares are over its walkable area"
    )


class RadioCellsQuality(Strict):
    n_reference_points: int = Field(description="reference points of this floor")
    readings_per_rp: Percentiles | None = Field(
        description="RSS readings (all emitters) folded into a reference point"
    )
    emitters_per_rp: Percentiles | None = Field(description="emitters heard at a reference point")
    var_db2: Percentiles | None = Field(
        description="RSS variance (dB²) over reference point x emitter entries with at least "
        "2 readings"
    )


class MagneticCellsQuality(Strict):
    known_cells: int = Field(description="grid cells with a known field")
    samples_per_cell: Percentiles | None = Field(description="samples per known cell")
    var_ut2: Percentiles | None = Field(
        description="field magnitude variance (µT²) over cells with at least 2 samples"
    )


class MapFreshness(Strict):
    newest: datetime | None = Field(description="creation time of the newest survey point")
    oldest: datetime | None = Field(description="creation time of the oldest survey point")
    n_cells: int = Field(description="1 m cells holding survey points")
    cell_age_days: Percentiles | None = Field(
        description="per 1 m cell with survey points: days since its newest point was created"
    )
    n_points: int = Field(description="survey points of this floor")
    n_surveyed_points: int = Field(description="points surveyed through the admin API")
    n_uploads: int = Field(description="distinct uploads that contributed points")


class EmitterPositionOut(Strict):
    kind: Literal["wifi", "ble"]
    key: str = Field(description="lower-cased BSSID or beacon id")
    x_m: float
    y_m: float
    xy_std_m: Annotated[tuple[float, float], LAX_ARRAY] | None = Field(
        description="standard deviations of x and y from the fit; null when the noise cannot "
        "be estimated (exactly 4 readings)"
    )
    p0_dbm: float = Field(description="RSS at 1 m")
    exponent: float = Field(description="path-loss exponent")
    n: int = Field(description="readings fitted")
    residual_rms_db: float


class EmitterQuality(Strict):
    seen: int = Field(description="emitters heard at a reference point of this floor")
    fixed: int = Field(
        description="WiFi APs identified as fixed on this floor from the timed survey "
        "readings (heard on 4+ days, once above -55 dBm, strong readings clustered in "
        "under 100 m²)"
    )
    retired: int = Field(
        description="seen emitters that no survey point of this floor heard in the "
        "retired_after_days days before the floor's newest survey point"
    )
    positions: list[EmitterPositionOut] = Field(
        description="log-distance fits of the max_emitters most-read emitters, where the "
        "readings determine one"
    )
    unlocated: int = Field(
        description="emitters among the max_emitters most-read whose fit is under-determined"
    )


class MapQualityRead(Strict):
    floor_id: str
    radio_map: MapVersionRef | None = Field(description="the building's latest radio map")
    magnetic_map: MapVersionRef | None = Field(description="the floor's latest magnetic map")
    coverage: MapCoverage
    radio_cells: RadioCellsQuality
    magnetic_cells: MagneticCellsQuality
    freshness: MapFreshness
    emitters: EmitterQuality
