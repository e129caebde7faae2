"""Anchors read from a floor plan: points where a BLE beacon marks a known place.

A floor plan (GeoJSON in the building frame, metres) marks an anchor with a ``Point``
feature whose properties name the beacon::

    {"type": "Feature",
     "geometry": {"type": "Point", "coordinates": [12.5, 40.0]},
     "properties": {"anchor": "elevator", "beacon": "<BLE id>", "rssi_dbm": -65}}

``rssi_dbm`` (optional, default -65) is the level at which the phone counts as being at
the anchor: the first scan that hears the beacon at or above it. ``papers/003_*`` section
IV-B smooths the RSS and waits for its peak; taking the first scan over the threshold
answers sooner but places the phone a little before the anchor. Other features, and
anchor points that are malformed, are skipped.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from server.positioning.model.events import radio_key

DEFAULT_RSSI_DBM = -65.0


@dataclass(frozen=True, slots=True)
class Anchor:
    """A place the phone can tell it is at: a BLE beacon at a known position, such as an
    elevator or an entrance (``papers/003_*`` section IV-B); it is passed when the beacon
    is heard at or above ``rssi_dbm``."""

    floor: int
    x_m: float
    y_m: float
    emitter: str  # radio-map key of the beacon, "ble:<id>"
    rssi_dbm: float = -65.0


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def anchors_from_plan(plan: Mapping[str, Any] | None, floor: int) -> tuple[Anchor, ...]:
    """The anchors a floor plan marks, on floor index ``floor``."""
    if not plan:
        return ()
    found: list[Anchor] = []
    for feature in plan.get("features") or ():
        if not isinstance(feature, Mapping):
            continue
        props = feature.get("properties") or {}
        geometry = feature.get("geometry") or {}
        if not (isinstance(props, Mapping) and isinstance(geometry, Mapping)):
            continue
        beacon = props.get("beacon")
        coords: Any = geometry.get("coordinates")
        if geometry.get("type") != "Point" or not isinstance(beacon, str) or not beacon:
            continue
        rssi: Any = props.get("rssi_dbm", DEFAULT_RSSI_DBM)
        if not (isinstance(coords, list | tuple) and len(coords) >= 2):
            continue
        values = (coords[0], coords[1], rssi)
        if all(_is_number(v) and math.isfinite(v) for v in values):
            x, y = float(coords[0]), float(coords[1])
            found.append(Anchor(floor, x, y, radio_key("ble", beacon), float(rssi)))
    return tuple(found)
