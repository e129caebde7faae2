"""The reference-point Markov chain on toy corridors: stationary distribution, a
hand-computed two-step update, the reliability θ at its ends (eq 14, 18)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.filters import markov_chain as mc
from server.positioning.plan.navigation_graph import DECISION, FloorGraph, grid_graph, grid_pairs


def corridor(n: int) -> FloorGraph:
    """``n`` vertices in a row, 1 m apart."""
    xy = np.column_stack([np.arange(n) + 0.5, np.full(n, 0.5)])
    a, _ = grid_pairs(xy, 1.0)
    return grid_graph(xy, np.ones(a.shape[0], dtype=bool), np.full(n, DECISION, np.int8), 1.0)


@settings(deadline=None)  # 2000 moves an example: its time is the machine's load
@given(st.integers(min_value=2, max_value=12))
def test_stationary_distribution_of_the_uniform_chain(n: int) -> None:
    """Every move of a vertex equally likely (deg + 1 of them): the chain is reversible
    with stationary distribution proportional to deg + 1."""
    graph = corridor(n)
    expected = (graph.degree + 1) / (graph.degree + 1).sum()
    belief = mc.Belief.at(0)
    for _ in range(2000):
        belief = mc.move(graph, belief, None, 0.6)
    np.testing.assert_allclose(belief.dense(n), expected, atol=1e-6)
    M = graph.transition_matrix().toarray()
    np.testing.assert_allclose(expected @ M, expected, atol=1e-12)


def test_two_steps_by_hand() -> None:
    """Corridor 0-1-2 (M: ends 1/2 stay 1/2 move, middle 1/3 each), start at 0.

    Step 1, no direction: p = (1/2, 1/2, 0). Scan with D = (10, 0, 10) dB, σ = 10:
    likelihood ratios e^-0.5 : 1 : e^-0.5, so p ∝ (e^-0.5 / 2, 1/2, 0).
    Step 2, moving east (v = +x) with θ = 0.5: from 0 stay (1 - θ)/2 = 1/4, east
    ((1 - θ) + θ cos 0)/2 = 1/2, shares 1/3, 2/3; from 1 west (1 - θ)/3 = 1/6 (cos < 0
    clipped), stay 1/6, east 1/3, shares 1/4, 1/4, 1/2."""
    graph = corridor(3)
    b1 = mc.move(graph, mc.Belief.at(0), None, 0.5)
    np.testing.assert_allclose(b1.dense(3), [0.5, 0.5, 0.0])
    w = mc.correct(b1.p, np.array([10.0, 0.0]), 10.0)
    a = np.exp(-0.5) / 2
    np.testing.assert_allclose(w, np.array([a, 0.5]) / (a + 0.5))
    b2 = mc.move(graph, mc.Belief(b1.vertex, w), np.array([1.0, 0.0]), 0.5)
    p0, p1 = w
    expected = [p0 / 3 + p1 / 4, 2 * p0 / 3 + p1 / 4, p1 / 2]
    np.testing.assert_allclose(b2.dense(3), expected)


def test_theta_at_its_ends() -> None:
    """θ = 0: moves by M whatever the direction; θ = 1 standing still: nobody moves;
    θ = 1 walking: no staying, and no move against the direction."""
    graph = corridor(5)
    start = mc.Belief.at(2)
    plain = mc.move(graph, start, None, 0.0)
    for direction in (np.array([1.0, 0.0]), np.zeros(2)):
        np.testing.assert_allclose(mc.move(graph, start, direction, 0.0).p, plain.p)
    still = mc.move(graph, start, np.zeros(2), 1.0)
    np.testing.assert_allclose(still.dense(5), [0, 0, 1, 0, 0])
    walking = mc.move(graph, start, np.array([1.0, 0.0]), 1.0)
    np.testing.assert_allclose(walking.dense(5), [0, 0, 0, 1, 0])


def test_the_beam_keeps_the_most_probable_states() -> None:
    graph = corridor(40)
    belief = mc.move(graph, mc.Belief.at(20), None, 0.6, hops=10, max_states=5)
    assert belief.vertex.shape[0] == 5
    assert belief.p.sum() == pytest.approx(1.0)
    assert 20 in belief.vertex.tolist()


def test_theta_one_against_every_move_falls_back_to_the_chain() -> None:
    """At a corridor's dead end walking on, or walking across a 1-D corridor, no move
    agrees with the direction: the vertex moves by M instead of losing its mass."""
    graph = corridor(3)
    for start, direction in ((2, np.array([1.0, 0.0])), (1, np.array([0.0, 1.0]))):
        moved = mc.move(graph, mc.Belief.at(start), direction, 1.0)
        assert np.isfinite(moved.p).all()
        assert moved.p.sum() == pytest.approx(1.0)
        np.testing.assert_allclose(moved.p, mc.move(graph, mc.Belief.at(start), None, 0.0).p)
