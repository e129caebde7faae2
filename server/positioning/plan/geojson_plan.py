"""Floor plans from GeoJSON: the plan format, its checks, and its walkable area and walls.

Plan format. A floor plan is a GeoJSON FeatureCollection in metres of the floor frame
(x east, y north). Each feature's ``properties.kind`` says what it is:

==============================  ==============================================================
``"walkable"``                  Polygon / MultiPolygon of open floor area people may stand on
``"outline"``                   the same (ILC: the floor outline, see below)
``"room"``                      Polygon / MultiPolygon: floor area enclosed by walls along its
                                rings (doors cut gaps in them)
``"elevator"``, ``"stairs"``,   Polygon / MultiPolygon: open floor area where a walk may leave
``"escalator"``                 the floor (``navigation_graph``)
``"wall"``                      LineString / MultiLineString: a thin wall; Polygon /
                                MultiPolygon: a solid block (thick wall, pillar, closed room)
``"unit"``, ``"obstacle"``      the same as ``"wall"`` (ILC: a shop or room)
``"door"``                      Polygon: an opening area; LineString: an opening lying on a wall
                                (grown by ``DOOR_SNAP_M`` across it, flat ends)
==============================  ==============================================================

IMDF-style features (the Indoor Mapping Data Format's ``feature_type`` and ``category``,
in metres of the floor frame rather than IMDF's longitude/latitude) need no ``kind``:
``unit`` features map by their category (``IMDF_UNIT_KINDS``; any other category is a
``"room"``), ``opening`` features are doors, ``fixture`` and ``kiosk`` features are
obstacles, and the other IMDF feature types (level, footprint, section, ...) are
informational and ignored. An explicit ``properties.kind`` wins over the mapping.

Point features (anchors: ``"beacon"``, see ``anchors``; entrances, reference points ...)
may carry any kind or none. With ``D`` the union of the door areas, the walkable area is::

    W = union(walkable, room, elevator, stairs, escalator) - (union(solid blocks) - D)

and the wall segments are the edges of the boundary of ``W`` together with the thin walls
and the rings of the rooms, minus ``D``. Adjacent open polygons merge into one area: rooms
are kept apart by walls drawn between them (or by being ``"room"``), with doors cutting gaps
in those walls.

ILC plans (``server.datasets.ilc.plan_to_metres``) carry one ``"outline"`` feature (the
floor) and ``"unit"`` features (shops, rooms): the walkable area is the outline minus the
units, i.e. the corridors and halls of the mall. People are followed in the corridors
only: on site2 of the ILC 2.0 sample, all 3,054 waypoints of all 417 traces lie inside
that area and in walkable raster cells (0.25 m), though 15 of them are less than 0.25 m
from a wall (the closest 0.012 m).

Checks. ``plan_from_geojson`` reads leniently what it can build from (features of other
kinds are skipped, self-crossing rings repaired), as recorded datasets need.
``validate_plan`` is what a plan sent to the service must pass; it raises ``PlanError``
naming the feature and the property at fault:

* an area or line feature (Polygon, MultiPolygon, LineString, MultiLineString) without a
  kind from the table above (nor an IMDF type that maps to one);
* a geometry that does not fit its kind, a position that is not two or three finite
  numbers, a ring with fewer than four positions or not closed (RFC 7946 section
  3.1.6), a geometry shapely finds invalid (``is_valid_reason``: a self-crossing ring, a
  hole outside its shell, overlapping parts of a MultiPolygon);
* coordinates that look like longitude/latitude degrees: all within 0.05 degrees of the
  building's geographic origin (when it has one), or, for the area and line features,
  all within the ranges of longitude and latitude while spanning less than
  ``MIN_PLAN_SPAN_M`` (a floor narrower than that in both directions holds no walk; a
  building of a few hundred metres spans a few thousandths of a degree);
* area and line features spanning more than ``MAX_PLAN_SPAN_M`` (the raster of such a
  plan would not fit in memory), walls or doors with no walkable area, or a walkable
  area that the solid blocks cover entirely.

``plan_from_geojson`` builds the ``floor_plan.FloorPlan`` (the raster of ``W`` and the
wall segments); ``plan_extent`` gives the box of a plan's walkable features without
building it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry.base import BaseGeometry

from server.positioning.plan.floor_plan import FloorPlan

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

CELL_M = 0.25
"""Default raster cell side (m)."""

DOOR_SNAP_M = 0.05
"""Half-thickness given to a door LineString so that it cuts the wall it lies on (m)."""

MIN_PLAN_SPAN_M = 2.0
"""Area and line features spanning less than this in both directions, with every
coordinate within longitude/latitude ranges, are taken for degrees (m)."""

MAX_PLAN_SPAN_M = 2000.0
"""Widest span of a plan's area and line features (m): a floor plan, not a city; its
0.25 m raster is then at most 64 million cells."""

GEO_ORIGIN_DEG = 0.05
"""Coordinates all within this many degrees of the building's geographic origin are
taken for longitude/latitude (about 5 km; read as metres, 5 cm around one point)."""

_OPEN_KINDS = frozenset({"walkable", "outline"})
_ROOM_KINDS = frozenset({"room"})
_LINK_KINDS = frozenset({"elevator", "stairs", "escalator"})  # floor_graph.LINK_KINDS
_AREA_KINDS = _OPEN_KINDS | _ROOM_KINDS | _LINK_KINDS
_BARRIER_KINDS = frozenset({"wall", "unit", "obstacle"})
_DOOR_KINDS = frozenset({"door"})
PLAN_KINDS = _AREA_KINDS | _BARRIER_KINDS | _DOOR_KINDS
"""The kinds an area or line feature may have (module docstring)."""

_AREA_TYPES = frozenset({"Polygon", "MultiPolygon"})
_LINE_TYPES = frozenset({"LineString", "MultiLineString"})
_TYPES_OF = {
    **dict.fromkeys(_AREA_KINDS, _AREA_TYPES),
    **dict.fromkeys(_BARRIER_KINDS | _DOOR_KINDS, _AREA_TYPES | _LINE_TYPES),
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


@dataclass
class _Parts:
    """The shapes of a plan by their role in ``W`` (module docstring)."""

    areas: list[BaseGeometry] = field(default_factory=list)
    solids: list[BaseGeometry] = field(default_factory=list)
    thin: list[BaseGeometry] = field(default_factory=list)
    doors: list[BaseGeometry] = field(default_factory=list)


def plan_from_geojson(geojson: Mapping[str, Any], cell_m: float = CELL_M) -> FloorPlan:
    """Build a floor plan from a GeoJSON FeatureCollection in metres.

    Parameters
    ----------
    geojson : mapping
        FeatureCollection whose features carry ``properties.kind`` (module docstring).
    cell_m : float
        Raster cell side (m).

    Returns
    -------
    FloorPlan

    Raises
    ------
    PlanError
        No walkable polygon, a feature whose geometry does not fit its kind (the field
        names the feature's index), or an empty walkable area.
    ValueError
        A bad ``cell_m``.
    """
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be positive, not {cell_m}")
    parts = _read(geojson, strict=False)
    if not parts.areas:
        raise PlanError(
            "features", "no walkable polygon (a Polygon of kind 'walkable', 'outline' or 'room')"
        )
    area, door_area = _walkable_area(parts)
    walls = np.concatenate(
        [
            _segments(area.boundary),
            _segments(shapely.difference(shapely.union_all(parts.thin), door_area)),
        ]
    )
    return FloorPlan(*_raster(area, cell_m), walls=walls)


def validate_plan(
    geojson: Mapping[str, Any], origin_deg: tuple[float, float] | None = None
) -> dict[str, Any]:
    """The plan as the service stores it, once it passes the checks of the module
    docstring: a copy whose IMDF-style features have the ``properties.kind`` they map to.

    Parameters
    ----------
    geojson : mapping
        The FeatureCollection sent.
    origin_deg : (float, float), optional
        ``(lat, lon)`` of the building's origin, when it has a geo-reference.

    Raises
    ------
    PlanError
        The first problem found, naming the feature (``features.<index>``) and the property.
    """
    features = geojson.get("features")
    if not isinstance(features, Sequence) or isinstance(features, str):
        raise PlanError("features", "a FeatureCollection needs a list of features")
    parts = _read(geojson, strict=True)
    _check_frame(features, origin_deg)
    if parts.areas:
        _walkable_area(parts)
    elif parts.solids or parts.thin or parts.doors:
        raise PlanError(
            "features",
            "walls and doors but no walkable area: add a Polygon of kind 'walkable', "
            "'outline' or 'room'",
        )
    out = []
    for feature in features:
        props = feature.get("properties") or {}
        kind = _kind(feature)
        if kind is not None and props.get("kind") != kind:
            feature = {**feature, "properties": {**props, "kind": kind}}
        out.append(feature)
    return {**geojson, "features": out}


def _properties(feature: Mapping[str, Any]) -> Mapping[str, Any]:
    properties = feature.get("properties")
    return properties if isinstance(properties, Mapping) else {}


def _imdf_type(feature: Mapping[str, Any]) -> str | None:
    """IMDF puts ``feature_type`` beside ``properties``; tools that drop foreign members
    may have moved it inside."""
    return _text(feature.get("feature_type", _properties(feature).get("feature_type")))


def _text(value: Any) -> str | None:
    """A name read from the plan (a type, a category): None unless a string."""
    return value if isinstance(value, str) else None


def _kind(feature: Mapping[str, Any]) -> str | None:
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


def _read(geojson: Mapping[str, Any], *, strict: bool) -> _Parts:
    """The plan's shapes by role; with ``strict``, the feature checks of ``validate_plan``
    (otherwise features it cannot use are skipped, and invalid rings repaired)."""
    parts = _Parts()
    for index, feature in enumerate(geojson.get("features") or ()):
        if not isinstance(feature, Mapping):
            raise PlanError(f"features.{index}", "not a GeoJSON feature (an object)")
        kind = _kind(feature) if not strict else _checked_kind(index, feature)
        if kind not in PLAN_KINDS:
            continue
        try:
            geometry = shapely.geometry.shape(feature["geometry"])
        except (KeyError, TypeError, ValueError, AttributeError, shapely.errors.ShapelyError):
            raise PlanError(
                f"features.{index}.geometry", f"a {kind} needs a GeoJSON geometry"
            ) from None
        if geometry.is_empty:
            continue
        dim = shapely.get_dimensions(geometry)
        if kind in _AREA_KINDS and dim == 2:
            parts.areas += _polygons(geometry)
            if kind in _ROOM_KINDS:
                parts.thin += [p.boundary for p in _polygons(geometry)]
        elif kind in _BARRIER_KINDS and dim == 2:
            parts.solids += _polygons(geometry)
        elif kind in _BARRIER_KINDS and dim == 1:
            parts.thin.append(geometry)
        elif kind in _DOOR_KINDS and dim == 2:
            parts.doors += _polygons(geometry)
        elif kind in _DOOR_KINDS and dim == 1:
            parts.doors.append(shapely.buffer(geometry, DOOR_SNAP_M, cap_style="flat"))
        else:
            raise PlanError(
                f"features.{index}.geometry.type",
                f"a {kind} is {_type_names(kind)}, not a {geometry.geom_type}",
            )
    return parts


def _walkable_area(parts: _Parts) -> tuple[BaseGeometry, BaseGeometry]:
    """``(W, D)`` of the module docstring; PlanError when ``W`` is empty."""
    door_area = shapely.union_all(parts.doors)
    area = shapely.difference(
        shapely.union_all(parts.areas),
        shapely.difference(shapely.union_all(parts.solids), door_area),
    )
    if area.is_empty or area.area <= 0:
        raise PlanError("features", "the walls and obstacles cover all the walkable area")
    return area, door_area


def _type_names(kind: str) -> str:
    if _TYPES_OF[kind] >= _LINE_TYPES:
        return "a Polygon, MultiPolygon, LineString or MultiLineString"
    return "a Polygon or MultiPolygon"


def _checked_kind(index: int, feature: Mapping[str, Any]) -> str | None:
    """The kind of a feature that passes the checks of ``validate_plan``; None for a
    feature the plan ignores (a Point, an informational IMDF feature, no geometry)."""
    at = f"features.{index}"
    properties = feature.get("properties")
    if properties is not None and not isinstance(properties, Mapping):
        raise PlanError(f"{at}.properties", "must be an object or null")
    raw_kind = _properties(feature).get("kind")
    if raw_kind is not None and not isinstance(raw_kind, str):
        raise PlanError(f"{at}.properties.kind", f"must be a string, not {raw_kind!r}")
    geometry = feature.get("geometry")
    kind = _kind(feature)
    if geometry is None and kind not in PLAN_KINDS:
        return None
    if not isinstance(geometry, Mapping):
        raise PlanError(f"{at}.geometry", "must be a GeoJSON geometry object or null")
    geometry_type = _text(geometry.get("type"))
    if kind not in PLAN_KINDS:
        if geometry_type not in _AREA_TYPES | _LINE_TYPES or _imdf_type(feature) in (
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
            f"{at}.geometry.type", f"a {kind} is {_type_names(kind)}, not {geometry_type!r}"
        )
    _check_coordinates(f"{at}.geometry.coordinates", geometry_type, geometry.get("coordinates"))
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


def _check_coordinates(at: str, geometry_type: str, coordinates: Any) -> None:
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
            ring = geometry_type in _AREA_TYPES
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


def _check_frame(features: Sequence[Any], origin_deg: tuple[float, float] | None) -> None:
    """PlanError when the coordinates look like longitude/latitude degrees, or the area
    and line features span more than ``MAX_PLAN_SPAN_M`` (module docstring)."""
    shaped: list[FloatArray] = []  # the area and line features' positions
    points: list[FloatArray] = []
    first: int | None = None
    for index, feature in enumerate(features):
        geometry = feature.get("geometry") if isinstance(feature, Mapping) else None
        if not isinstance(geometry, Mapping):
            continue
        try:
            xy = shapely.get_coordinates(shapely.geometry.shape(dict(geometry)))
        except (
            KeyError,
            IndexError,
            OverflowError,
            TypeError,
            ValueError,
            AttributeError,
            shapely.errors.ShapelyError,
        ):
            continue  # a malformed geometry the reading skipped (an anchor point, say)
        if xy.size == 0:
            continue
        first = index if first is None else first
        line_or_area = _text(geometry.get("type")) in _AREA_TYPES | _LINE_TYPES
        (shaped if line_or_area else points).append(xy)
    if first is None:
        return
    at = f"features.{first}.geometry.coordinates"
    everything = np.concatenate(shaped + points)
    if origin_deg is not None:
        lat, lon = origin_deg
        for x_deg, y_deg in ((lon, lat), (lat, lon)):
            near = np.abs(everything - [x_deg, y_deg]) <= GEO_ORIGIN_DEG
            if near.all():
                raise PlanError(
                    at,
                    f"every coordinate lies within {GEO_ORIGIN_DEG:g} degrees of the "
                    f"building's origin (lat {lat:g}, lon {lon:g}): these are longitude/"
                    "latitude, but a plan is in metres of the building frame (x east, y "
                    "north of the origin)",
                )
    if not shaped:
        return
    xy = np.concatenate(shaped)
    span = xy.max(axis=0) - xy.min(axis=0)
    in_degrees = np.all(np.abs(xy[:, 0]) <= 180.0) and np.all(np.abs(xy[:, 1]) <= 90.0)
    if in_degrees and span.max() < MIN_PLAN_SPAN_M:
        raise PlanError(
            at,
            f"the plan spans {span[0]:.3g} m x {span[1]:.3g} m, all within longitude/"
            "latitude ranges: these look like degrees, but a plan is in metres of the "
            "building frame (x east, y north)",
        )
    if span.max() > MAX_PLAN_SPAN_M:
        raise PlanError(
            at,
            f"the plan spans {span[0]:.0f} m x {span[1]:.0f} m: more than "
            f"{MAX_PLAN_SPAN_M:g} m is not one floor (is it in metres?)",
        )


PLAN_MARGIN_M = 10.0
"""How far outside its plan's walkable extent a sample may lie and still be used (a
wrong anchor or a typo must not stretch a floor's maps across a city)."""


Extent = tuple[float, float, float, float]  # x0, y0, x1, y1 (m)


def plan_extent(geojson: Mapping[str, Any] | None) -> Extent | None:
    """``(x0, y0, x1, y1)``: the bounding box of a plan's walkable features (what
    ``plan_from_geojson`` builds the walkable area from), without rasterising; None when
    the plan has none or they are not readable geometries."""
    boxes = []
    for feature in (geojson or {}).get("features") or ():
        if not isinstance(feature, Mapping):
            continue
        if _kind(feature) not in _AREA_KINDS:
            continue
        try:
            geometry = shapely.geometry.shape(feature["geometry"])
        except (KeyError, TypeError, ValueError, AttributeError, shapely.errors.ShapelyError):
            continue
        if not geometry.is_empty:
            boxes.append(geometry.bounds)
    if not boxes:
        return None
    b = np.array(boxes, dtype=np.float64)
    return float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())


def near_extent(extent: ArrayLike, xy: ArrayLike, margin_m: float = PLAN_MARGIN_M) -> BoolArray:
    """Whether each coordinate of points lies within ``margin_m`` of an extent.

    Parameters
    ----------
    extent : array_like, shape (4,) or (n, 4)
        ``(x0, y0, x1, y1)`` as :func:`plan_extent` gives it, or one per point.
    xy : array_like, shape (n, 2)
        The points.

    Returns
    -------
    ndarray, shape (n, 2), bool
        Per point, whether its x and its y lie within the margin (a point is near the
        extent where both do).
    """
    box = np.asarray(extent, dtype=np.float64)
    points = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    near: BoolArray = (points >= box[..., :2] - margin_m) & (points <= box[..., 2:] + margin_m)
    return near


def _polygons(geometry: BaseGeometry) -> list[BaseGeometry]:
    """The polygonal parts of a repaired (multi)polygon: a self-touching ring repaired
    by ``make_valid`` may leave lines or points beside the polygons."""
    parts = shapely.get_parts(shapely.make_valid(geometry))
    return [p for p in parts.tolist() if shapely.get_dimensions(p) == 2]


def _segments(geometry: BaseGeometry) -> FloatArray:
    """Edges ``[x1, y1, x2, y2]`` of the lines of a (multi)line geometry, shape (m, 4)."""
    parts = shapely.get_parts(geometry)
    xy, part = shapely.get_coordinates(parts, return_index=True)
    same = part[1:] == part[:-1]
    segments = np.column_stack([xy[:-1][same], xy[1:][same]])
    return segments[np.any(segments[:, :2] != segments[:, 2:], axis=1)].reshape(-1, 4)


def _raster(
    area: BaseGeometry, cell_m: float
) -> tuple[tuple[float, float], float, NDArray[np.bool_]]:
    """``(origin_m, cell_m, walkable)`` of the cells whose centres lie inside ``area``."""
    x_min, y_min, x_max, y_max = area.bounds
    x0, y0 = math.floor(x_min / cell_m) * cell_m, math.floor(y_min / cell_m) * cell_m
    nx, ny = math.ceil((x_max - x0) / cell_m), math.ceil((y_max - y0) / cell_m)
    xs = x0 + (np.arange(nx) + 0.5) * cell_m
    ys = y0 + (np.arange(ny) + 0.5) * cell_m
    shapely.prepare(area)
    walkable = shapely.contains_xy(area, *np.meshgrid(xs, ys))
    return (x0, y0), cell_m, np.asarray(walkable, dtype=bool)
