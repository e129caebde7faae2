"""Zones: named areas of a floor (a shop, a room, a geofence) read from GeoJSON, and which
of them hold a point.

A zone is a GeoJSON Feature with a Polygon or MultiPolygon in metres of the floor frame
(the frame of the floor's plan, ``geojson_format``). From a FeatureCollection,
:func:`zones_from_geojson` takes as zones:

* IMDF ``geofence``, ``unit`` and ``section`` features (``feature_type`` beside or inside
  ``properties``), so that a plan's own units and geofences serve as they are (but not
  the units a plan takes for obstacles: columns, structure);
* features whose ``properties.kind`` is ``"zone"``;
* areas with neither a ``feature_type`` nor a ``kind`` (plain polygons).

Everything else of a plan (walls, doors, walkable areas, points, IMDF openings and levels)
is skipped and counted. A zone's ``id`` is the feature's ``id`` (or ``properties.id``); one
without is named by a digest of its name and geometry, so sending the same zones again
keeps their ids (and the sessions inside them stay inside). Its name is
``properties.name``: a string, or an IMDF labels object (``{"en": "Café"}``, English
first); the properties are kept as sent.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from server.positioning.plan.geojson_format import (
    AREA_TYPES,
    PlanError,
    check_coordinates,
    feature_kind,
    text,
)

ZONE_FEATURE_TYPES = frozenset({"geofence", "unit", "section"})
ZONE_KIND = "zone"
ZONE_ID = re.compile(r"[A-Za-z0-9._:~-]{1,64}")
NAME_MAX = 200


@dataclass(frozen=True)
class ZoneFeature:
    """A zone as read from GeoJSON (floor metres)."""

    id: str
    name: str
    geometry: Mapping[str, Any]
    properties: Mapping[str, Any]


@dataclass(frozen=True)
class ReadZones:
    zones: tuple[ZoneFeature, ...]
    skipped: int  # features of the collection that are not zones


@dataclass(frozen=True)
class Zone:
    """A zone of a site: ``floor`` is an index into ``SiteMaps.floors``."""

    floor: int
    floor_id: str
    id: str
    name: str
    shape: BaseGeometry = field(repr=False, compare=False)

    @property
    def key(self) -> str:
        """Unique in the site (a zone's ``id`` is unique on its floor only)."""
        return f"{self.floor_id}/{self.id}"

    @cached_property
    def _edge(self) -> BaseGeometry:
        return self.shape.boundary

    def border_distance_m(self, x_m: float, y_m: float) -> float:
        """How far a point of the zone's floor is from its border, inside or out."""
        return float(shapely.distance(self._edge, shapely.Point(x_m, y_m)))


def _is_zone(feature: Mapping[str, Any], properties: Mapping[str, Any]) -> bool:
    """Whether a feature is a zone (module docstring); an IMDF unit is one unless its
    category makes it an obstacle (a column, a structure)."""
    feature_type = text(feature.get("feature_type", properties.get("feature_type")))
    if feature_type is not None:
        if feature_type == "unit":
            return feature_kind(feature) != "obstacle"
        return feature_type in ZONE_FEATURE_TYPES
    kind = properties.get("kind")
    if kind is not None:
        return bool(kind == ZONE_KIND)
    geometry = feature.get("geometry")
    # a plan's points without a kind (an entrance) are not zones; a plain area is
    return not (isinstance(geometry, Mapping) and text(geometry.get("type")) not in AREA_TYPES)


def feature_name(properties: Mapping[str, Any]) -> str | None:
    """A feature's name: ``name`` (or ``alt_name``), a string or IMDF labels (English
    first); None without one."""
    for key in ("name", "alt_name"):
        value = properties.get(key)
        if isinstance(value, str) and value.strip():
            return value.strip()
        if isinstance(value, Mapping):  # IMDF labels: {"en": "Shop", "fr": "Boutique"}
            labels = [value.get("en"), *value.values()]
            found = next((v.strip() for v in labels if isinstance(v, str) and v.strip()), None)
            if found:
                return found
    return None


def _feature_id(at: str, feature: Mapping[str, Any], properties: Mapping[str, Any]) -> str | None:
    raw = feature.get("id", properties.get("id"))
    if raw is None:
        return None
    if isinstance(raw, bool) or not isinstance(raw, str | int):
        raise PlanError(f"{at}.id", f"a zone's id is a string or an integer, not {raw!r}")
    value = str(raw)
    if not ZONE_ID.fullmatch(value):
        raise PlanError(
            f"{at}.id", f"a zone's id is 1 to 64 letters, digits or ._:~- ; not {value!r}"
        )
    return value


def zones_from_geojson(collection: Mapping[str, Any]) -> ReadZones:
    """The zones of a FeatureCollection (module docstring); ``PlanError`` naming the
    field at fault for a zone that is not one (``features.2.geometry.type``)."""
    if collection.get("type") != "FeatureCollection":
        raise PlanError("type", "zones come as a GeoJSON FeatureCollection")
    features = collection.get("features")
    if not isinstance(features, list):
        raise PlanError("features", "must be a list of GeoJSON features")
    zones: list[ZoneFeature] = []
    seen: dict[str, int] = {}
    skipped = 0
    for i, feature in enumerate(features):
        at = f"features.{i}"
        if not isinstance(feature, Mapping) or feature.get("type") != "Feature":
            raise PlanError(at, "must be a GeoJSON Feature")
        properties = feature.get("properties")
        if properties is not None and not isinstance(properties, Mapping):
            raise PlanError(f"{at}.properties", "must be an object or null")
        properties = properties or {}
        if not _is_zone(feature, properties):
            skipped += 1
            continue
        geometry = feature.get("geometry")
        if not isinstance(geometry, Mapping):
            raise PlanError(f"{at}.geometry", "a zone is a Polygon or MultiPolygon")
        geometry_type = text(geometry.get("type"))
        if geometry_type not in AREA_TYPES:
            raise PlanError(
                f"{at}.geometry.type", f"a zone is a Polygon or MultiPolygon, not {geometry_type!r}"
            )
        check_coordinates(f"{at}.geometry.coordinates", geometry_type, geometry.get("coordinates"))
        shape = shapely.geometry.shape(dict(geometry))
        if not shapely.is_valid(shape):
            raise PlanError(
                f"{at}.geometry", f"not a valid {geometry_type} ({shapely.is_valid_reason(shape)})"
            )
        name = feature_name(properties)
        if name is not None and len(name) > NAME_MAX:
            raise PlanError(f"{at}.properties.name", f"at most {NAME_MAX} characters")
        plain = {"type": geometry_type, "coordinates": geometry["coordinates"]}
        zone_id = _feature_id(at, feature, properties) or _digest(name, plain)
        if zone_id in seen:
            raise PlanError(f"{at}.id", f"{zone_id!r} is the id of features.{seen[zone_id]} too")
        seen[zone_id] = i
        zones.append(ZoneFeature(zone_id, name or zone_id, plain, dict(properties)))
    return ReadZones(tuple(zones), skipped)


def _digest(name: str | None, geometry: Mapping[str, Any]) -> str:
    data = json.dumps([name, geometry], sort_keys=True, separators=(",", ":")).encode()
    return "z" + hashlib.sha256(data).hexdigest()[:15]


def as_feature(zone: ZoneFeature) -> dict[str, Any]:
    """A zone as a GeoJSON Feature with its name beside its properties (as sent), which
    ``zones_from_geojson`` reads back as the same zone."""
    return {
        "type": "Feature",
        "id": zone.id,
        "name": zone.name,
        "geometry": dict(zone.geometry),
        "properties": dict(zone.properties),
    }


class ZoneIndex:
    """The zones of a site by floor, for point-in-zone questions."""

    def __init__(self, zones: Sequence[Zone], digest: str = "") -> None:
        self.zones = tuple(zones)
        self.digest = digest  # changes with any zone (the service's word, to tell a change)
        self.by_key = {z.key: z for z in self.zones}
        by_floor: dict[int, list[Zone]] = {}
        for zone in self.zones:
            by_floor.setdefault(zone.floor, []).append(zone)
        self._floors: dict[int, tuple[tuple[Zone, ...], np.ndarray, np.ndarray]] = {}
        for floor, members in by_floor.items():
            shapes = np.array([z.shape for z in members], dtype=object)
            shapely.prepare(shapes)
            self._floors[floor] = (tuple(members), shapes, shapely.bounds(shapes))

    @classmethod
    def of(
        cls, rows: Iterable[tuple[int, str, str, str, Mapping[str, Any]]], digest: str = ""
    ) -> ZoneIndex:
        """From (floor index, floor id, zone id, name, GeoJSON geometry) rows."""
        return cls(
            [Zone(f, fid, zid, n, shapely.geometry.shape(dict(g))) for f, fid, zid, n, g in rows],
            digest,
        )

    def __bool__(self) -> bool:
        return bool(self.zones)

    def at(self, floor: int, x_m: float, y_m: float) -> tuple[Zone, ...]:
        """The zones of floor ``floor`` that hold the point (a point on a zone's border is
        in it), in the order they were given."""
        return self.at_many([floor], [x_m], [y_m])[0]

    def at_many(
        self, floors: Sequence[int], xs_m: Sequence[float], ys_m: Sequence[float]
    ) -> list[tuple[Zone, ...]]:
        """``at`` for many points (a batch's fixes: a few). Per point, the zones whose
        bounding box holds it, then the exact test of those (prepared shapes): some
        microseconds, where a spatial tree's query costs more for a site's tens to
        thousands of zones."""
        out: list[tuple[Zone, ...]] = []
        for floor, x, y in zip(floors, xs_m, ys_m, strict=True):
            found = self._floors.get(floor)
            if found is None:
                out.append(())
                continue
            members, shapes, box = found
            near = np.flatnonzero(
                (box[:, 0] <= x) & (x <= box[:, 2]) & (box[:, 1] <= y) & (y <= box[:, 3])
            )
            if near.size:
                near = near[shapely.intersects_xy(shapes[near], x, y)]
            out.append(tuple(members[k] for k in near.tolist()))
        return out


NO_ZONES = ZoneIndex(())
