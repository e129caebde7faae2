"""Floor plans from GeoJSON: the walkable area and the walls that a plan's features build
(the format and its kinds are in ``geojson_format``, the checks of a plan sent to the
service in ``geojson_validation``).

With ``D`` the union of the door areas, the walkable area is::

    W = union(walkable, room, elevator, stairs, escalator) - (union(solid blocks) - D)

and the wall segments are the edges of the boundary of ``W`` together with the thin walls
and the rings of the rooms, minus ``D``. Adjacent open polygons merge into one area: rooms
are kept apart by walls drawn between them (or by being ``"room"``), with doors cutting gaps
in those walls.

ILC plans (``lab.datasets.ilc.plan_to_metres``) carry one ``"outline"`` feature (the
floor) and ``"unit"`` features (shops, rooms): the walkable area is the outline minus the
units, i.e. the corridors and halls of the mall. People are followed in the corridors
only: on site2 of the ILC 2.0 sample, all 3,054 waypoints of all 417 traces lie inside
that area and in walkable raster cells (0.25 m), though 15 of them are less than 0.25 m
from a wall (the closest 0.012 m).

``plan_from_geojson`` reads leniently what it can build from (features of other kinds
are skipped, self-crossing rings repaired), as recorded datasets need, and builds the
``floor_plan.FloorPlan`` (the raster of ``W`` and the wall segments); ``plan_extent``
gives the box of a plan's walkable features without building it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry.base import BaseGeometry

from server.positioning.plan.floor_plan import FloorPlan
from server.positioning.plan.geojson_format import (
    AREA_KINDS,
    BARRIER_KINDS,
    DOOR_KINDS,
    PLAN_KINDS,
    ROOM_KINDS,
    PlanError,
    checked_kind,
    feature_kind,
    type_names,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

CELL_M = 0.25
"""Default raster cell side (m)."""

DOOR_SNAP_M = 0.05
"""Half-thickness given to a door LineString so that it cuts the wall it lies on (m)."""


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
        FeatureCollection whose features carry ``properties.kind`` (``geojson_format``).
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
    parts = read(geojson, strict=False)
    if not parts.areas:
        raise PlanError(
            "features", "no walkable polygon (a Polygon of kind 'walkable', 'outline' or 'room')"
        )
    area, door_area = walkable_area(parts)
    walls = np.concatenate(
        [
            _segments(area.boundary),
            _segments(shapely.difference(shapely.union_all(parts.thin), door_area)),
        ]
    )
    return FloorPlan(*_raster(area, cell_m), walls=walls)


def read(geojson: Mapping[str, Any], *, strict: bool) -> _Parts:
    """The plan's shapes by role; with ``strict``, the feature checks of
    ``geojson_validation.validate_plan`` (otherwise features it cannot use are skipped, and
    invalid rings repaired)."""
    parts = _Parts()
    for index, feature in enumerate(geojson.get("features") or ()):
        if not isinstance(feature, Mapping):
            raise PlanError(f"features.{index}", "not a GeoJSON feature (an object)")
        kind = feature_kind(feature) if not strict else checked_kind(index, feature)
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
        if kind in AREA_KINDS and dim == 2:
            parts.areas += _polygons(geometry)
            if kind in ROOM_KINDS:
                parts.thin += [p.boundary for p in _polygons(geometry)]
        elif kind in BARRIER_KINDS and dim == 2:
            parts.solids += _polygons(geometry)
        elif kind in BARRIER_KINDS and dim == 1:
            parts.thin.append(geometry)
        elif kind in DOOR_KINDS and dim == 2:
            parts.doors += _polygons(geometry)
        elif kind in DOOR_KINDS and dim == 1:
            parts.doors.append(shapely.buffer(geometry, DOOR_SNAP_M, cap_style="flat"))
        else:
            raise PlanError(
                f"features.{index}.geometry.type",
                f"a {kind} is {type_names(kind)}, not a {geometry.geom_type}",
            )
    return parts


def walkable_area(parts: _Parts) -> tuple[BaseGeometry, BaseGeometry]:
    """``(W, D)`` of the module docstring; PlanError when ``W`` is empty."""
    door_area = shapely.union_all(parts.doors)
    area = shapely.difference(
        shapely.union_all(parts.areas),
        shapely.difference(shapely.union_all(parts.solids), door_area),
    )
    if area.is_empty or area.area <= 0:
        raise PlanError("features", "the walls and obstacles cover all the walkable area")
    return area, door_area


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
        if feature_kind(feature) not in AREA_KINDS:
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
