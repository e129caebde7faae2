"""Anchors marked in a floor plan."""

from __future__ import annotations

from typing import Any

from server.positioning.plan.anchors import Anchor, anchors_from_plan


def point(x: Any, y: Any, **props: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "geometry": {"type": "Point", "coordinates": [x, y]},
        "properties": props,
    }


def test_points_with_a_beacon_are_anchors() -> None:
    plan = {
        "type": "FeatureCollection",
        "features": [
            point(1.0, 2.0, anchor="elevator", beacon="Lift-1"),
            point(5, 6, beacon="door", rssi_dbm=-70),
            point(9.0, 9.0, name="shop"),  # no beacon: not an anchor
            {
                "type": "Feature",
                "geometry": {"type": "Polygon", "coordinates": []},
                "properties": {"beacon": "x"},
            },
            point("a", 2.0, beacon="bad"),  # malformed coordinates: skipped
            point(float("nan"), 2.0, beacon="nan"),
            point(True, 2.0, beacon="bool"),
            point(1.0, 2.0, beacon="loud", rssi_dbm="strong"),
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": {"x": 1, "y": 2}},
                "properties": {"beacon": "mapping"},
            },
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": "12"},
                "properties": {"beacon": "text"},
            },
            "not a feature",
        ],
    }
    assert anchors_from_plan(plan, 3) == (
        Anchor(3, 1.0, 2.0, "ble:lift-1", -65.0),
        Anchor(3, 5.0, 6.0, "ble:door", -70.0),
    )


def test_no_plan_no_anchors() -> None:
    assert anchors_from_plan(None, 0) == ()
    assert anchors_from_plan({"type": "FeatureCollection", "features": []}, 0) == ()
