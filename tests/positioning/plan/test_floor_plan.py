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
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from lab.datasets.ilc import read_site
from server.positioning.plan.floor_plan import (
    FloorPlan,
    crosses_wall,
    random_walkable_points,
    valid_moves,
    walkable_at,
)
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.storage.ilc_trace_format import read_trace
from tests.support.datasets import dataset_dir
from tests.support.toy_plans import ROOM, as_moves, room

NUMERIC_TOL_M = 1e-9
RASTER_BAND_M = 0.25 * math.sqrt(0.5)  # half a cell diagonal

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
    assert valid_moves(plan, *as_moves(a, b)).tolist() == [valid]
    assert valid_moves(plan, *as_moves(b, a)).tolist() == [valid]  # the wall part is symmetric


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
    a, b = as_moves([ax, ay], [bx, by])
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
