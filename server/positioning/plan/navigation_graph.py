"""A floor's navigation graph: reference points on a grid over walkable space, linked
where a walker can go in one move, as the Markov chain of ``papers/004_*`` (Wang et al.).

Wang's vector map (section "Using map in tracking phase") has vertices (room centres, door
midpoints, corridor points and corners), edges between them and locations (rooms,
hallways); the reference points over it form a Markov chain whose states are RPs and
whose moves are "go forward, turn left, turn right, turn back, stay" (Figure 1). Here the
vertices are the points of a square grid of side ``spacing_m`` that fall in the floor
plan's walkable space (``floor_plan``); two vertices are linked when they are grid
neighbours (the 8 around a point) and the segment between them meets no wall, so a door
is a gap that links the vertices on both sides of its wall. Each vertex has a kind:

* ``CORRIDOR``: the only free directions around it (rays of ``OPEN_RAY_M`` that stay in
  walkable space and meet no wall) are one pair of opposite ones -- a straight hallway;
* ``DECISION``: anything else -- a corner, a junction, a room, an entrance, open space:
  the places where Algorithm 3 lets the chain predict every branch;
* ``DOOR``: inside (or on) a ``"door"`` feature of the plan;
* ``LINK``: inside an ``"elevator"``, ``"stairs"`` or ``"escalator"`` feature: where a
  walk may leave the floor.

A floor without a plan gets a free grid over the points within ``FREE_MARGIN_M`` of its
reference points: every vertex ``DECISION``, every neighbour pair linked.

Transitions (``papers/004_*`` eq 15). ``M[j, i] = P(R_{t+1} = i | R_t = j)`` over the
moves of ``j`` (its links and staying). Before any walk is known every move of a vertex
is equally likely (Wang: "initialized with the same probability"); walks then count
moves: ``M[j, i] = deg_j / (deg_j + 1) * (a_ji + 1) / (b_j + deg_j)`` with ``a_ji`` the
moves from ``j`` to ``i`` and ``b_j`` the departures from ``j`` over the walks given to
``learn`` (eq 15's counting rule with the uniform start kept as one pseudo-count per
move). Walks are resampled every half spacing and snapped to vertices, so each counted
move is one link; they tell where people go, not how long they stand, so staying keeps
its uniform ``M[j, j] = 1 / (deg_j + 1)`` (eq 15 would count stays by the sampling rate
of the walk).

The radio map's reference points of the floor are attached to their nearest vertex
(``rp_vertex``); a vertex may hold none (space nobody surveyed) or several.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from server.positioning.plan.floor_plan import FloorPlan, crosses_wall, walkable_at
from server.positioning.radio.fingerprints import RadioMap

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

CORRIDOR, DECISION, DOOR, LINK = 0, 1, 2, 3
KIND_NAMES = ("corridor", "decision", "door", "link")

SPACING_M = 1.0
"""Default grid side (m): the radio maps' cell (``services.maps.SURVEY_CELL_M``)."""

OPEN_RAY_M = 3.0
"""Length of the rays that tell a corridor vertex from a decision vertex (m)."""

FREE_MARGIN_M = 10.0
"""Margin of a plan-less floor's grid around its reference points (m)."""

LINK_KINDS = frozenset({"elevator", "stairs", "escalator"})

# the 8 grid moves, counter-clockwise from east
_OFFSETS = np.array([(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)])


@dataclass(frozen=True, eq=False)
class FloorGraph:
    """Vertices, links (CSR, each undirected link in both rows), their kinds and the
    chain's move probabilities.

    Attributes
    ----------
    spacing_m : float
    xy : ndarray, shape (n, 2), float64
        Vertex positions (m, floor frame).
    kind : ndarray, shape (n,), int8
        ``CORRIDOR``, ``DECISION``, ``DOOR`` or ``LINK``.
    indptr, indices : ndarray, int64
        Row ``j``'s neighbours are ``indices[indptr[j]:indptr[j + 1]]``, ascending.
    move_p : ndarray, shape (n_links,), float64
        ``M[j, i]`` of each link in that order.
    stay_p : ndarray, shape (n,), float64
        ``M[j, j]``; each row of moves and stay sums to 1.
    rp_vertex : ndarray, shape (n_rp,), int64
        Vertex of each radio-map reference point of this floor; -1 for RPs of other floors.
    """

    spacing_m: float
    xy: FloatArray
    kind: NDArray[np.int8]
    indptr: IntArray
    indices: IntArray
    move_p: FloatArray
    stay_p: FloatArray
    rp_vertex: IntArray

    @property
    def n(self) -> int:
        return int(self.xy.shape[0])

    @property
    def degree(self) -> IntArray:
        return np.diff(self.indptr)

    @cached_property
    def tree(self) -> cKDTree:
        return cKDTree(self.xy)

    @cached_property
    def fingerprint(self) -> int:
        """A number that changes when the vertices do (a state's vertex ids are only
        meaningful on the graph they were found on)."""
        digest = hashlib.blake2b(self.xy.tobytes(), digest_size=7).digest()
        return int.from_bytes(digest, "big")

    def nearest(self, xy: Sequence[float] | FloatArray) -> int:
        """The vertex nearest a point."""
        return int(self.tree.query(np.asarray(xy, dtype=np.float64))[1])

    def transition_matrix(self) -> csr_matrix:
        """``M`` as a sparse (n, n) row-stochastic matrix (row: from, column: to)."""
        rows = np.repeat(np.arange(self.n), self.degree)
        return csr_matrix(
            (
                np.concatenate([self.move_p, self.stay_p]),
                (
                    np.concatenate([rows, np.arange(self.n)]),
                    np.concatenate([self.indices, np.arange(self.n)]),
                ),
            ),
            shape=(self.n, self.n),
        )


def grid_graph(
    xy: FloatArray, linked: NDArray[np.bool_], kind: NDArray[np.int8], spacing_m: float
) -> FloorGraph:
    """A graph over grid vertices ``xy`` (multiples of ``spacing_m`` plus half a cell)
    with the uniform chain; ``linked(a, b)`` is ``linked[k]`` for the k-th candidate pair
    of ``grid_pairs``."""
    a, b = grid_pairs(xy, spacing_m)
    a, b = a[linked], b[linked]
    return _from_links(xy, np.concatenate([a, b]), np.concatenate([b, a]), kind, spacing_m)


def grid_pairs(xy: FloatArray, spacing_m: float) -> tuple[IntArray, IntArray]:
    """Every pair of grid neighbours among the vertices (each pair once)."""
    cells = np.rint(xy / spacing_m - 0.5).astype(np.int64)
    if cells.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    cells -= cells.min(axis=0) - 1  # a free ring of cells around the vertices
    index = np.full(tuple(cells.max(axis=0) + 2), -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(cells.shape[0])
    a: list[IntArray] = []
    b: list[IntArray] = []
    for dx, dy in _OFFSETS[:4]:
        j = index[cells[:, 0] + dx, cells[:, 1] + dy]
        a.append(np.flatnonzero(j >= 0))
        b.append(j[j >= 0])
    return np.concatenate(a), np.concatenate(b)


def _from_links(
    xy: FloatArray, src: IntArray, dst: IntArray, kind: NDArray[np.int8], spacing_m: float
) -> FloorGraph:
    n = xy.shape[0]
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    deg = np.diff(indptr).astype(np.float64)
    return FloorGraph(
        spacing_m=spacing_m,
        xy=xy,
        kind=kind,
        indptr=indptr,
        indices=dst.astype(np.int64),
        move_p=1.0 / (deg[src] + 1.0),
        stay_p=1.0 / (deg + 1.0),
        rp_vertex=np.zeros(0, dtype=np.int64),
    )


def plan_graph(
    plan: FloorPlan,
    geojson: Mapping[str, Any] | None = None,
    spacing_m: float = SPACING_M,
) -> FloorGraph:
    """The graph of a floor plan (module docstring); ``geojson`` (the plan's features)
    marks door and link vertices."""
    ny, nx = plan.walkable.shape
    x0, y0 = plan.origin_m
    x1, y1 = x0 + nx * plan.cell_m, y0 + ny * plan.cell_m
    gx = (np.arange(math.floor(x0 / spacing_m), math.ceil(x1 / spacing_m)) + 0.5) * spacing_m
    gy = (np.arange(math.floor(y0 / spacing_m), math.ceil(y1 / spacing_m)) + 0.5) * spacing_m
    mesh = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    xy = mesh[walkable_at(plan, mesh)]
    if xy.shape[0] == 0:
        raise ValueError("the plan has no walkable grid point")
    a, b = grid_pairs(xy, spacing_m)
    linked = ~crosses_wall(plan, xy[a], xy[b])
    kind = _kinds(plan, xy, geojson, spacing_m)
    return grid_graph(xy, linked, kind, spacing_m)


def free_graph(points: FloatArray, spacing_m: float = SPACING_M) -> FloorGraph:
    """A graph without walls over the grid points within ``FREE_MARGIN_M`` of
    ``points``."""
    lo = np.floor((points.min(axis=0) - FREE_MARGIN_M) / spacing_m)
    hi = np.ceil((points.max(axis=0) + FREE_MARGIN_M) / spacing_m)
    gx = (np.arange(lo[0], hi[0]) + 0.5) * spacing_m
    gy = (np.arange(lo[1], hi[1]) + 0.5) * spacing_m
    xy = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    near, _ = cKDTree(points).query(xy, distance_upper_bound=FREE_MARGIN_M)
    xy = xy[np.isfinite(near)]
    a, _ = grid_pairs(xy, spacing_m)
    kind = np.full(xy.shape[0], DECISION, dtype=np.int8)
    return grid_graph(xy, np.ones(a.shape[0], dtype=bool), kind, spacing_m)


def _kinds(
    plan: FloorPlan, xy: FloatArray, geojson: Mapping[str, Any] | None, spacing_m: float
) -> NDArray[np.int8]:
    n = xy.shape[0]
    free = np.zeros((n, 8), dtype=bool)
    for k, (dx, dy) in enumerate(_OFFSETS):
        d = np.array([dx, dy], dtype=np.float64)
        end = xy + d / np.linalg.norm(d) * OPEN_RAY_M
        free[:, k] = walkable_at(plan, end) & ~crosses_wall(plan, xy, end)
    count = free.sum(axis=1)
    opposite = np.zeros(n, dtype=bool)
    for k in range(4):
        opposite |= free[:, k] & free[:, k + 4]
    kind = np.where((count == 2) & opposite, CORRIDOR, DECISION).astype(np.int8)
    for feature in (geojson or {}).get("features", []) or []:
        props = feature.get("properties") or {}
        name = props.get("kind")
        if name != "door" and name not in LINK_KINDS:
            continue
        try:
            shape = shapely.geometry.shape(feature.get("geometry"))
        except (AttributeError, TypeError, ValueError, shapely.errors.GeometryTypeError):
            continue
        area = shape.buffer(spacing_m * 0.75) if shape.area == 0 else shape
        x0, y0, x1, y1 = area.bounds
        box = np.flatnonzero(
            (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        )
        inside = box[shapely.contains_xy(area, xy[box, 0], xy[box, 1])]
        kind[inside] = DOOR if name == "door" else LINK
    return kind


def attach(graph: FloorGraph, radio: RadioMap | None, floor: int) -> FloorGraph:
    """The graph with the radio map's RPs of ``floor`` attached to their nearest vertex."""
    if radio is None:
        return replace(graph, rp_vertex=np.zeros(0, dtype=np.int64))
    rp_vertex = np.full(radio.rp_xy.shape[0], -1, dtype=np.int64)
    mine = np.flatnonzero(radio.rp_floor == floor)
    if mine.size:
        _, nearest = graph.tree.query(radio.rp_xy[mine].astype(np.float64))
        rp_vertex[mine] = nearest
    return replace(graph, rp_vertex=rp_vertex)


def learn(graph: FloorGraph, walks: Sequence[FloatArray]) -> FloorGraph:
    """The chain's moves counted over walks on the floor (module docstring, eq 15).

    Parameters
    ----------
    graph : FloorGraph
    walks : sequence of ndarray, shape (m, 2)
        Positions of each walk in time order (m, floor frame).
    """
    if graph.indices.shape[0] == 0:
        return graph
    tree = graph.tree
    key = np.repeat(np.arange(graph.n), graph.degree) * graph.n + graph.indices
    counts = np.zeros(graph.indices.shape[0])
    departures = np.zeros(graph.n)
    for walk in walks:
        walk = np.asarray(walk, dtype=np.float64)
        if walk.shape[0] < 2:
            continue
        _, visited = tree.query(_resampled(walk, graph.spacing_m / 2))
        visited = visited[np.r_[True, np.diff(visited) != 0]]
        if visited.size < 2:
            continue
        pairs = visited[:-1] * graph.n + visited[1:]
        at = np.searchsorted(key, pairs)
        at = np.minimum(at, key.shape[0] - 1)
        linked = key[at] == pairs  # moves between vertices that are not linked are dropped
        np.add.at(counts, at[linked], 1.0)
        np.add.at(departures, visited[:-1][linked], 1.0)
    deg = graph.degree.astype(np.float64)
    rows = np.repeat(np.arange(graph.n), graph.degree)
    share = deg / (deg + 1.0)  # what moving keeps of each row: staying keeps its 1/(deg+1)
    move_p = share[rows] * (counts + 1.0) / (departures + deg)[rows]
    return replace(graph, move_p=move_p)


def _resampled(walk: FloatArray, step_m: float) -> FloatArray:
    seg = np.linalg.norm(np.diff(walk, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return walk[:1]
    at = np.arange(0.0, s[-1] + step_m, step_m)
    at[-1] = min(at[-1], s[-1])
    return np.column_stack([np.interp(at, s, walk[:, 0]), np.interp(at, s, walk[:, 1])])


def site_graphs(
    plans: Sequence[FloorPlan | None],
    geojsons: Sequence[Mapping[str, Any] | None],
    radio: RadioMap | None,
    n_floors: int,
    walks: Mapping[int, Sequence[FloatArray]] | None = None,
    spacing_m: float = SPACING_M,
) -> tuple[FloorGraph | None, ...]:
    """Each floor's graph: from its plan, else a free grid over its reference points (None
    for a floor with neither), RPs attached, moves learned from ``walks`` (per floor)."""
    out: list[FloorGraph | None] = []
    for floor in range(n_floors):
        plan = plans[floor] if floor < len(plans) else None
        graph: FloorGraph | None = None
        if plan is not None:
            try:
                geo = geojsons[floor] if floor < len(geojsons) else None
                graph = plan_graph(plan, geo, spacing_m)
            except ValueError:
                graph = None
        if graph is None and radio is not None and np.any(radio.rp_floor == floor):
            graph = free_graph(radio.rp_xy[radio.rp_floor == floor].astype(np.float64), spacing_m)
        if graph is not None:
            graph = attach(graph, radio, floor)
            if walks and walks.get(floor):
                graph = learn(graph, walks[floor])
        out.append(graph)
    return tuple(out)
