"""A session's fixes (``FixOut`` dicts) as a GeoJSON track or as OGC Moving Features JSON.

GeoJSON (RFC 7946): a FeatureCollection in WGS84 (positions ``[lon, lat]``), one Feature
per run of consecutive fixes on one floor: a LineString through them (a Point for a run of
one fix) whose properties hold the floor (``building_id``, ``floor_id``, ``level``) and,
vertex by vertex, the times (``times_ms``, epoch milliseconds; ``coordTimes``, ISO 8601 in
UTC, the name GPX converters give them) and the 68 % radii (``accuracy_m``). Every fix is
a vertex, in time order.

MF-JSON (OGC 19-045r3, the Prism encoding): a FeatureCollection holding one moving
feature, the session: a ``MovingPoint`` temporal geometry (``datetimes``, ``coordinates``,
linear ``interpolation``), temporal properties (the 68 % radius, linear; the floor's level
and id, stepwise), and its trajectory as a GeoJSON LineString. The standard asks for
distinct, increasing times: of fixes made at the same millisecond the last is kept. A
single time is one instant (``Discrete`` interpolation, a Point trajectory); no fixes, a
collection without a feature. A temporal property's values are all of its type (numbers,
text): one that some fixes lack (an accuracy not known, say) has its own ``datetimes``,
those of the fixes that have it, and is left out when none has it. Positions are in
CRS84, MF-JSON's default, so the feature names no ``crs`` (RFC 7946 has none either).

A fix without a WGS84 position (its building had no geo-reference when it was made)
cannot be in either: ``NoWorldPosition`` names its building.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

GREGORIAN = "http://www.opengis.net/def/uom/ISO-8601/0/Gregorian"
DIGITS = 7  # of a degree: about a centimetre

Fix = Mapping[str, Any]


class NoWorldPosition(Exception):
    """Fixes of a building without a geo-reference: no WGS84 position."""

    def __init__(self, building_id: str | None) -> None:
        self.building_id = building_id
        where = f"building {building_id}" if building_id else "no building's floor"
        super().__init__(f"fixes on {where} have no WGS84 position")


def iso_ms(t_ms: int) -> str:
    """Epoch milliseconds as ISO 8601 in UTC: ``2023-11-14T22:13:20.000Z``."""
    when = datetime.fromtimestamp(t_ms / 1000, UTC)
    return when.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _in_time_order(fixes: Iterable[Fix]) -> list[Fix]:
    """The fixes by time (those of one time in the order given), each checked to have a
    WGS84 position."""
    ordered = sorted(fixes, key=lambda f: f["t"])
    for f in ordered:
        if f.get("lat") is None or f.get("lon") is None:
            raise NoWorldPosition(f.get("building_id"))
    return ordered


def _position(f: Fix) -> list[float]:
    return [round(f["lon"], DIGITS), round(f["lat"], DIGITS)]


def _floor(f: Fix) -> tuple[Any, Any, Any]:
    return f.get("building_id"), f.get("floor_id"), f.get("level")


def geojson_track(session_id: str, fixes: Iterable[Fix]) -> dict[str, Any]:
    """The fixes as an RFC 7946 FeatureCollection (module docstring)."""
    features = []
    for (building_id, floor_id, level), run in itertools.groupby(_in_time_order(fixes), _floor):
        vertices = list(run)
        coordinates = [_position(f) for f in vertices]
        geometry: dict[str, Any] = (
            {"type": "LineString", "coordinates": coordinates}
            if len(vertices) > 1
            else {"type": "Point", "coordinates": coordinates[0]}
        )
        times = [int(f["t"]) for f in vertices]
        properties = {
            "session_id": session_id,
            "building_id": building_id,
            "floor_id": floor_id,
            "level": level,
            "start": iso_ms(times[0]),
            "end": iso_ms(times[-1]),
            "times_ms": times,
            "coordTimes": [iso_ms(t) for t in times],
            "accuracy_m": [f.get("accuracy_m") for f in vertices],
        }
        features.append({"type": "Feature", "geometry": geometry, "properties": properties})
    return {"type": "FeatureCollection", "features": features}


def _one_per_time(fixes: Sequence[Fix]) -> list[Fix]:
    """Of fixes of the same time (in time order), the last."""
    return [f for i, f in enumerate(fixes) if i + 1 == len(fixes) or fixes[i + 1]["t"] != f["t"]]


# MF-JSON temporal properties: (name, what it is, interpolation between its values);
# "MTR" is the UN/CEFACT code of the metre
TEMPORAL_PROPERTIES: tuple[tuple[str, dict[str, str], str], ...] = (
    (
        "accuracy_m",
        {"type": "Measure", "form": "MTR", "description": "radius holding 68 % of the errors"},
        "Linear",
    ),
    ("level", {"type": "Measure", "description": "the floor's ordinal (0: ground floor)"}, "Step"),
    ("floor_id", {"type": "Text"}, "Step"),
)


def _temporal_properties(kept: Sequence[Fix], datetimes: list[str]) -> list[dict[str, Any]]:
    """The fixes' properties over time: those every fix has share the fixes'
    ``datetimes``; one that some lack has its own, of the fixes that have it."""
    whole: dict[str, Any] = {"datetimes": datetimes}
    groups = [whole]
    for name, kind, interpolation in TEMPORAL_PROPERTIES:
        having = [i for i, f in enumerate(kept) if f.get(name) is not None]
        if not having:
            continue
        values = {
            **kind,
            "values": [kept[i][name] for i in having],
            "interpolation": interpolation if len(having) > 1 else "Discrete",
        }
        if len(having) == len(kept):
            whole[name] = values
        else:
            groups.append({"datetimes": [datetimes[i] for i in having], name: values})
    return [group for group in groups if len(group) > 1]


def mfjson_track(session_id: str, fixes: Iterable[Fix]) -> dict[str, Any]:
    """The fixes as an MF-JSON FeatureCollection of one moving feature (module
    docstring)."""
    kept = _one_per_time(_in_time_order(fixes))
    if not kept:
        return {"type": "FeatureCollection", "features": []}
    datetimes = [iso_ms(int(f["t"])) for f in kept]
    coordinates = [_position(f) for f in kept]
    lons = [c[0] for c in coordinates]
    lats = [c[1] for c in coordinates]
    trajectory: dict[str, Any] = (
        {"type": "LineString", "coordinates": coordinates}
        if len(kept) > 1
        else {"type": "Point", "coordinates": coordinates[0]}
    )
    feature = {
        "type": "Feature",
        "id": session_id,
        "trs": {"type": "Link", "properties": {"type": "OGCDEF", "href": GREGORIAN}},
        "time": [datetimes[0], datetimes[-1]],
        "bbox": [min(lons), min(lats), max(lons), max(lats)],
        "temporalGeometry": {
            "type": "MovingPoint",
            "datetimes": datetimes,
            "coordinates": coordinates,
            "interpolation": "Linear" if len(kept) > 1 else "Discrete",
        },
        "temporalProperties": _temporal_properties(kept, datetimes),
        "geometry": trajectory,
        "properties": {"session_id": session_id},
    }
    return {"type": "FeatureCollection", "features": [feature]}
