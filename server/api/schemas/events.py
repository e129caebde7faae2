"""Radio readings and the typed events a batch or an upload carries."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator
from pydantic import (
    Strict as StrictMode,
)

from server.api.schemas.common import LAX_ARRAY, EmitterId, StrictIn, TimestampMs

MAX_READINGS_PER_SCAN = 2048  # malls with every SSID per radio reach 500+
# raw motion samples: one sensor at 200 Hz for a whole minute fits an event
MAX_IMU_ROWS_PER_SENSOR = 12_000
MAX_IMU_SPAN_MS = 60_000  # no sample later than t + this
MAX_IMU_RATE_HZ = 500  # mean rate of one sensor over its samples in one event


MAX_READING_AGE_MS = 600_000  # a reading ten minutes old says nothing of where the phone is

ReadingAge = Annotated[
    int | None,
    Field(
        ge=0,
        le=MAX_READING_AGE_MS,
        description="how long before the scan's `t` the emitter was last heard, in ms: "
        "scans list cached results seconds old beside fresh ones, and matching discounts "
        "them. Android: `t` minus `ScanResult.timestamp` (µs since boot, /1000) taken on "
        "`SystemClock.elapsedRealtime()`; iOS (beacons): 0 for ranged beacons. Omitted: "
        "fresh",
    ),
]


# a magnetometer axis in µT: Earth's field is 25-65 µT, steel and motors indoors add a few
# hundred, and a raw (uncalibrated) magnetometer reports as much again of hard-iron bias;
# phone magnetometers saturate at ±4900 µT at most, so ±5000 µT refuses only what no phone
# measures (a field of 1e308 µT would overflow the particle filter's arithmetic)
Magnetic = Annotated[float, StrictMode(), Field(ge=-5000, le=5000, allow_inf_nan=False)]
# an azimuth in either convention: Android's [-π, π] or a compass bearing's [0, 2π)
Heading = Annotated[
    float,
    StrictMode(),
    Field(
        ge=-2 * math.pi,
        le=2 * math.pi,
        allow_inf_nan=False,
        description="radians clockwise from north, in [-2π, 2π]: one turn either way",
    ),
]


class WifiReading(StrictIn):
    bssid: EmitterId
    rssi_dbm: Annotated[float, Field(ge=-130, le=0, allow_inf_nan=False)]
    age_ms: ReadingAge = None


class BleReading(StrictIn):
    id: EmitterId
    rssi_dbm: Annotated[float, Field(ge=-130, le=0, allow_inf_nan=False)]
    age_ms: ReadingAge = None


class StepIn(StrictIn):
    type: Literal["step"]
    t: TimestampMs
    length_m: Annotated[float, Field(gt=0, le=3.0, allow_inf_nan=False)]
    heading_rad: Heading
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
    field_ut: Annotated[tuple[Magnetic, Magnetic, Magnetic], LAX_ARRAY] | None = None
    magnitude_ut: Annotated[float | None, Field(ge=0, le=2000, allow_inf_nan=False)] = None

    @model_validator(mode="after")
    def _has_field(self) -> MagIn:
        if self.field_ut is None and self.magnitude_ut is None:
            raise ValueError("field_ut or magnitude_ut is required")
        return self


# plausible ranges: accelerometers saturate at 16 g, gyroscopes at 2000 °/s
Accel = Annotated[float, StrictMode(), Field(ge=-160, le=160, allow_inf_nan=False)]
Gyro = Annotated[float, StrictMode(), Field(ge=-35, le=35, allow_inf_nan=False)]
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
