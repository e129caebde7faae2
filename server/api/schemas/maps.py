"""Surveys, radio and magnetic map versions, per-model RSS offsets."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated, Literal

from pydantic import Field, StringConstraints, model_validator
from pydantic import (
    Strict as StrictMode,
)

from server.api.schemas.common import (
    LAX_ARRAY,
    Coordinate,
    Strict,
    StrictIn,
    TimestampMs,
)
from server.api.schemas.events import MAX_READINGS_PER_SCAN, BleReading, WifiReading

WalkName = Annotated[str, StringConstraints(min_length=1, max_length=64)]
# Survey readings (magnetic surveys and the radio survey's mag_ut, which go into the same
# magnetic maps) must come from a calibrated magnetometer: indoor fields stay far below
# this, the hard-iron bias of an uncalibrated one often does not
SurveyField = Annotated[float, StrictMode(), Field(ge=-500, le=500, allow_inf_nan=False)]


class SurveyPoint(StrictIn):
    x_m: Coordinate
    y_m: Coordinate
    floor: int = Field(description="floor level")
    t: TimestampMs | None = None
    wifi: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    ble: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    mag_ut: Annotated[tuple[SurveyField, SurveyField, SurveyField], LAX_ARRAY] | None = Field(
        None,
        description="calibrated magnetic field in µT, each axis within ±500; its norm goes "
        "into the floor's magnetic map",
    )
    walk: WalkName | None = Field(
        None,
        description="the recorded walk this point was taken on: a walk's points in time "
        "order are where people walk (the floor graphs learn their moves from them), and "
        "they are held out together when the map's fix error is learned; without one the "
        "point stands on its own",
    )
    route: WalkName | None = Field(
        None,
        description="walks repeated along one route share a route name: their points are "
        "held out together when the fix error is learned",
    )


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
    build_status: Literal["pending", "built", "failed", "superseded"] = Field(
        description="what the worker has made of the version beside its radio map (the "
        "fix-error table sessions' radii come from, FAI maps, floor graphs with moves "
        "learned from the walks): pending until it has; superseded: a newer version came "
        "first (built if activated again); failed: sessions use the defaults"
    )
    build_seconds: float | None = Field(None, description="how long the build took")


class RadioMapList(Strict):
    items: list[RadioMapRead]
    count: int


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
