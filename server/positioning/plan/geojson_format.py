"""The GeoJSON floor-plan format: the kinds of feature, the IMDF features that map to them,
and what a feature must be to pass (``checked_kind``), with the error that names the one
at fault (``PlanError``).

Plan format. A floor plan is a GeoJSON FeatureCollection in metres of the floor frame
(x east, y north). Each feature's ``properties.kind`` says what it is:

==============================  ==============================================================
``"walkable"``                  Polygon / MultiPolygon of open floor area people may stand on
``"outline"``                   the same (ILC: the floor outline, ``geojson_plan``)
``"room"``                      Polygon / MultiPolygon: floor area enclosed by walls along its
                                rings (doors cut gaps in them)
``"elevator"``, ``"stairs"``,   Polygon / MultiPolygon: open floor area where a walk may leave
``"escalator"``                 the floor (``navigation_graph``)
``"wall"``                      LineString / MultiLineString: a thin wall; Polygon /
                                MultiPolygon: a solid block (thick wall, pillar, closed room)
``"unit"``, ``"obstacle"``      the same as ``"wall"`` (ILC: a shop or room)
``"door"``                      Polygon: an opening area; LineString: an opening lying on a wall
                                (grown by ``geojson_plan.DOOR_SNAP_M`` across it, flat ends)
==============================  ==============================================================

IMDF-style features (the Indoor Mapping Data Format's ``feature_type`` and ``category``,
in metres of the floor frame rather than IMDF's longitude/latitude) need no ``kind``:
``unit`` features map by their category (``IMDF_UNIT_KINDS``; any other category is a
``"room"``), ``opening`` features are doors, ``fixture`` and ``kiosk`` features are
obstacles, and the other IMDF feature types (level, footprint, section, ...) are
informational and ignored. An explicit ``properties.kind`` wins over the mapping.

Point features (anchors: ``"beacon"``, see ``anchors``; entrances, reference points ...)
may carry any kind or none. ``geojson_plan`` builds the walkable area and the walls from
the kinds; ``geojson_validation`` checks a whole plan sent to the service, and each of its
features with ``checked_kind``, which refuses:

* an area or line feature (Polygon, MultiPolygon, LineString, MultiLineString) without a
  kind from the table above (nor an IMDF type that maps to one);
* a geometry that does not fit its kind, a position that is not two or three finite
  numbers, a ring with fewer than four positions or not closed (RFC 7946 section
  3.1.6), a geometry shapely finds invalid (``is_valid_reason``: a self-crossing ring, a
  hole outside its shell, overlapping parts of a MultiPolygon).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import shapely

_OPEN_KINDS = frozenset({"walkable", "outline"})
ROOM_KINDS = frozenset({"room"})
_LINK_KINDS = frozenset({"elevator", "stairs", "escalator"})  # navigation_graph.LINK_KINDS
AREA_KINDS = _OPEN_KINDS | ROOM_KINDS | _LINK_KINDS
BARRIER_KINDS = frozenset({"wall", "unit", "obstacle"})
DOOR_KINDS = frozenset({"door"})
PLAN_KINDS = AREA_KINDS | BARRIER_KINDS | DOOR_KINDS
"""The kinds an area or line feature may have (module docstring)."""

AREA_TYPES = frozenset({"Polygon", "MultiPolygon"})
LINE_TYPES = frozenset({"LineString", "MultiLineString"})
_TYPES_OF = {
    **dict.fromkeys(AREA_KINDS, AREA_TYPES),
    **dict.fromkeys(BARRIER_KINDS | DOOR_KINDS, AREA_TYPES | LINE_TYPES),
}

IMDF_UNIT_KINDS: Mapping[str, str] = {
    **dict.fromkeys(
        (
            "walkway", "corridor", "footbridge", "lobby", "platform", "ramp", "steps",
            "movingwalkway", "unenclosedarea", "opentowalkway", "sidewalk", "parking",
            "terrace", "fieldofplay",
        ),
        "walkable",
    ),
    **dict.fromkeys(
        (
            "structure", "column", "opentobelow", "vegetation", "brick", "concrete",
            "drywall", "glass", "wood",
        ),
        "obstacle",
    ),
    "elevator": "elevator",
    "escalator": "escalator",
    "stairs": "stairs",
}  # fmt: skip
"""Our kind of an IMDF ``unit`` by its ``category``; any other category is a ``"room"``
(a space with walls: office, shop, restroom, storage, nonpublic, unspecified ...)."""

IMDF_FEATURE_KINDS: Mapping[str, str] = {
    "opening": "door",
    "fixture": "obstacle",
    "kiosk": "obstacle",
}
"""Our kind of the other IMDF feature types that shape the walkable area."""

IMDF_INFORMATIONAL = frozenset(
    {
        "venue", "building", "footprint", "level", "section", "geofence", "detail",
        "amenity", "anchor", "occupant", "address", "relationship",
    }
)  # fmt: skip
"""IMDF feature types that say nothing about where people walk: ignored."""


class PlanError(ValueError):
    """A plan that cannot be used as it is: ``field`` is the dotted path of what is wrong
    (``features.3.properties.kind``), ``reason`` says why."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


def _properties(feature: Mapping[str, Any]) -> Mapping[str, Any]:
    properties = feature.get("properties")
    return properties if isinstance(properties, Mapping) else {}


def _imdf_type(feature: Mapping[str, Any]) -> str | None:
    """IMDF puts ``feature_type`` beside ``properties``; tools that drop foreign members
    may have moved it inside."""
    return text(feature.get("feature_type", _properties(feature).get("feature_type")))


def text(value: Any) -> str | None:
    """A name read from the plan (a type, a category): None unless a string."""
    return value if isinstance(value, str) else None


def feature_kind(feature: Mapping[str, Any]) -> str | None:
    """A feature's kind: its ``properties.kind`` when that is a string, else the kind its
    IMDF type and category map to (module docstring); None when it has neither."""
    properties = _properties(feature)
    kind = properties.get("kind")
    if kind is not None:
        return kind if isinstance(kind, str) else None
    feature_type = _imdf_type(feature)
    if feature_type == "unit":
        category = properties.get("category")
        return IMDF_UNIT_KINDS.get(category, "room") if isinstance(category, str) else "room"
    return IMDF_FEATURE_KINDS.get(feature_type) if isinstance(feature_type, str) else None


def type_names(kind: str) -> str:
    if _TYPES_OF[kind] >= LINE_TYPES:
        return "a Polygon, MultiPolygon, LineString or MultiLineString"
    return "a Polygon or MultiPolygon"


def checked_kind(index: int, feature: Mapping[str, Any]) -> str | None:
    """The kind of a feature that passes the checks of ``geojson_validation.validate_plan``;
    None for a feature the plan ignores (a Point, an informational IMDF feature, no
    geometry)."""
    at = f"features.{index}"
    properties = feature.get("properties")
    if properties is not None and not isinstance(properties, Mapping):
        raise PlanError(f"{at}.properties", "must be an object or null")
    raw_kind = _properties(feature).get("kind")
    if raw_kind is not None and not isinstance(raw_kind, str):
        raise PlanError(f"{at}.properties.kind", f"must be a string, not {raw_kind!r}")
    geometry = feature.get("geometry")
    kind = feature_kind(feature)
    if geometry is None and kind not in PLAN_KINDS:
        return None
    if not isinstance(geometry, Mapping):
        raise PlanError(f"{at}.geometry", "must be a GeoJSON geometry object or null")
    geometry_type = text(geometry.get("type"))
    if kind not in PLAN_KINDS:
        if geometry_type not in AREA_TYPES | LINE_TYPES or _imdf_type(feature) in (
            IMDF_INFORMATIONAL
        ):
            return None  # points may be anything; informational IMDF features are ignored
        if raw_kind is None:
            raise PlanError(
                f"{at}.properties.kind",
                f"missing: a {geometry_type} needs a kind, one of {_kind_list()}",
            )
        raise PlanError(
            f"{at}.properties.kind", f"unknown kind {raw_kind!r}: one of {_kind_list()}"
        )
    if geometry_type not in _TYPES_OF[kind]:
        raise PlanError(
            f"{at}.geometry.type", f"a {kind} is {type_names(kind)}, not {geometry_type!r}"
        )
    check_coordinates(f"{at}.geometry.coordinates", geometry_type, geometry.get("coordinates"))
    shape = shapely.geometry.shape(dict(geometry))
    if not shapely.is_valid(shape):
        raise PlanError(
            f"{at}.geometry",
            f"not a valid {geometry_type} ({shapely.is_valid_reason(shape)}): rings must not "
            "cross or touch themselves, holes lie inside their shell, parts must not overlap",
        )
    return kind


def _kind_list() -> str:
    return ", ".join(sorted(PLAN_KINDS))


# how deep the positions lie in each geometry's coordinates
_POSITION_DEPTH = {"LineString": 1, "MultiLineString": 2, "Polygon": 2, "MultiPolygon": 3}


def check_coordinates(at: str, geometry_type: str, coordinates: Any) -> None:
    """RFC 7946 coordinates of a line or area geometry: lists nested to the type's depth,
    positions of two or three finite numbers, lines of two positions or more, rings of
    four or more with the last equal to the first."""
    depth = _POSITION_DEPTH[geometry_type]

    def check(value: Any, path: str, level: int) -> None:
        if level == depth:  # a line or a ring: a list of positions
            if not isinstance(value, list):
                raise PlanError(path, "must be a list of positions")
            for k, position in enumerate(value):
                _check_position(f"{path}.{k}", position)
            ring = geometry_type in AREA_TYPES
            if ring and (len(value) < 4 or value[0] != value[-1]):
                raise PlanError(
                    path,
                    f"a ring has four positions or more, the last equal to the first "
                    f"(RFC 7946 3.1.6); this one has {len(value)} positions"
                    + ("" if len(value) < 4 else ", and is not closed"),
                )
            if not ring and len(value) < 2:
                raise PlanError(path, f"a line has two positions or more, not {len(value)}")
            return
        if not isinstance(value, list) or not value:
            raise PlanError(path, "must be a non-empty list")
        for k, item in enumerate(value):
            check(item, f"{path}.{k}", level + 1)

    check(coordinates, at, 1)


def _check_position(at: str, position: Any) -> None:
    numbers = isinstance(position, list) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in position
    )
    if not (numbers and len(position) in (2, 3) and all(_finite(v) for v in position)):
        raise PlanError(at, f"a position is [x, y] or [x, y, z] in finite metres, not {position!r}")


def _finite(value: float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond float range
        return False
