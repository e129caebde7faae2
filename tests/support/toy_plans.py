"""Toy worlds shared by the tests of the floor plans and the particle filter.

* a 20 m x 10 m room with a wall with a door and a pillar, as a GeoJSON plan (``ROOM``,
  ``room``);
* a 40 m x 4 m corridor cut by a wall across it at x = 20 m with a 1 m door
  (1.5 m < y < 2.5 m), with its exact move test and a magnetic field known for x < 30 m
  (``door_valid_move``, ``door_map``), and small particle clouds to put in it (``cloud``,
  ``with_window``) with their checks.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters.particle_cloud import MapSampler, Particles, from_points
from server.positioning.filters.particle_resampling import alive
from server.positioning.model import state_codec
from server.positioning.plan.floor_plan import FloorPlan
from server.positioning.plan.geojson_plan import plan_from_geojson

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
FloorArray = NDArray[np.int16]


def feature(kind: str, geometry_type: str, coordinates: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": {"kind": kind},
        "geometry": {"type": geometry_type, "coordinates": coordinates},
    }


def box(x0: float, y0: float, x1: float, y1: float) -> list[list[list[float]]]:
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


def square(x0: float, y0: float, size: float) -> dict[str, Any]:
    """A GeoJSON Polygon: the square of side ``size`` m from (``x0``, ``y0``)."""
    return {"type": "Polygon", "coordinates": box(x0, y0, x0 + size, y0 + size)}


# 20 m x 10 m room, a thin wall at x = 10 with a 1 m door (y 4.5-5.5), a 2 m pillar
ROOM = {
    "type": "FeatureCollection",
    "features": [
        feature("walkable", "Polygon", box(0, 0, 20, 10)),
        feature("wall", "LineString", [[10, 0], [10, 10]]),
        feature("door", "LineString", [[10, 4.5], [10, 5.5]]),
        feature("wall", "Polygon", box(4, 2, 6, 4)),
        feature("anchor", "Point", [1, 1]),  # other kinds are ignored
    ],
}


@cache
def room() -> FloorPlan:
    return plan_from_geojson(ROOM)


def feature_collection(*features: dict[str, Any]) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": list(features)}


# the walkable floor of ``ROOM`` alone
FLOOR = feature("walkable", "Polygon", box(0, 0, 20, 10))


def as_moves(a: Any, b: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_2d(np.asarray(b, dtype=float))


# ---- the corridor with a wall and a door, and particle clouds in it -------------------------

DOOR_LENGTH_M, DOOR_WIDTH_M, WALL_X_M = 40.0, 4.0, 20.0
DOOR_Y_M = (1.5, 2.5)


def door_valid_move(floor: FloorArray, a: FloatArray, b: FloatArray) -> BoolArray:
    """Exact: ``b`` strictly inside the rectangle and ``a -> b`` meets no wall segment.

    The rectangle is convex, so a segment between two inside points stays inside; the
    wall is the closed segments x = 20, 0 <= y <= 1.5 and 2.5 <= y <= 4.
    """
    inside = (b[:, 0] > 0) & (b[:, 0] < DOOR_LENGTH_M) & (b[:, 1] > 0) & (b[:, 1] < DOOR_WIDTH_M)
    lo = np.minimum(a[:, 0], b[:, 0])
    hi = np.maximum(a[:, 0], b[:, 0])
    reaches = (lo <= WALL_X_M) & (hi >= WALL_X_M)
    dx = b[:, 0] - a[:, 0]
    along = dx == 0  # on the line x = 20: blocked unless the whole move is in the door
    with np.errstate(divide="ignore", invalid="ignore"):
        y_at = np.where(along, a[:, 1], a[:, 1] + (WALL_X_M - a[:, 0]) / dx * (b[:, 1] - a[:, 1]))
    y_lo = np.where(along, np.minimum(a[:, 1], b[:, 1]), y_at)
    y_hi = np.where(along, np.maximum(a[:, 1], b[:, 1]), y_at)
    through_door = (y_lo > DOOR_Y_M[0]) & (y_hi < DOOR_Y_M[1])
    return inside & ~(reaches & ~through_door)


def door_valid_point(floor: FloorArray, xy: FloatArray) -> BoolArray:
    return door_valid_move(floor, xy, xy)


def door_map(floor: FloorArray, xy: FloatArray) -> FloatArray:
    """A field known only for x < 30 m (NaN beyond), so unknown cells occur."""
    field = 45.0 + 5.0 * np.sin(xy[:, 0]) + np.cos(2.0 * xy[:, 1])
    return np.where(xy[:, 0] < 30.0, field, np.nan)


def cloud(
    xy: Sequence[tuple[float, float]],
    weights: Sequence[float] | None = None,
    floors: Sequence[int] | None = None,
    window: int = 3,
) -> Particles:
    p = from_points(np.array(xy, dtype=float), 0, window)
    if weights is not None:
        with np.errstate(divide="ignore"):
            log_w = np.log(np.asarray(weights, dtype=float) / np.sum(weights))
        p = replace(p, log_w=log_w.astype(np.float32))
    if floors is not None:
        p = replace(p, floor=np.asarray(floors, dtype=np.int16))
    return p


def with_window(
    p: Particles, mags: Sequence[Sequence[float]], observed: Sequence[float]
) -> Particles:
    """Fill the last ``len(observed)`` slots of the windows."""
    k = len(observed)
    m = p.mags.copy()
    m[:, -k:] = mags
    o = p.observed.copy()
    o[-k:] = observed
    return replace(p, mags=m, observed=o, count=k)


def weights_of(p: Particles) -> FloatArray:
    return np.exp(p.log_w.astype(np.float64))


def assert_normalised(p: Particles) -> None:
    assert not np.isnan(p.log_w).any()
    if alive(p):
        assert abs(weights_of(p).sum() - 1.0) < 1e-5
    else:
        assert np.all(p.log_w == -np.inf)


def assert_same(p: Particles, q: Particles) -> None:
    a, b = state_codec.to_arrays(p), state_codec.to_arrays(q)
    assert a.keys() == b.keys()
    for name in a:
        assert a[name].dtype == b[name].dtype, name
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def fixed_map(values: Sequence[float]) -> MapSampler:
    def sample_map(floor: FloorArray, xy: FloatArray) -> FloatArray:
        return np.asarray(values, dtype=float)[: xy.shape[0]]

    return sample_map
