"""Survey points: JSON-ready SurveyIn points over the walkable ground; chunked bodies."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from client_sim.seeding import stream
from client_sim.survey import survey_bodies, survey_points
from client_sim.world import synthesize_world

WORLD = synthesize_world(0)


def test_points_cover_every_floor_and_speak_the_wire_format() -> None:
    points = survey_points(WORLD, stream(0, "survey"), spacing_m=2.0, t0_ms=1_000)
    assert {p["floor"] for p in points} == {0, 1}
    assert len(points) > 700
    assert json.loads(json.dumps(points)) == points  # plain JSON types only
    for p in points[:50]:
        assert set(p) == {"x_m", "y_m", "floor", "t", "wifi", "ble", "mag_ut"}
        assert all(
            set(r) == {"bssid", "rssi_dbm"} and -130 <= r["rssi_dbm"] <= 0 for r in p["wifi"]
        )
        assert all(set(r) == {"id", "rssi_dbm"} for r in p["ble"])
        assert len(p["mag_ut"]) == 3
        assert all(math.isfinite(v) for v in p["mag_ut"])
    assert [p["t"] for p in points] == [1_000 + 1000 * i for i in range(len(points))]
    for level in (0, 1):
        floor = WORLD.building.floor(level)
        xy = np.array([(p["x_m"], p["y_m"]) for p in points if p["floor"] == level])
        assert np.all(floor.contains(xy))
        assert np.all(floor.wall_distance_m(xy) >= 0.24)
    assert np.mean([len(p["wifi"]) for p in points]) > 10  # a useful fingerprint


def test_same_seed_same_survey() -> None:
    a = survey_points(WORLD, stream(0, "survey"), spacing_m=4.0)
    b = survey_points(WORLD, stream(0, "survey"), spacing_m=4.0)
    assert a == b


@given(n=st.integers(0, 120), max_points=st.integers(1, 50))
def test_bodies_keep_every_point_in_order_within_the_limit(n: int, max_points: int) -> None:
    points: list[dict[str, Any]] = [{"i": i} for i in range(n)]
    bodies = list(survey_bodies(points, max_points))
    assert len(bodies) == math.ceil(n / max_points)
    assert all(set(b) == {"points"} and 1 <= len(b["points"]) <= max_points for b in bodies)
    assert [p for b in bodies for p in b["points"]] == points


def test_default_limit_is_5000_points() -> None:
    points: list[dict[str, Any]] = [{"i": i} for i in range(12_001)]
    assert [len(b["points"]) for b in survey_bodies(points)] == [5000, 5000, 2001]
    with pytest.raises(ValueError, match="max_points"):
        list(survey_bodies(points, 0))
