"""The wall index, box filter, cutting of long moves and clearance raster against the plain
orientation test of every move against every wall."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
import shapely
from numpy.typing import NDArray

from server.positioning.plan.floor_plan import (
    FloorPlan,
    _cells,
    crosses_wall,
    random_walkable_points,
    valid_moves,
    walkable_at,
)
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.wall_index import CLEARANCE_STEPS, segments_meet
from tests.support.toy_plans import ROOM, box, feature, room


def _plain_crossing(
    plan: FloorPlan, a: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """The orientation test of every move against every wall: no index, no clearance
    raster, no box filter, no cutting of long moves."""
    out = ~np.asarray(np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1), dtype=bool)
    walls = plan.walls
    m = walls.shape[0]
    for rows in np.array_split(np.flatnonzero(~out), max(1, a.shape[0] // 100)):
        p, q = np.repeat(a[rows], m, axis=0), np.repeat(b[rows], m, axis=0)
        c, d = np.tile(walls[:, :2], (rows.size, 1)), np.tile(walls[:, 2:], (rows.size, 1))
        out[rows] = segments_meet(p, q, c, d).reshape(rows.size, m).any(axis=1)
    return out


@cache
def cluttered() -> FloorPlan:
    """The room with 150 random thin walls (0.2-3 m, any direction) and a few pillars."""
    rng = np.random.default_rng(21)
    start = rng.uniform([0, 0], [20, 10], size=(150, 2))
    angle = rng.uniform(0, np.pi, size=150)
    end = start + rng.uniform(0.2, 3.0, size=(150, 1)) * np.column_stack(
        [np.cos(angle), np.sin(angle)]
    )
    features = [
        feature("wall", "LineString", [s, e])
        for s, e in zip(start.tolist(), end.tolist(), strict=True)
    ]
    pillars = [
        feature("wall", "Polygon", box(x, y, x + 0.4, y + 0.4))
        for x, y in rng.uniform([1, 1], [18, 8], size=(8, 2)).tolist()
    ]
    return plan_from_geojson({"features": [*ROOM["features"], *features, *pillars]})


def _random_moves(
    plan: FloorPlan, n: int, rng: np.random.Generator, max_m: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Moves from walkable points and from anywhere around the plan, and moves that
    start exactly at a wall's end or on a wall (grazing)."""
    k = n // 4
    a = np.concatenate([random_walkable_points(plan, n - k, rng), rng.uniform(-2, 22, size=(k, 2))])
    heading = rng.uniform(0, 2 * np.pi, size=n)
    length = rng.uniform(0, max_m, size=n) * (rng.random(n) > 0.02)  # some stand still
    step = length[:, None] * np.column_stack([np.sin(heading), np.cos(heading)])
    walls = plan.walls[rng.integers(plan.walls.shape[0], size=k)]
    t = rng.random((k, 1))
    a[:k] = walls[:, 2:]  # starts at a wall's end (a cut move's first piece starts at a)
    a[k : 2 * k] = walls[:, :2] + t * (walls[:, 2:] - walls[:, :2])  # starts on a wall
    return a, a + step


@pytest.mark.parametrize("max_m", [0.3, 1.0, 3.0])
def test_fast_crossing_test_agrees_with_the_plain_test(max_m: float) -> None:
    """Clearance raster, wall index, box filter and cutting of long moves give the plain
    test's answer on every move (moves up to 1 m are tested in one piece)."""
    for plan in (cluttered(), room()):
        a, b = _random_moves(plan, 4000, np.random.default_rng(int(max_m * 10)), max_m)
        plain = _plain_crossing(plan, a, b)
        assert 0.05 < plain.mean() < 0.95
        fast = crosses_wall(plan, a, b)
        np.testing.assert_array_equal(fast, plain)
        np.testing.assert_array_equal(valid_moves(plan, a, b), walkable_at(plan, b) & ~plain)
        # the clearance raster spared some of the moves the segment test (in the room
        # 13-27 %, in the cluttered room 0.5-5 %)
        cell, inside = _cells(plan, a)
        length2 = np.sum((b - a) ** 2, axis=1)
        spared = inside & (length2 < plan._clear_below[plan._clearance[cell]])
        assert spared.sum() >= 10


def test_clearance_is_a_lower_bound_of_the_distance_to_the_walls() -> None:
    """Any point of a cell is at least the cell's clearance from every wall, walls
    outside the raster included."""
    rng = np.random.default_rng(5)
    base = cluttered()
    outside = np.array([[-3.0, 5.0, -0.5, 5.0], [25.0, -1.0, 25.0, 12.0]])  # off the raster
    plan = FloorPlan(
        base.origin_m, base.cell_m, base.walkable, np.concatenate([base.walls, outside])
    )
    xy = rng.uniform(
        plan.origin_m,
        np.asarray(plan.origin_m) + plan.cell_m * np.array(plan.walkable.shape[::-1]),
        size=(20000, 2),
    )
    cell, inside = _cells(plan, xy)
    assert inside.all()
    clearance_m = plan._clearance[cell] * (plan.cell_m / CLEARANCE_STEPS)
    walls = shapely.multilinestrings(plan.walls.reshape(-1, 2, 2))
    distance = shapely.distance(walls, shapely.points(xy))
    assert np.all(clearance_m <= distance)
    # and not a useless one: the slack is two cell diagonals at most (measured: 0.67 m,
    # median 0.19 m)
    assert np.max(distance - clearance_m) < 4 * plan.cell_m
    assert np.median(distance - clearance_m) < plan.cell_m
    # a plan without walls: the clearance only reflects the edge of the raster
    bare = FloorPlan((0.0, 0.0), 0.25, np.ones((40, 40), dtype=bool), np.zeros((0, 4)))
    # the middle cells of 40: their points come within 19 cells (4.75 m) of the edge
    assert bare._clearance.max() == 19 * CLEARANCE_STEPS
