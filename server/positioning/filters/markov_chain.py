"""The reference-point Markov chain of ``papers/004_*``: a belief over a floor graph's
vertices moved by the chain and corrected by a WiFi scan.

A belief is sparse: vertex ids and their probabilities (summing to 1), at most
``max_states`` of them (the most probable; a beam, so a state stays small).

Moves (``move``), per hop of the chain, after ``papers/004_*`` eq 17-18: from vertex
``j`` with the walker's forward direction ``v`` (unit, or zero when standing, or None
when unknown) and reliability ``theta``, the weight of moving to a neighbour ``i`` with
``d = R_i - R_j`` is::

    (1 - theta) M_ji + theta M_ji <d/|d|, v>     v != 0, i != j
    (1 - theta) M_ji                             v  = 0, i != j
    (1 - theta) M_jj                             v != 0, i  = j   (staying)
    M_jj                                         v  = 0, i  = j

with ``<d/|d|, v>`` clipped at 0 (Wang writes the inner product; a negative weight would
not be a probability) and each vertex's weights normalised so the belief keeps its mass.
Every line is ``(1 - theta) M + theta M c`` with ``c`` how well the move agrees with the
sensors: the clipped cosine when walking, 0 for staying while walking or moving while
standing, and 1 for staying while standing. Eq 18 prints ``theta M_jj`` on that last line,
which at ``theta = 0`` would forbid standing still while every other line reduces to
``M``; with ``c = 1`` both ends hold: ``theta = 0`` is the chain alone, ``theta = 1``
standing keeps everyone where they are. Without a direction (no inertial data) the
weights are ``M`` itself, and so are those of a vertex none of whose moves agrees with
the direction at ``theta = 1`` (a dead end, walking across a corridor).

Correction (``correct``), eq 14: each state's weight is multiplied by the scan's
likelihood at its fingerprint, ``exp(-D^2 / (2 sigma^2)) / (sqrt(2 pi) sigma)`` with ``D``
the signal distance of eq 1 (over the emitters the scan heard, ``fingerprints``); the
constant factor cancels in the normalisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from server.positioning.plan.navigation_graph import FloorGraph

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Belief:
    """Vertex ids (ascending) and their probabilities."""

    vertex: IntArray
    p: FloatArray

    @staticmethod
    def at(vertex: int) -> Belief:
        return Belief(np.array([vertex], dtype=np.int64), np.array([1.0]))

    def dense(self, n: int) -> FloatArray:
        out = np.zeros(n)
        out[self.vertex] = self.p
        return out


def move(
    graph: FloorGraph,
    belief: Belief,
    direction: FloatArray | None,
    theta: float,
    hops: int = 1,
    max_states: int = 1_000_000,
) -> Belief:
    """The belief after ``hops`` moves of the chain (module docstring, eq 18)."""
    vertex, p = belief.vertex, belief.p
    for _ in range(hops):
        start = graph.indptr[vertex]
        count = graph.indptr[vertex + 1] - start
        rows = np.repeat(np.arange(vertex.shape[0]), count)
        links = np.repeat(start - np.cumsum(np.r_[0, count[:-1]]), count) + np.arange(rows.shape[0])
        to = graph.indices[links]
        w_move = graph.move_p[links].copy()
        w_stay = graph.stay_p[vertex].copy()
        if direction is not None:
            norm = float(np.linalg.norm(direction))
            if norm > 0:
                d = graph.xy[to] - graph.xy[vertex[rows]]
                cos = d @ (direction / norm) / np.linalg.norm(d, axis=1)
                w_move *= (1.0 - theta) + theta * np.maximum(cos, 0.0)
                w_stay *= 1.0 - theta
            else:
                w_move *= 1.0 - theta
        total = w_stay + np.bincount(rows, weights=w_move, minlength=vertex.shape[0])
        stuck = total <= 0  # θ = 1 and no move along the direction: the chain's own moves
        if stuck.any():
            w_stay[stuck] = graph.stay_p[vertex[stuck]]
            w_move[stuck[rows]] = graph.move_p[links[stuck[rows]]]
            total = w_stay + np.bincount(rows, weights=w_move, minlength=vertex.shape[0])
        share = p / total
        ids = np.concatenate([vertex, to])
        mass = np.concatenate([w_stay * share, w_move * share[rows]])
        found = np.unique(ids, return_inverse=True)
        summed = np.bincount(found[1], weights=mass).astype(np.float64)
        vertex, p = _pruned(found[0].astype(np.int64), summed, max_states)
    return Belief(vertex, p / p.sum())


def correct(prior: FloatArray, distances_db: FloatArray, sigma_db: float) -> FloatArray:
    """Eq 14: the states' weights times each one's scan likelihood, normalised.

    Parameters
    ----------
    prior : ndarray, shape (n,)
        Weights of the candidate states.
    distances_db : ndarray, shape (n,)
        Signal distance ``D`` of the scan to each state's fingerprint.
    sigma_db : float
        Eq 14's ``sigma``: the larger, the less a scan is believed.
    """
    log_w = np.log(np.maximum(prior, 1e-300)) - distances_db**2 / (2.0 * sigma_db**2)
    log_w -= log_w.max()
    w = np.exp(log_w)
    out: FloatArray = w / w.sum()
    return out


def _pruned(vertex: IntArray, p: FloatArray, max_states: int) -> tuple[IntArray, FloatArray]:
    if vertex.shape[0] <= max_states:
        return vertex, p
    keep = np.sort(np.argpartition(-p, max_states - 1)[:max_states])
    return vertex[keep], p[keep]
