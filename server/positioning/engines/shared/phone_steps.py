"""What the engines on the phone's step events share (``step_ekf``, ``fai_ekf``,
``map_markov``): the event kinds they read and their routes. The engines that find their
own steps in raw samples share theirs in ``pdr_kalman``."""

from __future__ import annotations

from typing import TypeVar

from server.positioning.engines.shared.spec import Handler, Route, on, on_scans
from server.positioning.model.accuracy import EngineParams
from server.positioning.model.events import BleEvent, StepEvent, WifiEvent
from server.positioning.motion.barometer import FloorChange

S = TypeVar("S")
P = TypeVar("P", bound=EngineParams)

# the phone's steps, WiFi/BLE scans and the barometer (raw samples only for their pressure
# rows: the pre-pass ``spec.with_floor_changes``)
USES = frozenset({"step", "wifi", "ble", "pressure"})


def routes(
    on_step: Handler[S, StepEvent, P],
    on_scan: Handler[S, WifiEvent | BleEvent, P],
    on_floor_change: Handler[S, FloorChange, P],
) -> tuple[Route[S, P], ...]:
    """The steps, the scans and the barometer's floor changes, each to its handler."""
    return (on(StepEvent, on_step), *on_scans(on_scan), on(FloorChange, on_floor_change))
