"""Reference-point placement (Algorithm 1 of ``papers/004_*``) on toy floors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from server.positioning.mapping.survey_plan import (
    AccessPoint,
    noise_distance,
    noise_from_map,
    plan,
    survey_plan,
)
from server.positioning.plan.floor_plan import walkable_at
from server.positioning.plan.navigation_graph import (
    DECISION,
    FloorGraph,
    grid_graph,
    grid_pairs,
    plan_graph,
)
from server.positioning.radio.fingerprints import RadioMap
from tests.support.toy_plans import ROOM, room


def strip(n: int) -> FloorGraph:
    """A 1 m wide corridor of ``n`` grid points along y = 0.5."""
    xy = np.column_stack([np.arange(n) + 0.5, np.full(n, 0.5)])
    a, _ = grid_pairs(xy, 1.0)
    return grid_graph(xy, np.ones(a.shape[0], dtype=bool), np.full(n, DECISION, np.int8), 1.0)


def test_a_given_noise_distance_spaces_the_marks_by_it() -> None:
    """One AP at the corridor's start, Δ = 3 m on a 1 m grid: a mark every 3 m."""
    points, from_aps = plan(strip(20), (AccessPoint((0.5, 0.5), 2.0),), 4.0, noise_distance_m=3.0)
    xs = np.sort(points[:, 0])
    np.testing.assert_allclose(xs, np.arange(0.5, 20.0, 3.0))
    assert from_aps.all()


def test_marks_follow_the_noise_distance_of_the_path_loss_model() -> None:
    """δ = 6 dB, γ = 2: Δ(d) = d (10^0.3 - 1) ≈ d: marks about double their distance."""
    points, _ = plan(strip(80), (AccessPoint((0.5, 0.5), 2.0),), 6.0)
    xs = np.sort(points[:, 0]) - 0.5
    for a, b in itertools.pairwise(xs):
        assert b - a >= noise_distance(a, 6.0, 2.0) - 1e-9
        assert b - a < noise_distance(a, 6.0, 2.0) + 1.0  # the first grid point beyond
    assert noise_distance(10.0, 6.0, 2.0) == pytest.approx(10 * (10**0.3 - 1))


def test_plan_of_a_room_lies_in_walkable_space_and_covers_it() -> None:
    graph = plan_graph(room(), ROOM)
    aps = (AccessPoint((3.0, 8.0), 3.0), AccessPoint((15.0, 2.0), 3.0))
    points, from_aps = plan(graph, aps, 5.0)
    assert walkable_at(room(), points).all()
    assert from_aps.any()
    assert (~from_aps).any()
    # every walkable grid point is within a noise distance of a mark (Definition 2)
    d_ap = np.min(np.hypot(*(graph.xy[:, None, :] - np.array([a.xy for a in aps])).T), axis=0)
    d_mark = np.min(np.hypot(*(graph.xy[:, None, :] - points[None]).T), axis=0)
    assert (d_mark <= noise_distance(d_ap, 5.0, 3.0) + 1e-9).all()


def test_survey_plan_reads_noise_and_aps_from_the_map() -> None:
    rng = np.random.default_rng(0)
    graph = plan_graph(room(), ROOM)
    xy = graph.xy[::2]
    ap = np.array([6.0, 7.0])
    d = np.maximum(np.hypot(*(xy - ap).T), 1.0)
    mean = (-40 - 25 * np.log10(d))[:, None] + rng.normal(0, 0.5, (len(xy), 1))
    radio = RadioMap(
        rp_xy=xy.astype(np.float32),
        rp_floor=np.zeros(len(xy), dtype=np.int32),
        mean_dbm=mean.astype(np.float32),
        var_db2=np.full((len(xy), 1), 9.0, dtype=np.float32),
        count=np.full((len(xy), 1), 5, dtype=np.int32),
        emitters=("wifi:ap",),
    )
    assert noise_from_map(radio, 0) == pytest.approx(3.0)
    found = survey_plan(graph, radio, 0)
    assert found.noise_source == "map"
    assert found.noise_db == pytest.approx(3.0)
    assert len(found.aps) == 1
    np.testing.assert_allclose(found.aps[0].xy, ap, atol=0.5)
    assert 0 < found.expected_error_m < found.expected_error_p90_m < 5


def test_no_noise_still_gives_one_point_per_grid_point_at_most() -> None:
    graph = plan_graph(room(), ROOM)
    points, _ = plan(graph, (AccessPoint((3.0, 8.0), 3.0),), 0.0)
    assert len(np.unique(points, axis=0)) == len(points) <= graph.n


def test_an_access_point_outside_the_floor_still_marks_its_lines() -> None:
    points, from_aps = plan(strip(20), (AccessPoint((-30.5, 0.5), 2.0),), 4.0, noise_distance_m=3.0)
    assert from_aps.sum() >= 6
    np.testing.assert_allclose(np.sort(points[from_aps, 0])[:3], [0.5, 3.5, 6.5])
