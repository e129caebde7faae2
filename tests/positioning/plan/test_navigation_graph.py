"""Floor graphs: grid vertices in walkable space, links that respect walls and doors,
vertex kinds, reference points attached, moves learned from walks (eq 15)."""

from __future__ import annotations

import numpy as np
import pytest

from server.positioning.plan.floor_plan import crosses_wall, walkable_at
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.navigation_graph import (
    CORRIDOR,
    DECISION,
    DOOR,
    LINK,
    attach,
    free_graph,
    learn,
    plan_graph,
    site_graphs,
)
from server.positioning.radio.fingerprints import RadioMap
from tests.support.toy_plans import ROOM, box, feature, room

# a 2 m wide corridor 20 m long with a side room (door at x 9-11) and an elevator
CORRIDOR_PLAN = {
    "type": "FeatureCollection",
    "features": [
        feature("walkable", "Polygon", box(0, 0, 20, 2)),
        feature("walkable", "Polygon", box(8, 2, 12, 8)),
        feature("wall", "LineString", [[8, 2], [12, 2]]),
        feature("door", "LineString", [[9, 2], [11, 2]]),
        feature("elevator", "Polygon", box(10, 6, 12, 8)),
    ],
}


def test_vertices_lie_in_walkable_space_and_links_cross_no_wall() -> None:
    plan = room()
    graph = plan_graph(plan, ROOM)
    assert graph.n > 150
    assert walkable_at(plan, graph.xy).all()
    src = np.repeat(np.arange(graph.n), graph.degree)
    assert not crosses_wall(plan, graph.xy[src], graph.xy[graph.indices]).any()
    # links are symmetric and between grid neighbours only
    pairs = set(zip(src.tolist(), graph.indices.tolist(), strict=True))
    assert all((b, a) in pairs for a, b in pairs)
    gaps = np.linalg.norm(graph.xy[src] - graph.xy[graph.indices], axis=1)
    assert gaps.max() == pytest.approx(np.sqrt(2.0))
    # only the door links the two halves of the room (wall at x = 10)
    across = (graph.xy[src, 0] < 10) & (graph.xy[graph.indices, 0] > 10)
    assert across.any()
    ys = graph.xy[src[across], 1]
    assert ys.min() > 3.5
    assert ys.max() < 6.5


def test_kinds_of_a_corridor_a_room_a_door_and_an_elevator() -> None:
    plan = plan_from_geojson(CORRIDOR_PLAN)
    graph = plan_graph(plan, CORRIDOR_PLAN)
    kind = {tuple(xy): int(k) for xy, k in zip(graph.xy.tolist(), graph.kind, strict=True)}
    assert kind[(3.5, 0.5)] == CORRIDOR  # straight hallway, away from the side room
    assert kind[(10.5, 4.5)] == DECISION  # inside the room
    assert kind[(10.5, 1.5)] == kind[(10.5, 2.5)] == DOOR  # either side of the door line
    assert kind[(3.5, 1.5)] != DOOR
    assert kind[(11.5, 7.5)] == LINK


def test_free_graph_links_every_neighbour_without_walls() -> None:
    graph = free_graph(np.array([[0.0, 0.0], [4.0, 2.0]]))
    inner = (graph.degree == 8).sum()
    assert inner > 0
    assert (graph.kind == DECISION).all()
    assert graph.xy[:, 0].min() < -9
    assert graph.xy[:, 0].max() > 13


def test_rows_of_the_chain_sum_to_one_before_and_after_learning() -> None:
    graph = plan_graph(room(), ROOM)
    rows = np.asarray(graph.transition_matrix().sum(axis=1)).ravel()
    np.testing.assert_allclose(rows, 1.0)
    walk = np.array([[1.5, 5.5], [8.5, 5.5], [12.5, 5.0], [18.5, 5.0]])
    learned = learn(graph, [walk])
    rows = np.asarray(learned.transition_matrix().sum(axis=1)).ravel()
    np.testing.assert_allclose(rows, 1.0)


def test_learning_counts_the_moves_of_a_walk() -> None:
    """A walk east along y = 5.5 counts one move east from each vertex it passes:
    M = deg / (deg + 1) (a + 1) / (b + deg) with a = b = 1 (eq 15, uniform start); staying
    keeps 1 / (deg + 1), a move the walk did not make shrinks."""
    graph = plan_graph(room(), ROOM)
    learned = learn(graph, [np.array([[1.5, 5.5], [8.5, 5.5]])])
    j = graph.nearest([3.5, 5.5])
    i = graph.nearest([4.5, 5.5])
    row = slice(graph.indptr[j], graph.indptr[j + 1])
    east = graph.indptr[j] + int(np.flatnonzero(graph.indices[row] == i)[0])
    deg = graph.degree[j]
    assert learned.move_p[east] == pytest.approx(deg / (deg + 1) * 2.0 / (1 + deg))
    assert learned.stay_p[j] == pytest.approx(1.0 / (deg + 1))
    other = graph.indptr[j] + int(np.flatnonzero(graph.indices[row] != i)[0])
    assert learned.move_p[other] == pytest.approx(deg / (deg + 1) / (1 + deg))
    assert learned.move_p[other] < graph.move_p[other]
    untouched = graph.nearest([15.5, 1.5])
    assert learned.stay_p[untouched] == pytest.approx(graph.stay_p[untouched])


def test_reference_points_attach_to_their_nearest_vertex_on_their_floor() -> None:
    graph = plan_graph(room(), ROOM)
    radio = RadioMap(
        rp_xy=np.array([[2.4, 2.6], [15.0, 7.0], [3.0, 3.0]], dtype=np.float32),
        rp_floor=np.array([0, 0, 1], dtype=np.int32),
        mean_dbm=np.zeros((3, 1), dtype=np.float32),
        var_db2=np.zeros((3, 1), dtype=np.float32),
        count=np.ones((3, 1), dtype=np.int32),
        emitters=("wifi:a",),
    )
    attached = attach(graph, radio, 0)
    assert attached.rp_vertex[2] == -1
    np.testing.assert_allclose(attached.xy[attached.rp_vertex[0]], [2.5, 2.5])
    both = site_graphs([room(), None], [ROOM, None], radio, 2)
    assert both[0] is not None
    assert both[1] is not None
    assert both[1].rp_vertex[2] >= 0
    assert both[1].rp_vertex[0] == -1
