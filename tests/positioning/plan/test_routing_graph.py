"""A site's routing graph: walking grids that respect walls and doors, clearance costs,
links between floors (one shaft by id, by name or by overlapping footprints; stairs
between consecutive levels, a lift between every pair; IMDF traversals) and named places."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import shapely
from scipy.sparse.csgraph import connected_components

from client_sim.building import Shaft, SyntheticBuilding, synthesize_building
from server.positioning.plan.floor_plan import crosses_wall, walkable_at
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.routing_graph import (
    LINK_SECONDS,
    WALK_SPEED_M_S,
    WALL_PENALTY,
    FloorInput,
    RoutingGraph,
    clearance_raster,
    floor_walk,
    routing_graph,
)
from tests.support.imdf_building import floor_inputs, imdf_levels
from tests.support.toy_plans import ROOM, box, feature, feature_collection, room


@pytest.fixture(scope="module")
def building() -> SyntheticBuilding:
    return synthesize_building(np.random.default_rng(0), levels=(0, 1, 2))


@pytest.fixture(scope="module")
def building_graph(building: SyntheticBuilding) -> RoutingGraph:
    return routing_graph(floor_inputs([(f.level, f.plan_geojson()) for f in building.floors]))


@pytest.fixture(scope="module")
def imdf_graph() -> RoutingGraph:
    return routing_graph(floor_inputs(imdf_levels()))


def links_of(graph: RoutingGraph, kind: str) -> set[tuple[int, int]]:
    return {(link.a[0], link.b[0]) for link in graph.links if link.kind == kind}


def vertex_xy(graph: RoutingGraph, end: tuple[int, int]) -> Any:
    walk = graph.floors[end[0]]
    assert walk is not None
    return walk.xy[end[1]]


# ---------------------------------------------------------------- floors


def test_vertices_are_walkable_edges_cross_no_wall_and_cost_at_most_the_penalty() -> None:
    plan = room()
    walk = floor_walk(plan, 0, 0, "b", [shapely.box(9.95, 4.5, 10.05, 5.5)])
    assert walk is not None
    assert walkable_at(plan, walk.xy).all()
    costs = walk.costs.tocoo()
    assert (walk.costs != walk.costs.T).nnz == 0
    assert not crosses_wall(plan, walk.xy[costs.row], walk.xy[costs.col]).any()
    walked_s = np.linalg.norm(walk.xy[costs.row] - walk.xy[costs.col], axis=1) / WALK_SPEED_M_S
    assert np.all(costs.data >= walked_s - 1e-12)
    assert np.all(costs.data <= walked_s * (1 + WALL_PENALTY) + 1e-12)
    # the wall at x = 10 is crossed only through its door (y 4.5-5.5), at its own vertex
    across = (walk.xy[costs.row, 0] < 10) & (walk.xy[costs.col, 0] > 10)
    assert across.any()
    assert np.all(np.abs(walk.xy[costs.row[across], 1] - 5.0) < 1.5)
    assert np.any(np.all(walk.xy == [10.0, 5.0], axis=1))  # the door's middle
    assert connected_components(walk.costs, directed=False)[0] == 1


def test_clearance_is_the_distance_to_the_nearest_wall_on_every_side() -> None:
    """A corridor 3 m wide along x: the clearance across it rises to the middle and falls
    to either wall, including the walls on the raster's far edges."""
    plan = plan_from_geojson(feature_collection(feature("walkable", "Polygon", box(0, 0, 40, 3))))
    across = clearance_raster(plan)[:, 80]  # x = 20 m
    y = plan.origin_m[1] + (np.arange(across.size) + 0.5) * plan.cell_m
    np.testing.assert_allclose(across, np.minimum(y, 3 - y), atol=plan.cell_m)
    assert across.max() == pytest.approx(1.375)
    along = clearance_raster(plan)[6, :]  # y = 1.625 m
    assert along[0] <= plan.cell_m
    assert along[-1] <= plan.cell_m


def test_the_clearance_of_a_floor_walk_favours_the_middle_of_a_corridor() -> None:
    plan = plan_from_geojson(feature_collection(feature("walkable", "Polygon", box(0, 0, 40, 3))))
    walk = floor_walk(plan, 0, 0, "b")
    assert walk is not None
    inner = (walk.xy[:, 0] > 2) & (walk.xy[:, 0] < 38)  # away from the ends' walls
    middle = walk.xy[:, 1] == 1.5
    assert walk.clearance_m[inner & middle].min() > walk.clearance_m[inner & ~middle].max()
    assert walk.clearance_m[inner & middle].min() >= 1.2


# ---------------------------------------------------------------- links


def test_the_simulators_stairs_join_consecutive_levels_and_its_lift_every_pair(
    building: SyntheticBuilding, building_graph: RoutingGraph
) -> None:
    assert links_of(building_graph, "stairs") == {(0, 1), (1, 2)}
    assert links_of(building_graph, "elevator") == {(0, 1), (0, 2), (1, 2)}
    assert len(building_graph.links) == 5
    shafts: dict[str, Shaft] = {s.kind: s for s in building.floors[0].shafts}
    assert all(f.shafts == building.floors[0].shafts for f in building.floors)
    for link in building_graph.links:
        shaft = shafts[link.kind]
        assert link.name == shaft.name
        assert not link.directed
        square = shapely.box(shaft.rect.x0, shaft.rect.y0, shaft.rect.x1, shaft.rect.y1)
        for end in (link.a, link.b):
            assert shapely.intersects_xy(square, *vertex_xy(building_graph, end))
        levels = abs(link.b[0] - link.a[0])  # the building's levels are 0, 1, 2
        fixed, per_level = LINK_SECONDS[link.kind]
        assert link.seconds == pytest.approx(fixed + per_level * levels)
    assert building_graph.places == ()  # the plan's features have no IMDF type


def test_imdf_stairs_and_lift_units_of_two_levels_are_linked_by_their_footprints(
    imdf_graph: RoutingGraph,
) -> None:
    """Each unit has an id of its own (IMDF): the main stairs and the lift of levels 0
    and 1 are matched by the footprints they share."""
    by_name = {link.name: link for link in imdf_graph.links}
    assert set(by_name) == {"Main stairs", "Lift", "Back stairs"}
    assert by_name["Main stairs"].kind == "stairs"
    assert by_name["Lift"].kind == "elevator"
    for name, square in (
        ("Main stairs", shapely.box(30, 0, 34, 4)),
        ("Lift", shapely.box(30, 6, 34, 10)),
    ):
        link = by_name[name]
        assert {link.a[0], link.b[0]} == {0, 1}
        for end in (link.a, link.b):
            assert shapely.intersects_xy(square, *vertex_xy(imdf_graph, end))
    assert all(2 not in (link.a[0], link.b[0]) for link in imdf_graph.links)  # the roof


def test_an_imdf_traversal_links_its_origin_and_destination_as_its_intermediary(
    imdf_graph: RoutingGraph,
) -> None:
    (link,) = [link for link in imdf_graph.links if link.name == "Back stairs"]
    assert link.kind == "stairs"  # the intermediary's category
    assert not link.directed
    lobby = shapely.box(-5, 0, 0, 10)  # west lobby of level 0 (origin) and of level 1
    assert (link.a[0], link.b[0]) == (0, 1)
    assert shapely.intersects_xy(lobby, *vertex_xy(imdf_graph, link.a))
    assert shapely.intersects_xy(lobby, *vertex_xy(imdf_graph, link.b))
    assert link.seconds == pytest.approx(sum(LINK_SECONDS["stairs"]))


def test_a_directed_traversal_is_one_way_and_takes_its_category_as_kind() -> None:
    levels = imdf_levels()
    traversal = next(f for f in levels[0][1]["features"] if f.get("feature_type") == "relationship")
    traversal["properties"].update(category="escalator", direction="directed")
    graph = routing_graph(floor_inputs(levels))
    (link,) = [link for link in graph.links if link.kind == "escalator"]
    assert link.directed
    assert (link.a[0], link.b[0]) == (0, 1)


def test_imdf_places_are_the_named_units_and_amenities(imdf_graph: RoutingGraph) -> None:
    places = {(p.name, p.floor) for p in imdf_graph.places}
    assert {("Bakery", 0), ("Office", 1), ("Toilets", 1), ("Roof terrace", 2)} <= places
    assert ("Lift", 0) in places
    toilets = next(p for p in imdf_graph.places if p.name == "Toilets")
    assert (toilets.id, toilets.category, toilets.shape.geom_type) == (
        "a1-toilets",
        "restroom",
        "Point",
    )
    assert len(places) == len(imdf_graph.places) == 13  # no opening, no relationship


def stairs_plan(stairs: list[list[list[float]]] | None) -> dict[str, Any]:
    """A 20 m x 10 m floor with, optionally, a stairs polygon with no id and no name."""
    features = [feature("walkable", "Polygon", box(0, 0, 20, 10))]
    if stairs is not None:
        features.append(feature("stairs", "Polygon", stairs))
    return feature_collection(*features)


def test_stairs_without_id_or_name_are_one_shaft_where_their_footprints_overlap() -> None:
    graph = routing_graph(
        floor_inputs([(0, stairs_plan(box(2, 2, 5, 5))), (1, stairs_plan(box(3, 3, 6, 6)))])
    )
    (link,) = graph.links
    assert (link.kind, link.name, link.a[0], link.b[0]) == ("stairs", None, 0, 1)
    # overlapping by less than a quarter of the smaller: two staircases, no link
    apart = [(0, stairs_plan(box(2, 2, 5, 5))), (1, stairs_plan(box(4.5, 4.5, 7.5, 7.5)))]
    assert routing_graph(floor_inputs(apart)).links == ()
    # overlapping, but with a level between them that has no stairs: no link either
    skip = [
        (0, stairs_plan(box(2, 2, 5, 5))),
        (1, stairs_plan(None)),
        (2, stairs_plan(box(2, 2, 5, 5))),
    ]
    assert routing_graph(floor_inputs(skip)).links == ()
    # nor between buildings
    inputs = floor_inputs([(0, stairs_plan(box(2, 2, 5, 5)))], "a")
    inputs += floor_inputs([(1, stairs_plan(box(2, 2, 5, 5)))], "b")
    assert routing_graph(inputs).links == ()


def test_a_floor_without_plan_has_no_walk_and_no_links() -> None:
    graph = routing_graph([*floor_inputs([(0, ROOM)]), FloorInput("imdf-b1", 1, None, None)])
    assert graph.floors[1] is None
    assert graph.floors[0] is not None
    assert graph.links == ()


def named_stairs_plan(*stairs: tuple[list[list[list[float]]], str | None, str | None]) -> Any:
    """A 40 m x 10 m floor with stairs polygons (geometry, id, name)."""
    features = [feature("walkable", "Polygon", box(0, 0, 40, 10))]
    for geometry, feature_id, name in stairs:
        stair = feature("stairs", "Polygon", geometry)
        if feature_id is not None:
            stair["id"] = feature_id
        if name is not None:
            stair["properties"]["name"] = name
        features.append(stair)
    return feature_collection(*features)


def test_a_name_shared_by_two_stairs_of_a_floor_does_not_cross_link_them() -> None:
    """Two staircases at each end, both named "Stairs", with ids numbered per floor (as
    exports number them): each is joined to the one above it, not across the floor."""
    west, east = box(1, 1, 4, 4), box(36, 1, 39, 4)
    plans = [
        (level, named_stairs_plan((west, "1", "Stairs"), (east, "2", "Stairs"))) for level in (0, 1)
    ]
    graph = routing_graph(floor_inputs(plans))
    assert len(graph.links) == 2
    for link in graph.links:
        assert link.a[0] != link.b[0]
        assert np.linalg.norm(vertex_xy(graph, link.a) - vertex_xy(graph, link.b)) < 5.0


def test_a_traversal_between_levels_is_not_accessible() -> None:
    levels = imdf_levels()
    traversal = next(f for f in levels[0][1]["features"] if f.get("feature_type") == "relationship")
    traversal["properties"]["intermediary"] = None  # a way up of no known kind
    graph = routing_graph(floor_inputs(levels))
    (link,) = [link for link in graph.links if link.kind == "traversal"]
    assert link.level_change
    assert not link.accessible
    assert [link.kind for link in graph.links if link.accessible] == ["elevator"] * sum(
        link.kind == "elevator" for link in graph.links
    )
