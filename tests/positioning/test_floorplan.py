"""Floor plans: raster, wall crossing, door gaps, seeding, against shapely and real ILC plans.

The crossing test is exact, so it must agree with shapely's (robust) ``intersects`` except
where a rounding error of the orientation tests could flip the answer: an end of the move
or of a wall within 1e-9 m of the other segment, with coordinates that are not all
multiples of 0.5 (those keep every product exact). The walkable raster judges a point by
its cell's centre, so it may disagree with the exact polygon within half a cell diagonal
(0.18 m at 0.25 m cells) of the area's boundary, and nowhere else.
"""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.datasets.ilc import read_site
from server.datasets.ilc_trace import read_trace
from server.positioning.floorplan import (
    CLEARANCE_STEPS,
    FloorPlan,
    _cells,
    _segments_meet,
    crosses_wall,
    plan_from_geojson,
    random_walkable_points,
    valid_moves,
    walkable_at,
)
from tests.datasets.conftest import dataset_dir

NUMERIC_TOL_M = 1e-9
RASTER_BAND_M = 0.25 * math.sqrt(0.5)  # half a cell diagonal


def _feature(kind: str, geometry_type: str, coordinates: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": {"kind": kind},
        "geometry": {"type": geometry_type, "coordinates": coordinates},
    }


def _box(x0: float, y0: float, x1: float, y1: float) -> list[list[list[float]]]:
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


# 20 m x 10 m room, a thin wall at x = 10 with a 1 m door (y 4.5-5.5), a 2 m pillar
ROOM = {
    "type": "FeatureCollection",
    "features": [
        _feature("walkable", "Polygon", _box(0, 0, 20, 10)),
        _feature("wall", "LineString", [[10, 0], [10, 10]]),
        _feature("door", "LineString", [[10, 4.5], [10, 5.5]]),
        _feature("wall", "Polygon", _box(4, 2, 6, 4)),
        _feature("anchor", "Point", [1, 1]),  # other kinds are ignored
    ],
}
# the same room drawn independently for the shapely reference
REF_AREA = shapely.difference(shapely.box(0, 0, 20, 10), shapely.box(4, 2, 6, 4))
REF_WALLS = shapely.union_all(
    [
        REF_AREA.boundary,
        shapely.linestrings([[10, 0], [10, 4.5]]),
        shapely.linestrings([[10, 5.5], [10, 10]]),
    ]
)
REF_VERTICES = shapely.multipoints(shapely.get_coordinates(REF_WALLS))
SNAP = 0.5


@cache
def room() -> FloorPlan:
    return plan_from_geojson(ROOM)


def _moves(a: Any, b: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_2d(np.asarray(b, dtype=float))


def test_room_raster_and_walls() -> None:
    plan = room()
    assert plan.origin_m == (0.0, 0.0)
    assert plan.cell_m == 0.25
    assert plan.walkable.shape == (40, 80)
    assert plan.walkable.sum() * 0.25**2 == pytest.approx(200 - 4)
    assert not plan.walkable[8:16, 16:24].any()  # the pillar
    assert plan.walkable[:8].all()
    # 4 outline edges, 4 pillar edges, the thin wall in two pieces around the door
    assert plan.walls.shape == (10, 4)
    thin = plan.walls[(plan.walls[:, 0] == 10) & (plan.walls[:, 2] == 10)]
    assert sorted(sorted((y1, y2)) for _, y1, _, y2 in thin.tolist()) == [[0, 4.5], [5.5, 10]]


@pytest.mark.parametrize(
    ("a", "b", "valid"),
    [
        pytest.param((9.5, 5.0), (10.5, 5.0), True, id="through the door"),
        pytest.param((10.4, 4.6), (9.6, 5.4), True, id="diagonally through the door"),
        pytest.param((9.5, 2.0), (10.5, 2.0), False, id="through the wall"),
        pytest.param((9.5, 4.4), (10.5, 4.4), False, id="just beside the door"),
        pytest.param((19.5, 5.0), (20.5, 5.0), False, id="out of the outline"),
        pytest.param((19.9, 9.5), (20.0, 9.5), False, id="onto the outline"),
        pytest.param((3.5, 3.0), (4.5, 3.0), False, id="into the pillar"),
        pytest.param((6.5, 3.0), (6.25, 3.0), True, id="up to the pillar"),
        pytest.param((9.0, 3.0), (10.0, 3.0), False, id="ending on the wall"),
        pytest.param((9.5, 4.0), (10.5, 5.0), False, id="through the door jamb"),
        pytest.param((10.0, 1.0), (10.0, 2.0), False, id="along the wall"),
        pytest.param((10.0, 4.6), (10.0, 5.4), True, id="along the door line"),
        pytest.param((1.0, 0.0), (2.0, 0.0), False, id="along the outline"),
        pytest.param((3.0, 1.0), (5.0, 3.0), False, id="into the pillar corner"),
        pytest.param((3.0, 1.0), (4.0, 2.0), False, id="ending on the pillar corner"),
        pytest.param((3.5, 2.5), (4.5, 1.5), False, id="grazing the pillar corner"),
        pytest.param((3.5, 2.6), (4.5, 1.6), False, id="clipping the pillar corner"),
        pytest.param((3.0, 1.9), (5.0, 1.95), True, id="under the pillar"),
        pytest.param((7.0, 5.0), (7.0, 5.0), True, id="standing still"),
        pytest.param((1.0, 5.0), (9.0, 5.0), True, id="long, clear"),
        pytest.param((1.0, 1.0), (19.0, 1.0), False, id="long, through the wall"),
        pytest.param((1.0, 9.0), (19.0, 3.0), False, id="long diagonal, through the wall"),
        pytest.param((1.0, 5.0), (19.0, 5.0), True, id="long, through the door"),
    ],
)
def test_moves(a: tuple[float, float], b: tuple[float, float], valid: bool) -> None:
    plan = room()
    assert valid_moves(plan, *_moves(a, b)).tolist() == [valid]
    assert valid_moves(plan, *_moves(b, a)).tolist() == [valid]  # the wall part is symmetric


def test_moves_are_vectorised() -> None:
    a = np.array([[9.5, 5.0], [9.5, 2.0], [1.0, 1.0], [1.0, 5.0]])
    b = np.array([[10.5, 5.0], [10.5, 2.0], [19.0, 1.0], [1.5, 5.5]])
    assert valid_moves(room(), a, b).tolist() == [True, False, False, True]
    assert crosses_wall(room(), a, b).tolist() == [False, True, True, False]
    assert valid_moves(room(), a[:0], b[:0]).shape == (0,)


def test_non_finite_points() -> None:
    plan = room()
    bad = np.array([[np.nan, 1.0], [1.0, np.inf], [-np.inf, np.nan]])
    good = np.full((3, 2), 1.0)
    assert not walkable_at(plan, bad).any()
    assert crosses_wall(plan, good, bad).all()
    assert crosses_wall(plan, bad, good).all()
    assert not valid_moves(plan, good, bad).any()


def test_walkable_at_outside_the_raster() -> None:
    xy = [[-0.1, 5.0], [5.0, -0.1], [20.1, 5.0], [5.0, 10.1], [0.1, 0.1], [19.9, 9.9]]
    assert walkable_at(room(), xy).tolist() == [False] * 4 + [True] * 2


def test_thick_wall_with_a_door_polygon() -> None:
    plan = plan_from_geojson(
        {
            "features": [
                _feature("walkable", "Polygon", _box(0, 0, 20, 10)),
                _feature("wall", "Polygon", _box(9.75, 0, 10.25, 10)),
                _feature("door", "Polygon", _box(9.7, 4.5, 10.3, 5.5)),  # wider than the wall
            ]
        }
    )
    a, b = _moves(
        [[9.5, 5.0], [9.5, 2.0], [9.5, 2.0], [9.5, 4.4]],
        [[10.5, 5.0], [10.5, 2.0], [10.0, 2.0], [10.5, 4.4]],
    )
    assert valid_moves(plan, a, b).tolist() == [True, False, False, False]
    assert walkable_at(plan, [[10.0, 5.0], [10.0, 2.0]]).tolist() == [True, False]


def test_ilc_kinds_outline_minus_units() -> None:
    plan = plan_from_geojson(
        {
            "features": [
                _feature("outline", "MultiPolygon", [_box(0, 0, 10, 10)]),
                _feature("unit", "Polygon", _box(2, 2, 8, 8)),
                _feature("obstacle", "Polygon", _box(0, 0, 1, 1)),
            ]
        }
    )
    assert walkable_at(plan, [[1.0, 5.0], [5.0, 5.0], [0.5, 0.5], [1.5, 1.5]]).tolist() == [
        True,
        False,
        False,
        True,
    ]
    assert valid_moves(
        plan, *_moves([[1.0, 5.0], [1.0, 5.0]], [[1.0, 6.0], [2.5, 5.0]])
    ).tolist() == [
        True,
        False,
    ]


@pytest.mark.parametrize(
    ("geojson", "message"),
    [
        pytest.param({"features": []}, "no walkable polygon", id="empty"),
        pytest.param({"features": [3]}, "feature 0: not a GeoJSON feature", id="not a feature"),
        pytest.param(
            {"features": [_feature("wall", "LineString", [[0, 0], [1, 1]])]},
            "no walkable polygon",
            id="walls only",
        ),
        pytest.param(
            {"features": [_feature("walkable", "LineString", [[0, 0], [1, 1]])]},
            "feature 0 \\(walkable\\): unexpected LineString",
            id="walkable line",
        ),
        pytest.param(
            {
                "features": [
                    _feature("walkable", "Polygon", _box(0, 0, 1, 1)),
                    _feature("door", "Point", [0.5, 0.0]),
                ]
            },
            "feature 1 \\(door\\): unexpected Point",
            id="door point",
        ),
        pytest.param(
            {"features": [{"properties": {"kind": "walkable"}, "geometry": {"type": "Nope"}}]},
            "feature 0 \\(walkable\\): not a GeoJSON geometry",
            id="bad geometry",
        ),
        pytest.param(
            {
                "features": [
                    _feature("walkable", "Polygon", _box(0, 0, 1, 1)),
                    _feature("wall", "Polygon", _box(-1, -1, 2, 2)),
                ]
            },
            "the walkable area is empty",
            id="all walled",
        ),
    ],
)
def test_bad_plans(geojson: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        plan_from_geojson(geojson)


def test_a_self_crossing_polygon_is_repaired() -> None:
    bow_tie = [[[0, 0], [4, 4], [4, 0], [0, 4], [0, 0]]]  # two triangles meeting at (2, 2)
    plan = plan_from_geojson({"features": [_feature("walkable", "Polygon", bow_tie)]})
    assert walkable_at(plan, [[0.5, 2.0], [2.0, 0.5], [3.5, 2.0]]).tolist() == [True, False, True]
    assert plan.walls.shape == (6, 4)
    assert not valid_moves(plan, [[0.5, 2.0]], [[3.5, 2.0]]).any()  # through the waist


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="cell_m"):
        plan_from_geojson(ROOM, cell_m=0.0)
    with pytest.raises(ValueError, match="shape"):
        walkable_at(room(), [1.0, 2.0])
    with pytest.raises(ValueError, match="differ in shape"):
        crosses_wall(room(), np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="walls"):
        FloorPlan((0.0, 0.0), 1.0, np.ones((2, 2), dtype=bool), np.zeros((3, 2)))


def test_a_plan_without_walls_is_rebuilt_from_its_arrays() -> None:
    bare = FloorPlan((0.0, 0.0), 1.0, np.ones((2, 2), dtype=bool), np.zeros((0, 4)))
    assert valid_moves(bare, [[0.5, 0.5]], [[1.5, 1.5]]).tolist() == [True]
    plan = room()
    copy = FloorPlan(plan.origin_m, plan.cell_m, plan.walkable.copy(), plan.walls.copy())
    a = random_walkable_points(plan, 500, np.random.default_rng(3))
    b = a + np.random.default_rng(4).normal(0, 0.7, a.shape)
    np.testing.assert_array_equal(valid_moves(copy, a, b), valid_moves(plan, a, b))


def _coordinate(low: float, high: float) -> st.SearchStrategy[float]:
    snapped = st.integers(math.ceil(low / SNAP), math.floor(high / SNAP)).map(lambda k: k * SNAP)
    # rounded to a nanometre: GEOS measures no distance to a 1e-170 m segment
    return st.one_of(snapped, st.floats(low, high).map(lambda v: round(v, 9)))


@st.composite
def short_moves(draw: st.DrawFn) -> tuple[float, float, float, float]:
    ax, ay = draw(_coordinate(-1.0, 21.0)), draw(_coordinate(-1.0, 11.0))
    reach = 1.5 / math.sqrt(2)  # keeps the move at most 1.5 m long
    bx, by = draw(_coordinate(ax - reach, ax + reach)), draw(_coordinate(ay - reach, ay + reach))
    return ax, ay, bx, by


@settings(max_examples=400, deadline=None)
@given(short_moves())
def test_moves_agree_with_shapely(move: tuple[float, float, float, float]) -> None:
    ax, ay, bx, by = move
    a, b = _moves([ax, ay], [bx, by])
    end = shapely.points([bx, by])
    # shapely takes a zero-length line for an empty one
    segment = shapely.linestrings([[ax, ay], [bx, by]]) if (ax, ay) != (bx, by) else end
    crosses = bool(crosses_wall(room(), a, b)[0])
    walkable = bool(walkable_at(room(), b)[0])
    exact_crosses = bool(shapely.intersects(REF_WALLS, segment))
    exact_walkable = bool(shapely.contains(REF_AREA, end))
    numeric = any(v % SNAP for v in move) and (
        min(
            shapely.distance(REF_WALLS, shapely.points([ax, ay])),
            shapely.distance(REF_WALLS, end),
            shapely.distance(REF_VERTICES, segment),
        )
        < NUMERIC_TOL_M
    )
    in_band = shapely.distance(REF_AREA.boundary, end) < RASTER_BAND_M
    assert crosses == exact_crosses or numeric, (crosses, exact_crosses)
    assert walkable == exact_walkable or in_band, (walkable, exact_walkable)
    valid = bool(valid_moves(room(), a, b)[0])
    assert valid == (walkable and not crosses)
    assert valid == (exact_walkable and not exact_crosses) or numeric or in_band


def test_particles_never_leave_the_area_nor_cross_a_wall() -> None:
    """Seeded particles making valid moves only stay strictly inside the exact area."""
    plan, rng = room(), np.random.default_rng(11)
    n = 2000
    xy = random_walkable_points(plan, n, rng)
    heading = rng.uniform(0, 2 * np.pi, size=n)
    shapely.prepare(REF_WALLS)
    moved = 0
    for _ in range(40):
        heading += rng.normal(0, 0.5, size=n)
        step = rng.uniform(0.3, 1.5, size=n)
        b = xy + step[:, None] * np.column_stack([np.sin(heading), np.cos(heading)])
        ok = valid_moves(plan, xy, b)
        segments = shapely.linestrings(np.stack([xy[ok], b[ok]], axis=1))
        assert not shapely.intersects(REF_WALLS, segments).any()
        xy[ok] = b[ok]
        heading[~ok] += np.pi  # turn back at walls
        moved += int(ok.sum())
        assert shapely.contains_xy(REF_AREA, xy[:, 0], xy[:, 1]).all()
    assert moved > 0.8 * 40 * n
    # the walkers went through the door
    assert 0 < np.mean(xy[:, 0] > 10) < 1


def test_random_walkable_points() -> None:
    plan = room()
    xy = random_walkable_points(plan, 20_000, np.random.default_rng(5))
    assert xy.shape == (20_000, 2)
    assert walkable_at(plan, xy).all()
    assert shapely.contains_xy(REF_AREA, xy[:, 0], xy[:, 1]).all()
    np.testing.assert_array_equal(
        xy, random_walkable_points(plan, 20_000, np.random.default_rng(5))
    )
    assert not np.array_equal(xy, random_walkable_points(plan, 20_000, np.random.default_rng(6)))
    # uniform: the left half holds 96 of the 196 m^2 (sd of the share about 0.0035)
    assert np.mean(xy[:, 0] < 10) == pytest.approx(96 / 196, abs=0.015)


def test_random_walkable_points_in_a_disc() -> None:
    plan = room()
    centre = np.array([6.2, 3.0])  # just right of the pillar
    xy = random_walkable_points(plan, 5000, np.random.default_rng(7), centre=centre, radius_m=1.0)
    assert np.all(np.hypot(*(xy - centre).T) <= 1.0)
    assert shapely.contains_xy(REF_AREA, xy[:, 0], xy[:, 1]).all()
    assert xy[:, 0].min() > 6.0
    assert random_walkable_points(plan, 0, np.random.default_rng(7)).shape == (0, 2)
    with pytest.raises(ValueError, match="within the disc"):
        random_walkable_points(plan, 3, np.random.default_rng(7), centre=(30.0, 30.0), radius_m=2.0)
    with pytest.raises(ValueError, match="both"):
        random_walkable_points(plan, 3, np.random.default_rng(7), centre=(3.0, 3.0))
    with pytest.raises(ValueError, match="negative"):
        random_walkable_points(plan, -1, np.random.default_rng(7))


# --- real ILC 2.0 floor plans (site2) ---


@pytest.fixture(scope="module")
def site2() -> list[tuple[str, FloorPlan, NDArray[np.float64]]]:
    """Each floor's plan and the waypoints of its first two traces."""
    site = read_site(dataset_dir("ilc20-sample") / "site2")
    floors = []
    for floor in site.floors:
        assert floor.plan is not None, floor.name
        waypoints = [read_trace(Path(p)).waypoint_xy_m for p in floor.trace_files[:2]]
        floors.append((floor.name, plan_from_geojson(floor.plan), np.concatenate(waypoints)))
    return floors


def test_ilc_plans_build(site2: list[tuple[str, FloorPlan, NDArray[np.float64]]]) -> None:
    assert [name for name, _, _ in site2] == ["B1", "F1", "F2", "F3", "F4", "F5", "F6", "F7", "F8"]
    for name, plan, _ in site2:
        assert plan.cell_m == 0.25, name
        assert 0.1 < plan.walkable.mean() < 0.5, name  # corridors: a quarter of the box
        assert plan.walls.shape[0] > 300, name


def test_ilc_waypoints_are_walkable(
    site2: list[tuple[str, FloorPlan, NDArray[np.float64]]],
) -> None:
    """Measured: all 3,054 waypoints of site2's 417 traces are in walkable cells."""
    walkable = np.concatenate([walkable_at(plan, xy) for _, plan, xy in site2])
    assert walkable.size > 100
    assert walkable.mean() >= 0.99


def test_ilc_crossings_agree_with_shapely(
    site2: list[tuple[str, FloorPlan, NDArray[np.float64]]],
) -> None:
    _, plan, _ = site2[0]  # B1, the largest floor
    rng = np.random.default_rng(8)
    n = 3000  # moves up to 3 m long: most in one piece, some cut in up to three
    a = random_walkable_points(plan, n, rng)
    heading = rng.uniform(0, 2 * np.pi, size=n)
    step = rng.uniform(0, 3.0, size=n)
    b = a + step[:, None] * np.column_stack([np.sin(heading), np.cos(heading)])
    walls = shapely.multilinestrings(plan.walls.reshape(-1, 2, 2))
    exact = shapely.intersects(walls, shapely.linestrings(np.stack([a, b], axis=1)))
    assert 0.05 < exact.mean() < 0.5
    np.testing.assert_array_equal(crosses_wall(plan, a, b), exact)


def test_plan_extent_is_the_box_of_the_walkable_features() -> None:
    from server.positioning.floorplan import plan_extent

    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"kind": "walkable"},
                "geometry": {"type": "Polygon", "coordinates": [[[1, 2], [9, 2], [9, 5], [1, 2]]]},
            },
            {
                "type": "Feature",
                "properties": {"beacon": "b"},
                "geometry": {"type": "Point", "coordinates": [500, 500]},
            },
        ],
    }
    assert plan_extent(plan) == (1.0, 2.0, 9.0, 5.0)
    assert plan_extent({"type": "FeatureCollection", "features": []}) is None
    assert plan_extent(None) is None


# --- the fast paths against the plain test ---


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
        out[rows] = _segments_meet(p, q, c, d).reshape(rows.size, m).any(axis=1)
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
        _feature("wall", "LineString", [s, e])
        for s, e in zip(start.tolist(), end.tolist(), strict=True)
    ]
    pillars = [
        _feature("wall", "Polygon", _box(x, y, x + 0.4, y + 0.4))
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
