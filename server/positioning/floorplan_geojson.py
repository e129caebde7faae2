"""Floor plans from GeoJSON: the plan format, and its walkable area and walls.

Plan format. A floor plan is a GeoJSON FeatureCollection in metres of the floor frame
(x east, y north). Each feature's ``properties.kind`` says what it is:

==========================  ==================================================================
``"walkable"``              Polygon / MultiPolygon of floor area people may stand on
``"outline"``               the same (ILC: the floor outline, see below)
``"wall"``                  LineString / MultiLineString: a thin wall; Polygon /
                            MultiPolygon: a solid block (thick wall, pillar, closed room)
``"unit"``, ``"obstacle"``  the same as ``"wall"`` (ILC: a shop or room)
``"door"``                  Polygon: an opening area; LineString: an opening lying on a wall
                            (grown by ``DOOR_SNAP_M`` across it, flat ends)
==========================  ==================================================================

Features of any other kind (anchors, entrances, beacons ...) or without a kind are
ignored. With ``D`` the union of the door areas, the walkable area is::

    W = union(walkable) - (union(solid blocks) - D)

and the wall segments are the edges of the boundary of ``W`` together with the thin walls
minus ``D``. Adjacent walkable polygons merge into one area: rooms are kept apart by walls
drawn between them, with doors cutting gaps in those walls.

ILC plans (``server.datasets.ilc.plan_to_metres``) carry one ``"outline"`` feature (the
floor) and ``"unit"`` features (shops, rooms): the walkable area is the outline minus the
units, i.e. the corridors and halls of the mall. People are followed in the corridors
only: on site2 of the ILC 2.0 sample, all 3,054 waypoints of all 417 traces lie inside
that area and in walkable raster cells (0.25 m), though 15 of them are less than 0.25 m
from a wall (the closest 0.012 m).


``plan_from_geojson`` builds the ``floorplan.FloorPlan`` (the raster of ``W`` and the
wall segments); ``plan_extent`` gives the box of a plan's walkable features without
building it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from server.positioning.floorplan import FloorPlan

FloatArray = NDArray[np.float64]

CELL_M = 0.25
"""Default raster cell side (m)."""

DOOR_SNAP_M = 0.05
"""Half-thickness given to a door LineString so that it cuts the wall it lies on (m)."""

_WALKABLE_KINDS = frozenset({"walkable", "outline"})
_BARRIER_KINDS = frozenset({"wall", "unit", "obstacle"})
_DOOR_KINDS = frozenset({"door"})


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
    ValueError
        No walkable polygon, a feature whose geometry does not fit its kind (the message
        gives the feature's index), an empty walkable area or a bad ``cell_m``.
    """
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be positive, not {cell_m}")
    walkable: list[BaseGeometry] = []
    solids: list[BaseGeometry] = []
    thin: list[BaseGeometry] = []
    doors: list[BaseGeometry] = []
    for index, feature in enumerate(geojson.get("features") or ()):
        if not isinstance(feature, Mapping):
            raise ValueError(f"feature {index}: not a GeoJSON feature")
        kind = _kind(feature)
        if not isinstance(kind, str) or kind not in _WALKABLE_KINDS | _BARRIER_KINDS | _DOOR_KINDS:
            continue
        try:
            geometry = shapely.geometry.shape(feature["geometry"])
        except (KeyError, TypeError, ValueError, AttributeError, shapely.errors.ShapelyError):
            raise ValueError(f"feature {index} ({kind}): not a GeoJSON geometry") from None
        dim = shapely.get_dimensions(geometry)
        if geometry.is_empty:
            continue
        if kind in _WALKABLE_KINDS and dim == 2:
            walkable += _polygons(geometry)
        elif kind in _BARRIER_KINDS and dim == 2:
            solids += _polygons(geometry)
        elif kind in _BARRIER_KINDS and dim == 1:
            thin.append(geometry)
        elif kind in _DOOR_KINDS and dim == 2:
            doors += _polygons(geometry)
        elif kind in _DOOR_KINDS and dim == 1:
            doors.append(shapely.buffer(geometry, DOOR_SNAP_M, cap_style="flat"))
        else:
            raise ValueError(f"feature {index} ({kind}): unexpected {geometry.geom_type}")
    if not walkable:
        raise ValueError(
            "no walkable polygon (features with properties.kind 'walkable' or 'outline')"
        )
    door_area = shapely.union_all(doors)
    area = shapely.difference(
        shapely.union_all(walkable), shapely.difference(shapely.union_all(solids), door_area)
    )
    if area.is_empty or area.area <= 0:
        raise ValueError("the walkable area is empty")
    walls = np.concatenate(
        [
            _segments(area.boundary),
            _segments(shapely.difference(shapely.union_all(thin), door_area)),
        ]
    )
    return FloorPlan(*_raster(area, cell_m), walls=walls)


def _kind(feature: Mapping[str, Any]) -> Any:
    """A feature's ``properties.kind``; None when its properties are not an object."""
    properties = feature.get("properties")
    return properties.get("kind") if isinstance(properties, Mapping) else None


PLAN_MARGIN_M = 10.0
"""How far outside its plan's walkable extent a sample may lie and still be used (a
wrong anchor or a typo must not stretch a floor's maps across a city)."""


def plan_extent(geojson: Mapping[str, Any] | None) -> tuple[float, float, float, float] | None:
    """``(x0, y0, x1, y1)``: the bounding box of a plan's walkable features (what
    ``plan_from_geojson`` builds the walkable area from), without rasterising; None when
    the plan has none or they are not readable geometries."""
    boxes = []
    for feature in (geojson or {}).get("features") or ():
        if not isinstance(feature, Mapping):
            continue
        if _kind(feature) not in _WALKABLE_KINDS:
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
