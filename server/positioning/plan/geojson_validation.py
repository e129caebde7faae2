"""The checks a floor plan sent to the service must pass (``validate_plan``).

``geojson_plan.plan_from_geojson`` reads leniently what it can build from (features of
other kinds are skipped, self-crossing rings repaired), as recorded datasets need.
``validate_plan`` is what a plan sent to the service must pass; it raises
``geojson_format.PlanError`` naming the feature and the property at fault:

* an area or line feature (Polygon, MultiPolygon, LineString, MultiLineString) without a
  kind from the table of ``geojson_format`` (nor an IMDF type that maps to one);
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

The first two are each feature's (``geojson_format.checked_kind``), the others the whole
plan's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray

from server.positioning.plan.geojson_format import (
    AREA_TYPES,
    LINE_TYPES,
    PlanError,
    feature_kind,
    text,
)
from server.positioning.plan.geojson_plan import read, walkable_area

FloatArray = NDArray[np.float64]

MIN_PLAN_SPAN_M = 2.0
"""Area and line features spanning less than this in both directions, with every
coordinate within longitude/latitude ranges, are taken for degrees (m)."""

MAX_PLAN_SPAN_M = 2000.0
"""Widest span of a plan's area and line features (m): a floor plan, not a city; its
0.25 m raster is then at most 64 million cells."""

GEO_ORIGIN_DEG = 0.05
"""Coordinates all within this many degrees of the building's geographic origin are
taken for longitude/latitude (about 5 km; read as metres, 5 cm around one point)."""


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
    parts = read(geojson, strict=True)
    check_frame(features, origin_deg)
    if parts.areas:
        walkable_area(parts)
    elif parts.solids or parts.thin or parts.doors:
        raise PlanError(
            "features",
            "walls and doors but no walkable area: add a Polygon of kind 'walkable', "
            "'outline' or 'room'",
        )
    out = []
    for feature in features:
        props = feature.get("properties") or {}
        kind = feature_kind(feature)
        if kind is not None and props.get("kind") != kind:
            feature = {**feature, "properties": {**props, "kind": kind}}
        out.append(feature)
    return {**geojson, "features": out}


def check_frame(features: Sequence[Any], origin_deg: tuple[float, float] | None) -> None:
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
        line_or_area = text(geometry.get("type")) in AREA_TYPES | LINE_TYPES
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
