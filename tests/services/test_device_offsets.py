"""Scans of a phone model brought to the map's common level."""

from __future__ import annotations

from server.positioning.model.events import BleEvent, RadioReading, StepEvent, WifiEvent
from server.services.device_offsets import on_common_level


def test_offsets_come_off_radio_readings_only() -> None:
    wifi = WifiEvent(1, (RadioReading("a", -60.0), RadioReading("b", -75.5, 3000.0)))
    ble = BleEvent(2, (RadioReading("u:1:2", -80.0),))
    step = StepEvent(3, 0.7, 0.0)
    out = on_common_level([wifi, ble, step], 4.5)
    # the readings keep their ages
    assert out[0] == WifiEvent(1, (RadioReading("a", -64.5), RadioReading("b", -80.0, 3000.0)))
    assert out[1] == BleEvent(2, (RadioReading("u:1:2", -84.5),))
    assert out[2] is step
    assert on_common_level([wifi], None) == [wifi]
    assert on_common_level([wifi], 0.0) == [wifi]
