"""Wire models to the core's event model and back."""

from __future__ import annotations

from collections.abc import Sequence

from server.api import schemas as sc
from server.positioning.events import (
    BleEvent,
    Event,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)


def to_event(e: sc.StepIn | sc.WifiIn | sc.BleIn | sc.MagIn) -> Event:
    match e:
        case sc.StepIn():
            return StepEvent(e.t, e.length_m, e.heading_rad, e.confidence)
        case sc.WifiIn():
            return WifiEvent(e.t, tuple(RadioReading(r.bssid, r.rssi_dbm) for r in e.readings))
        case sc.BleIn():
            return BleEvent(e.t, tuple(RadioReading(r.id, r.rssi_dbm) for r in e.readings))
        case sc.MagIn():
            return MagEvent(e.t, e.field_ut, e.magnitude_ut)


def to_events(events: Sequence[sc.StepIn | sc.WifiIn | sc.BleIn | sc.MagIn]) -> list[Event]:
    return [to_event(e) for e in events]


def wifi_pairs(readings: Sequence[sc.WifiReading]) -> list[tuple[str, float]]:
    return [(r.bssid, r.rssi_dbm) for r in readings]


def ble_pairs(readings: Sequence[sc.BleReading]) -> list[tuple[str, float]]:
    return [(r.id, r.rssi_dbm) for r in readings]
