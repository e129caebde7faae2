"""Wire models to the core's event model and back."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.api.schemas.events import (
    BleIn,
    BleReading,
    GnssIn,
    ImuIn,
    MagIn,
    StepIn,
    WifiIn,
    WifiReading,
)
from server.positioning.model.events import (
    BleEvent,
    Event,
    Fix,
    GnssEvent,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)

WireEvent = StepIn | WifiIn | BleIn | MagIn | ImuIn | GnssIn


def _samples(rows: Sequence[tuple[float, ...]], width: int) -> NDArray[np.float64]:
    return np.array(rows, dtype=np.float64).reshape(-1, width)


def _rows(samples: NDArray[np.float64]) -> list[list[float | int]]:
    """Sample rows on the wire: the time as an integer, the values as they are."""
    return [[int(row[0]), *row[1:]] for row in samples.tolist()]


def to_event(e: WireEvent) -> Event:
    match e:
        case StepIn():
            return StepEvent(e.t, e.length_m, e.heading_rad, e.confidence)
        case WifiIn():
            return WifiEvent(
                e.t, tuple(RadioReading(r.bssid, r.rssi_dbm, r.age_ms) for r in e.readings)
            )
        case BleIn():
            return BleEvent(
                e.t, tuple(RadioReading(r.id, r.rssi_dbm, r.age_ms) for r in e.readings)
            )
        case MagIn():
            return MagEvent(e.t, e.field_ut, e.magnitude_ut)
        case GnssIn():
            return GnssEvent(e.t, e.lat_deg, e.lon_deg, e.accuracy_m, e.hdop)
        case ImuIn():
            return ImuEvent(
                e.t,
                accel=_samples(e.accel, 4),
                gyro=_samples(e.gyro, 4),
                magnetic=_samples(e.magnetic, 4),
                magnetic_calibrated=e.magnetic_calibrated,
                rotation=_samples(e.rotation, 5),
                pressure=_samples(e.pressure, 2),
            )


def to_events(events: Sequence[WireEvent]) -> list[Event]:
    return [to_event(e) for e in events]


def wifi_pairs(readings: Sequence[WifiReading]) -> list[tuple[str, float]]:
    return [(r.bssid, r.rssi_dbm) for r in readings]


def ble_pairs(readings: Sequence[BleReading]) -> list[tuple[str, float]]:
    return [(r.id, r.rssi_dbm) for r in readings]


def _reading(key: str, r: RadioReading) -> dict[str, Any]:
    out: dict[str, Any] = {key: r.emitter, "rssi_dbm": r.rssi_dbm}
    if r.age_ms is not None:
        out["age_ms"] = round(r.age_ms)
    return out


def to_wire(event: Event) -> dict[str, Any]:
    """The batch-API form of a core event (the inverse of ``to_event``)."""
    match event:
        case StepEvent():
            return {
                "type": "step",
                "t": event.t_ms,
                "length_m": event.length_m,
                "heading_rad": event.heading_rad,
                "confidence": event.confidence,
            }
        case WifiEvent():
            readings = [_reading("bssid", r) for r in event.readings]
            return {"type": "wifi", "t": event.t_ms, "readings": readings}
        case BleEvent():
            readings = [_reading("id", r) for r in event.readings]
            return {"type": "ble", "t": event.t_ms, "readings": readings}
        case MagEvent():
            return {
                "type": "mag",
                "t": event.t_ms,
                "field_ut": list(event.field_ut) if event.field_ut else None,
                "magnitude_ut": event.magnitude_ut,
            }
        case GnssEvent():
            return {
                "type": "gnss",
                "t": event.t_ms,
                "lat_deg": event.lat_deg,
                "lon_deg": event.lon_deg,
                "accuracy_m": event.accuracy_m,
                "hdop": event.hdop,
            }
        case ImuEvent():
            return {
                "type": "imu",
                "t": event.t_ms,
                **{name: _rows(samples) for name, samples in event.sensors().items()},
                "magnetic_calibrated": event.magnetic_calibrated,
            }


def fix_from_wire(body: Mapping[str, Any], floor_index: Mapping[int, int]) -> Fix:
    """A wire fix back into the core's form; ``floor_index`` maps levels to floor indices."""
    level = body.get("floor")
    cov = body["cov_m2"]
    return Fix(
        t_ms=int(body["t"]),
        x_m=float(body["x_m"]),
        y_m=float(body["y_m"]),
        floor=floor_index.get(int(level), -1) if level is not None else -1,
        heading_rad=body.get("heading_rad"),
        cov=(float(cov[0]), float(cov[1]), float(cov[2]), float(cov[3])),
        source=str(body["source"]),
        diagnostics=dict(body.get("diagnostics", {})),
        accuracy_68_m=_number(body.get("accuracy_68_m")),
        accuracy_95_m=_number(body.get("accuracy_95_m")),
        floor_prob=_number(body.get("floor_prob")),
    )


def _number(value: object) -> float:
    """A wire number, NaN for null."""
    return math.nan if value is None else float(value)  # type: ignore[arg-type]
