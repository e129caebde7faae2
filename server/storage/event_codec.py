"""A batch's events as one array container (``storage.codec``) and back, exactly.

A session's log in the session store keeps each applied batch's events, so that any
process can step the engine through them again (``services.session_records``). The
encoding is lossless: times as int64, every float as float64, an absent optional value as
NaN (the wire admits only finite values, so NaN means "absent" and nothing else).

Arrays, each event kind in the order its events came::

    kind          uint8, one per event (KINDS)
    t             int64, one per event
    step          float64 (steps, 3): length, heading, confidence
    radio/count   int64, readings per WiFi or BLE scan
    radio/value   float64 (readings, 2): RSSI, age (NaN: none)
    radio/length  int64, the utf-8 length of each reading's emitter id
    radio/id      uint8, the emitter ids one after another
    mag           float64 (mags, 4): field x, y, z (NaN: no vector), magnitude (NaN: none)
    gnss          float64 (fixes, 4): latitude, longitude, accuracy, HDOP (NaN: none)
    imu/flags     uint8, per IMU block: whether its magnetometer is calibrated
    imu/<i>/<s>   float64, the samples of sensor s of IMU block i
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.events import (
    BleEvent,
    Event,
    GnssEvent,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)
from server.storage.codec import CodecError, decode_arrays, encode_arrays

KINDS: tuple[type, ...] = (StepEvent, WifiEvent, BleEvent, MagEvent, ImuEvent, GnssEvent)
_KIND = {kind: i for i, kind in enumerate(KINDS)}
_SENSORS = ("accel", "gyro", "magnetic", "rotation", "pressure")


def _or_nan(value: float | None) -> float:
    return math.nan if value is None else value


def _or_none(value: float) -> float | None:
    return None if math.isnan(value) else value


def event_arrays(events: Sequence[Event]) -> dict[str, NDArray[np.generic]]:
    """The arrays of ``events`` (module docstring)."""
    steps: list[tuple[float, float, float]] = []
    counts: list[int] = []
    readings: list[tuple[float, float]] = []
    ids: list[bytes] = []
    mags: list[tuple[float, float, float, float]] = []
    fixes: list[tuple[float, float, float, float]] = []
    imu: dict[str, NDArray[np.generic]] = {}
    flags: list[bool] = []
    for event in events:
        match event:
            case StepEvent():
                steps.append((event.length_m, event.heading_rad, event.confidence))
            case WifiEvent() | BleEvent():
                counts.append(len(event.readings))
                for r in event.readings:
                    readings.append((r.rssi_dbm, _or_nan(r.age_ms)))
                    ids.append(r.emitter.encode())
            case MagEvent():
                x, y, z = event.field_ut if event.field_ut is not None else (math.nan,) * 3
                mags.append((x, y, z, _or_nan(event.magnitude_ut)))
            case ImuEvent():
                for name, samples in event.sensors().items():
                    imu[f"imu/{len(flags)}/{name}"] = np.asarray(samples, dtype=np.float64)
                flags.append(event.magnetic_calibrated)
            case GnssEvent():
                fixes.append((event.lat_deg, event.lon_deg, event.accuracy_m, _or_nan(event.hdop)))
    return {
        "kind": np.array([_KIND[type(e)] for e in events], dtype=np.uint8),
        "t": np.array([e.t_ms for e in events], dtype=np.int64),
        "step": np.array(steps, dtype=np.float64).reshape(-1, 3),
        "radio/count": np.array(counts, dtype=np.int64),
        "radio/value": np.array(readings, dtype=np.float64).reshape(-1, 2),
        "radio/length": np.array([len(i) for i in ids], dtype=np.int64),
        "radio/id": np.frombuffer(b"".join(ids), dtype=np.uint8),
        "mag": np.array(mags, dtype=np.float64).reshape(-1, 4),
        "gnss": np.array(fixes, dtype=np.float64).reshape(-1, 4),
        "imu/flags": np.array(flags, dtype=np.uint8),
        **imu,
    }


def events_from_arrays(arrays: dict[str, NDArray[np.generic]]) -> list[Event]:
    """The inverse of :func:`event_arrays`; :class:`CodecError` for arrays it did not make."""
    try:
        return _events(arrays)
    except (KeyError, IndexError, ValueError, UnicodeDecodeError) as e:
        raise CodecError(f"not a batch's events: {e!r}") from None


def _events(a: dict[str, NDArray[np.generic]]) -> list[Event]:
    kinds, times = a["kind"].tolist(), a["t"].tolist()
    steps, mags, fixes = a["step"].tolist(), a["mag"].tolist(), a["gnss"].tolist()
    counts, values = a["radio/count"].tolist(), a["radio/value"].tolist()
    ends = np.cumsum(a["radio/length"]).tolist()
    id_bytes = a["radio/id"].tobytes()
    flags = a["imu/flags"].tolist()
    cursor = dict.fromkeys(KINDS, 0)
    scans = reading = 0  # WiFi and BLE scans share the radio arrays
    events: list[Event] = []
    for kind_index, t in zip(kinds, times, strict=True):
        kind = KINDS[kind_index]
        i = cursor[kind]
        cursor[kind] += 1
        if kind is StepEvent:
            length, heading, confidence = steps[i]
            events.append(StepEvent(t, length, heading, confidence))
        elif kind is WifiEvent or kind is BleEvent:
            scan = []
            for r in range(reading, reading + counts[scans]):
                start = ends[r - 1] if r else 0
                rssi, age = values[r]
                scan.append(RadioReading(id_bytes[start : ends[r]].decode(), rssi, _or_none(age)))
            scans += 1
            reading += len(scan)
            events.append(kind(t, tuple(scan)))
        elif kind is MagEvent:
            x, y, z, magnitude = mags[i]
            vector = None if math.isnan(x) else (x, y, z)
            events.append(MagEvent(t, vector, _or_none(magnitude)))
        elif kind is ImuEvent:
            sensors = {s: np.asarray(a[f"imu/{i}/{s}"], dtype=np.float64) for s in _SENSORS}
            events.append(ImuEvent(t, magnetic_calibrated=bool(flags[i]), **sensors))
        else:
            lat, lon, accuracy, hdop = fixes[i]
            events.append(GnssEvent(t, lat, lon, accuracy, _or_none(hdop)))
    return events


def encode_events(events: Sequence[Event]) -> bytes:
    return encode_arrays(event_arrays(events))


def decode_events(data: bytes) -> list[Event]:
    return events_from_arrays(decode_arrays(data))
