"""Synthetic building: the plan is closed, rooms are reachable, the graph avoids walls."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from client_sim.building import Floor, SyntheticBuilding, count_crossings, synthesize_building
from client_sim.seeding import sequence
from client_sim.walker import Walker
from client_sim.world import synthesize_world
from server.positioning.plan.floor_plan import valid_moves
from server.positioning.plan.geojson_plan import plan_from_geojson


def build(seed: int = 0, width_m: float = 60.0, depth_m: float = 30.0) -> SyntheticBuilding:
    return synthesize_building(np.random.default_rng(seed), width_m=width_m, depth_m=depth_m)


def reachable(floor: Floor, start: int = 0) -> set[int]:
    adjacency = floor.neighbours()
    seen, todo = {start}, deque([start])
    while todo:
        for nxt in adjacency[todo.popleft()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def check_floor(floor: Floor, width_m: float, depth_m: float) -> None:
    box = np.array([(r.x0, r.y0, r.x1, r.y1) for r in floor.walkable])
    # rooms and corridors tile the floor: no overlap, total area is the floor's
    assert sum(r.area_m2 for r in floor.walkable) == pytest.approx(width_m * depth_m)
    w = np.minimum(box[:, None, 2], box[None, :, 2]) - np.maximum(box[:, None, 0], box[None, :, 0])
    h = np.minimum(box[:, None, 3], box[None, :, 3]) - np.maximum(box[:, None, 1], box[None, :, 1])
    overlap = np.clip(w, 0, None) * np.clip(h, 0, None)
    np.fill_diagonal(overlap, 0.0)
    assert overlap.max() < 1e-9
    assert np.all((box[:, 0] >= 0) & (box[:, 0] < box[:, 2]) & (box[:, 2] <= width_m))
    assert np.all((box[:, 1] >= 0) & (box[:, 1] < box[:, 3]) & (box[:, 3] <= depth_m))
    # the outline is a closed ring around the floor
    assert np.array_equal(floor.outline[0], floor.outline[-1])
    assert np.allclose(floor.outline.min(axis=0), [0, 0])
    assert np.allclose(floor.outline.max(axis=0), [width_m, depth_m])
    # each room is closed by walls except at its one door
    half = floor.door_width_m / 2.0
    rooms = np.array([(r.x0, r.y0, r.x1, r.y1) for r in floor.walkable if r.use == "room"])
    assert len(floor.doors) == len(rooms)
    u = np.linspace(0.0, 1.0, 30)[None, :]
    x0, y0, x1, y1 = (rooms[:, i : i + 1] for i in range(4))
    xs = np.concatenate([x0 + (x1 - x0) * u, x1 + 0 * u, x0 + (x1 - x0) * u, x0 + 0 * u], 1)
    ys = np.concatenate([y0 + 0 * u, y0 + (y1 - y0) * u, y1 + 0 * u, y0 + (y1 - y0) * u], 1)
    samples = np.stack([xs, ys], axis=-1)  # (n_rooms, n_samples, 2)
    on_wall = floor.wall_distance_m(samples.reshape(-1, 2)).reshape(xs.shape) < 1e-9
    door = samples - floor.doors[:, None, :]  # room i's door is doors[i]
    in_door = np.hypot(door[..., 0], door[..., 1]) <= half + 1e-9
    assert np.all(on_wall | in_door)
    dx, dy = floor.doors[:, 0:1], floor.doors[:, 1:2]  # every room's door is on its outline
    on_x_side = np.isclose(dx, x0) | np.isclose(dx, x1)
    on_y_side = np.isclose(dy, y0) | np.isclose(dy, y1)
    assert np.all((on_x_side & (y0 < dy) & (dy < y1)) | (on_y_side & (x0 < dx) & (dx < x1)))
    # doors are gaps in walls
    assert np.all(floor.wall_distance_m(floor.doors) >= half - 1e-9)
    # the walkable graph: connected, on walkable ground, never through a wall
    assert reachable(floor) == set(range(len(floor.nodes)))
    assert np.all(floor.contains(floor.nodes))
    ends = floor.nodes[floor.edges]
    assert np.all(count_crossings(ends[:, 0], ends[:, 1], floor.walls) == 0)
    assert np.all(floor.edge_lengths_m > 0)


def test_default_building_is_closed_and_connected() -> None:
    building = build()
    assert building.levels == (0, 1)
    assert (building.width_m, building.depth_m) == (60.0, 30.0)
    for floor in building.floors:
        check_floor(floor, 60.0, 30.0)


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    width_m=st.floats(40.0, 120.0),
    depth_m=st.floats(24.0, 60.0),
    side_corridors=st.integers(0, 3),
)
def test_any_seed_and_size_gives_a_closed_connected_plan(
    seed: int, width_m: float, depth_m: float, side_corridors: int
) -> None:
    building = synthesize_building(
        np.random.default_rng(seed),
        width_m=width_m,
        depth_m=depth_m,
        side_corridors=side_corridors,
        levels=(-1, 0, 2),
    )
    assert building.levels == (-1, 0, 2)
    for floor in building.floors:
        check_floor(floor, width_m, depth_m)


def test_same_seed_same_building_other_seed_other_building() -> None:
    a, b, c = build(3), build(3), build(4)
    assert np.array_equal(a.floors[0].walls, b.floors[0].walls)
    assert a.floors[0].plan_geojson() == b.floors[0].plan_geojson()
    assert not np.array_equal(a.floors[0].doors, c.floors[0].doors)
    assert not np.array_equal(a.floors[0].doors, a.floors[1].doors)  # floors differ too


def test_plan_is_geojson_with_its_kinds() -> None:
    floor = build().floor(1)
    plan = floor.plan_geojson()
    assert plan["type"] == "FeatureCollection"
    geometry_of = {
        "walkable": "Polygon",
        "wall": "LineString",
        "door": "LineString",
        "stairs": "Polygon",
        "elevator": "Polygon",
    }
    kinds = set()
    for feature in plan["features"]:
        assert feature["type"] == "Feature"
        kind = feature["properties"]["kind"]
        kinds.add(kind)
        geometry = feature["geometry"]
        assert geometry["type"] == geometry_of[kind]
        if kind in ("walkable", "stairs", "elevator"):
            ring = geometry["coordinates"][0]
            assert ring[0] == ring[-1]
            assert len(ring) == 5
    assert kinds == {"walkable", "wall", "door", "stairs", "elevator"}
    walls = [f for f in plan["features"] if f["properties"]["kind"] == "wall"]
    assert len(walls) == len(floor.walls) - 3  # the outline's four sides are one ring
    assert walls[0]["geometry"]["coordinates"][0] == walls[0]["geometry"]["coordinates"][-1]


def test_the_service_reads_the_plan_and_walkers_never_cross_its_walls() -> None:
    world = synthesize_world(3)
    for index, floor in enumerate(world.building.floors):
        plan = plan_from_geojson(floor.plan_geojson())
        assert len(plan.walls) >= len(floor.walls)
        # each door opening lies on its gap: its ends are wall ends
        openings = floor.door_openings()
        assert np.allclose(np.hypot(*(openings[:, 1] - openings[:, 0]).T), floor.door_width_m)
        walker = Walker(world, floor.level, sequence(3, "walker", index), t0_ms=0)
        xy = np.array(
            [
                (e.truth.x_m, e.truth.y_m)
                for e, _ in zip(walker.events(), range(3000), strict=False)
                if e.event["type"] == "step"
            ]
        )
        assert len(xy) > 500
        assert valid_moves(plan, xy[:-1], xy[1:]).all()
        # a short move across the middle of each inner wall is refused
        a, b = floor.walls[4:, 0], floor.walls[4:, 1]
        along = (b - a) / np.hypot(*(b - a).T)[:, None]
        across = 0.3 * np.column_stack([-along[:, 1], along[:, 0]])
        middle = (a + b) / 2
        assert not valid_moves(plan, middle - across, middle + across).any()


def test_walkable_grid_keeps_clear_of_walls() -> None:
    floor = build().floor(0)
    grid = floor.walkable_grid(2.0, wall_clearance_m=0.25)
    assert len(grid) > 300
    assert np.all(floor.contains(grid))
    assert np.all(floor.wall_distance_m(grid) >= 0.25)


def test_count_crossings_counts_proper_crossings_only() -> None:
    square = np.array(
        [[[0, 0], [1, 0]], [[1, 0], [1, 1]], [[1, 1], [0, 1]], [[0, 1], [0, 0]]], dtype=float
    )
    p0 = np.array([[-1.0, 0.5], [0.5, 0.5], [-1.0, 0.5], [0.0, -1.0], [2.0, 2.0]])
    p1 = np.array([[2.0, 0.5], [0.6, 0.6], [0.5, 0.5], [0.0, 2.0], [3.0, 3.0]])
    assert count_crossings(p0, p1, square).tolist() == [2, 0, 1, 0, 0]  # along a wall: 0
    grid = count_crossings(p0[:, None, :], p1[None, :, :], square)
    assert grid.shape == (5, 5)


def test_too_small_a_floor_is_refused() -> None:
    with pytest.raises(ValueError, match="no room"):
        build(width_m=20.0, depth_m=10.0)
    with pytest.raises(ValueError, match="distinct"):
        synthesize_building(np.random.default_rng(0), levels=(0, 0))
