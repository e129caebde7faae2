"""A session's fixes as GeoJSON and as MF-JSON, on fixes small enough to check by hand."""

from __future__ import annotations

from typing import Any

import pytest
from geojson_pydantic import FeatureCollection

from server.services.track_export import (
    NoWorldPosition,
    geojson_track,
    iso_ms,
    mfjson_track,
)

T0 = 1_700_000_000_000  # 2023-11-14T22:13:20Z
SID = "a" * 32


def fix(t: int, lon: float, lat: float, level: int = 0, accuracy: float = 2.0) -> dict[str, Any]:
    """A fix as the service answers it, with what the exports read."""
    return {
        "t": t,
        "lon": lon,
        "lat": lat,
        "level": level,
        "floor": level,
        "floor_id": f"floor{level}",
        "building_id": "b1",
        "accuracy_m": accuracy,
    }


def test_times_are_iso_8601_in_utc_to_the_millisecond() -> None:
    assert iso_ms(T0) == "2023-11-14T22:13:20.000Z"
    assert iso_ms(T0 + 1) == "2023-11-14T22:13:20.001Z"


def test_a_line_per_run_on_one_floor_and_a_point_for_a_run_of_one() -> None:
    fixes = [
        fix(T0, 10.0, 50.0),
        fix(T0 + 1000, 10.00001, 50.0, accuracy=3.0),
        fix(T0 + 2000, 10.00002, 50.0, level=1),  # up the stairs: a run of one
        fix(T0 + 3000, 10.00003, 50.00001),  # and back down
        fix(T0 + 4000, 10.00004, 50.00002),
    ]
    track = geojson_track(SID, reversed(fixes))  # put in time order
    FeatureCollection.model_validate(track)  # a valid RFC 7946 document
    first, stairs, last = track["features"]
    assert first["geometry"] == {
        "type": "LineString",
        "coordinates": [[10.0, 50.0], [10.00001, 50.0]],
    }
    assert first["properties"] == {
        "session_id": SID,
        "building_id": "b1",
        "floor_id": "floor0",
        "level": 0,
        "start": "2023-11-14T22:13:20.000Z",
        "end": "2023-11-14T22:13:21.000Z",
        "times_ms": [T0, T0 + 1000],
        "coordTimes": ["2023-11-14T22:13:20.000Z", "2023-11-14T22:13:21.000Z"],
        "accuracy_m": [2.0, 3.0],
    }
    assert stairs["geometry"] == {"type": "Point", "coordinates": [10.00002, 50.0]}
    assert stairs["properties"]["level"] == 1
    assert stairs["properties"]["times_ms"] == [T0 + 2000]
    assert last["geometry"]["coordinates"] == [[10.00003, 50.00001], [10.00004, 50.00002]]
    # every fix is a vertex, once
    assert sum(len(f["properties"]["times_ms"]) for f in track["features"]) == len(fixes)


def test_positions_are_rounded_to_about_a_centimetre() -> None:
    track = geojson_track(SID, [fix(T0, 10.123456789, -33.987654321)])
    assert track["features"][0]["geometry"]["coordinates"] == [10.1234568, -33.9876543]


def test_no_fixes_no_features() -> None:
    assert geojson_track(SID, []) == {"type": "FeatureCollection", "features": []}
    assert mfjson_track(SID, []) == {"type": "FeatureCollection", "features": []}


def test_a_single_fix_is_one_discrete_instant_in_mfjson() -> None:
    document = mfjson_track(SID, [fix(T0, 10.0, 50.0), fix(T0, 10.00001, 50.0, accuracy=3.0)])
    (feature,) = document["features"]
    when = ["2023-11-14T22:13:20.000Z"]
    assert feature["temporalGeometry"] == {
        "type": "MovingPoint",
        "datetimes": when,
        "coordinates": [[10.00001, 50.0]],
        "interpolation": "Discrete",
    }
    (properties,) = feature["temporalProperties"]
    assert properties["datetimes"] == when
    assert properties["accuracy_m"]["values"] == [3.0]
    assert {properties[name]["interpolation"] for name in ("accuracy_m", "level", "floor_id")} == {
        "Discrete"
    }
    assert feature["geometry"] == {"type": "Point", "coordinates": [10.00001, 50.0]}
    assert feature["time"] == [when[0], when[0]]
    assert feature["bbox"] == [10.00001, 50.0, 10.00001, 50.0]
    FeatureCollection.model_validate(document)


def test_a_property_some_fixes_lack_has_its_own_times_in_mfjson() -> None:
    fixes = [
        {**fix(T0, 10.0, 50.0), "accuracy_m": None},
        fix(T0 + 1000, 10.00001, 50.0, accuracy=3.0),
        {**fix(T0 + 2000, 10.00002, 50.0), "accuracy_m": None},
        fix(T0 + 3000, 10.00003, 50.0, accuracy=5.0),
    ]
    (feature,) = mfjson_track(SID, fixes)["features"]
    every, accuracy = feature["temporalProperties"]
    assert len(every["datetimes"]) == 4
    assert set(every) == {"datetimes", "level", "floor_id"}
    assert accuracy["datetimes"] == ["2023-11-14T22:13:21.000Z", "2023-11-14T22:13:23.000Z"]
    assert accuracy["accuracy_m"]["values"] == [3.0, 5.0]  # numbers only, as 19-045r3 asks
    assert accuracy["accuracy_m"]["interpolation"] == "Linear"
    # a property none of them has is left out
    nowhere = [{**f, "accuracy_m": None} for f in fixes]
    (feature,) = mfjson_track(SID, nowhere)["features"]
    (every,) = feature["temporalProperties"]
    assert "accuracy_m" not in every
    for group in feature["temporalProperties"]:
        for name, values in group.items():
            if name != "datetimes":
                assert None not in values["values"]


def test_fixes_without_a_world_position_name_their_building() -> None:
    unreferenced = {**fix(T0, 0.0, 0.0), "lat": None, "lon": None, "building_id": "b9"}
    for export in (geojson_track, mfjson_track):
        with pytest.raises(NoWorldPosition, match="building b9") as caught:
            export(SID, [fix(T0 - 1000, 10.0, 50.0), unreferenced])
        assert caught.value.building_id == "b9"


def test_mfjson_is_one_moving_point_with_its_properties_over_time() -> None:
    fixes = [
        fix(T0, 10.0, 50.0),
        fix(T0 + 1000, 10.00001, 50.0, accuracy=3.0),
        fix(T0 + 1000, 10.00002, 50.0, accuracy=4.0),  # the same time: the last is kept
        fix(T0 + 2500, 10.00003, 50.00001, level=1, accuracy=5.0),
    ]
    document = mfjson_track(SID, fixes)
    (feature,) = document["features"]
    assert feature["type"] == "Feature"
    assert feature["id"] == SID
    times = ["2023-11-14T22:13:20.000Z", "2023-11-14T22:13:21.000Z", "2023-11-14T22:13:22.500Z"]
    coordinates = [[10.0, 50.0], [10.00002, 50.0], [10.00003, 50.00001]]
    assert feature["temporalGeometry"] == {
        "type": "MovingPoint",
        "datetimes": times,
        "coordinates": coordinates,
        "interpolation": "Linear",
    }
    (properties,) = feature["temporalProperties"]
    assert properties["datetimes"] == times
    assert properties["accuracy_m"]["values"] == [2.0, 4.0, 5.0]
    assert properties["accuracy_m"]["type"] == "Measure"
    assert properties["level"] == {
        **properties["level"],
        "values": [0, 0, 1],
        "interpolation": "Step",
    }
    assert properties["floor_id"]["values"] == ["floor0", "floor0", "floor1"]
    assert feature["time"] == [times[0], times[-1]]
    assert feature["bbox"] == [10.0, 50.0, 10.00003, 50.00001]
    assert feature["geometry"] == {"type": "LineString", "coordinates": coordinates}
    assert "crs" not in feature  # CRS84 is MF-JSON's default; RFC 7946 has no crs
    # what of it is GeoJSON is valid GeoJSON (MF-JSON extends it)
    FeatureCollection.model_validate(document)
