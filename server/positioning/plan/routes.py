"""Routes over a site's routing graph (``routing_graph``): the cheapest way from a point
to a point or an area, as legs per floor joined by floor changes.

Search. Dijkstra's algorithm (``scipy.sparse.csgraph.dijkstra``, chosen over networkx
and rustworkx because the graphs are already SciPy sparse matrices, SciPy is a
dependency of the core, and its compiled search takes a whole floor's costs as arrays,
with no Python call per edge: the 17,000 vertices of the ILC mall's largest floor are
searched in about 5 ms) runs from the origin's vertex over its floor. When links leave
both ends' floors, it also runs from the destination's vertices over theirs (the floors'
graphs are symmetric, so that is the cost of reaching them), and the portal graph joins
the two: its nodes are the links' ends, the origin ``S`` (an edge to each portal of its
floor, at the cost of walking there) and the destination ``T`` (likewise). The cheapest
of the walk on the floor and the way through the portals wins. An area (a zone, a unit)
is reached at the first of its vertices the search meets: its nearest reachable border
point.

Shape. A leg's vertex path zig-zags on the grid; it is pulled straight
(string-pulling): from each kept point, the farthest later point of the path that it
sees is kept next, where seeing means a segment that crosses no wall, keeps, at each of
its samples, the clearance the path itself kept between the two points (at most
``CLEARANCE_GOAL_M``, less one raster cell), and costs no more than the path between them
(its metres penalised near walls as the graph's edges are, ``routing_graph``): a
straightened route is never nearer to a wall than the grid route was, nor does it leave
the middle of a corridor that the grid route kept to (a route from beside one wall of a
corridor to beside the other does not cross it on a long diagonal). Its length is what is
walked; its duration that length over the walking speed plus the links' seconds.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from shapely.geometry.base import BaseGeometry

from server.positioning.plan.floor_plan import crosses_wall, walkable_at
from server.positioning.plan.route_kernels import segment_profiles
from server.positioning.plan.routing_graph import (
    CLEARANCE_GOAL_M,
    LINK_REACH_M,
    SPACING_M,
    WALK_SPEED_M_S,
    WALL_PENALTY,
    FloorWalk,
    Link,
    RoutingGraph,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

POINT_REACH_M = 1.0
"""How far a point may lie from the walkable grid and still be in walkable space (m)."""

_PULL_CHUNK = 32  # later points tested at once when pulling a path straight
_SAMPLE_M = 0.5  # between the clearance samples of a segment
_NO_PRED = -9999  # scipy's predecessor of a source or an unreached vertex
_EPS_S = 1e-6  # added to every portal-graph cost: a zero cost would tie two portals apart


class NoRoute(ValueError):
    """No route: ``field`` names the end at fault (``origin``, ``destination``),
    ``reason`` says why."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


@dataclass(frozen=True, eq=False)
class Endpoint:
    """Where a route starts or ends: floor index, the vertices that will do (one for a
    point, those of an area for an area) and, for a point, the point itself."""

    floor: int
    vertices: IntArray
    xy: FloatArray | None = None


@dataclass(frozen=True)
class _Walk:
    """Vertices walked on one floor, in order."""

    floor: int
    vertices: list[int]


@dataclass(frozen=True, eq=False)
class Leg:
    """The walk on one floor: a polyline, shape (m, 2), floor metres."""

    floor: int
    xy: FloatArray

    @cached_property
    def length_m(self) -> float:
        return float(np.sum(np.linalg.norm(np.diff(self.xy, axis=0), axis=1)))


@dataclass(frozen=True)
class FloorChange:
    """A link taken between two legs (possibly several of one shaft in a row)."""

    kind: str
    name: str | None
    from_floor: int
    to_floor: int
    seconds: float


@dataclass(frozen=True, eq=False)
class Route:
    legs: tuple[Leg, ...]
    changes: tuple[FloorChange, ...]  # changes[k] joins legs[k] and legs[k + 1]

    @property
    def length_m(self) -> float:
        return sum(leg.length_m for leg in self.legs)

    @property
    def duration_s(self) -> float:
        return self.length_m / WALK_SPEED_M_S + sum(c.seconds for c in self.changes)


def _walk(graph: RoutingGraph, floor: int, field: str) -> FloorWalk:
    walk = graph.floors[floor] if 0 <= floor < len(graph.floors) else None
    if walk is None:
        raise NoRoute(field, "its floor has no plan with walkable space to route on")
    return walk


def point_endpoint(
    graph: RoutingGraph, floor: int, xy: Sequence[float], field: str, reach_m: float = 0.0
) -> Endpoint:
    """A point as a route's end: the nearest vertex it sees (no wall between). A point
    outside walkable space by more than ``POINT_REACH_M`` is refused; ``reach_m`` (a fix's
    uncertainty) lets a point that far from walkable space snap to its nearest vertex."""
    walk = _walk(graph, floor, field)
    point = np.asarray(xy, dtype=np.float64).reshape(2)
    if not np.all(np.isfinite(point)):
        raise NoRoute(field, "the point is not finite")
    limit = max(POINT_REACH_M, reach_m) + SPACING_M
    k = min(16, walk.n)
    dist, idx = walk.tree.query(point, k=k, distance_upper_bound=limit)
    found = np.atleast_1d(idx)[np.isfinite(np.atleast_1d(dist))]
    if found.size:
        clear = ~crosses_wall(
            walk.plan, np.repeat(point[None, :], found.size, axis=0), walk.xy[found]
        )
        if clear.any():
            return Endpoint(floor, found[clear][:1].astype(np.int64), point)
        if reach_m > 0:
            return Endpoint(floor, found[:1].astype(np.int64), walk.xy[found[0]].copy())
    inside = bool(walkable_at(walk.plan, point[None, :])[0])
    nearest = float(walk.tree.query(point)[0])
    where = "in a part of the plan cut off by walls" if inside else "outside walkable space"
    raise NoRoute(
        field,
        f"({point[0]:.2f}, {point[1]:.2f}) lies {where} (the nearest walkable point is "
        f"{nearest:.1f} m away)",
    )


def area_endpoint(
    graph: RoutingGraph,
    floor: int,
    shape: BaseGeometry,
    field: str,
    entrances: Sequence[Sequence[float]] = (),
) -> Endpoint:
    """An area as a route's end: its declared ``entrances`` (points) where it has them,
    else the vertices inside it, else those within ``LINK_REACH_M`` of its border (a
    shop the plan takes for an obstacle is reached at its front)."""
    walk = _walk(graph, floor, field)
    if entrances:
        vertices = [
            int(point_endpoint(graph, floor, e, f"{field}.entrances.{i}").vertices[0])
            for i, e in enumerate(entrances)
        ]
        return Endpoint(floor, np.unique(np.array(vertices, dtype=np.int64)))
    x0, y0, x1, y1 = shape.bounds
    r = LINK_REACH_M
    box = np.flatnonzero(
        (walk.xy[:, 0] >= x0 - r) & (walk.xy[:, 0] <= x1 + r)
        & (walk.xy[:, 1] >= y0 - r) & (walk.xy[:, 1] <= y1 + r)
    )  # fmt: skip
    if box.size:
        inside = box[shapely.intersects_xy(shape, walk.xy[box, 0], walk.xy[box, 1])]
        if inside.size:
            return Endpoint(floor, inside.astype(np.int64))
        near = box[shapely.distance(shape, shapely.points(walk.xy[box])) <= r]
        if near.size:
            return Endpoint(floor, near.astype(np.int64))
    raise NoRoute(field, f"no walkable space in it or within {r:g} m of its border")


def find_route(
    graph: RoutingGraph, origin: Endpoint, destination: Endpoint, accessible: bool = False
) -> Route:
    """The cheapest route (module docstring); NoRoute when the destination cannot be
    reached from the origin (``accessible``: by lifts, ramps and level ways only)."""
    start = _walk(graph, origin.floor, "origin")
    end = _walk(graph, destination.floor, "destination")
    src = int(origin.vertices[0])
    d_start, p_start = dijkstra(start.costs, indices=src, return_predecessors=True)
    direct, reached = math.inf, -1
    if destination.floor == origin.floor:
        costs = d_start[destination.vertices]
        best = int(np.argmin(costs))
        direct, reached = float(costs[best]), int(destination.vertices[best])
    found: list[tuple[float, list[_Walk | Link]]] = []
    if math.isfinite(direct):
        found.append((direct, [_Walk(origin.floor, _back(p_start, reached)[::-1])]))
    portals = graph.portals.of_floor
    if origin.floor in portals and destination.floor in portals:
        via = _through_portals(graph, origin, destination, d_start, p_start, end, accessible)
        if via is not None:
            found.append(via)
    if not found:
        raise _unreachable(origin, destination, accessible)
    return _route(graph, min(found, key=lambda f: f[0])[1], origin, destination)


def _back(pred: NDArray[np.int32], vertex: int) -> list[int]:
    """The vertices from ``vertex`` back to the search's source, following ``pred``."""
    out = [vertex]
    while pred[out[-1]] != _NO_PRED and pred[out[-1]] >= 0:
        out.append(int(pred[out[-1]]))
    return out


def _through_portals(
    graph: RoutingGraph,
    origin: Endpoint,
    destination: Endpoint,
    d_start: FloatArray,
    p_start: NDArray[np.int32],
    end: FloorWalk,
    accessible: bool,
) -> tuple[float, list[_Walk | Link]] | None:
    """The cheapest way through the links' portals and its cost; None when there is none."""
    portals = graph.portals
    starts = portals.of_floor[origin.floor]
    ends = portals.of_floor[destination.floor]
    d_end, p_end, _ = dijkstra(
        end.costs, indices=destination.vertices, return_predecessors=True, min_only=True
    )
    n = len(portals.nodes)
    s_node, t_node = n, n + 1
    rows, cols, cost, via = portals.edges
    if accessible:
        ok = np.array([v < 0 or graph.links[v].accessible for v in via.tolist()], dtype=bool)
        rows, cols, cost, via = rows[ok], cols[ok], cost[ok], via[ok]
    to_start = d_start[[portals.nodes[p][1] for p in starts]]
    to_end = d_end[[portals.nodes[p][1] for p in ends]]
    s_ok, t_ok = np.isfinite(to_start), np.isfinite(to_end)
    matrix = csr_matrix(
        (
            np.concatenate([cost, to_start[s_ok], to_end[t_ok]]) + _EPS_S,
            (
                np.concatenate([rows, np.full(int(s_ok.sum()), s_node), ends[t_ok]]),
                np.concatenate([cols, starts[s_ok], np.full(int(t_ok.sum()), t_node)]),
            ),
        ),
        shape=(n + 2, n + 2),
    )
    dist, pred = dijkstra(matrix, indices=s_node, return_predecessors=True)
    if not math.isfinite(dist[t_node]):
        return None
    path = _back(pred, t_node)[::-1][1:-1]  # the portals, in walking order
    via_of = {(int(p), int(q)): int(v) for p, q, v in zip(rows, cols, via, strict=True)}
    first_floor, first_vertex = portals.nodes[path[0]]
    chain: list[_Walk | Link] = [_Walk(first_floor, _back(p_start, first_vertex)[::-1])]
    for p, q in itertools.pairwise(path):
        link = via_of.get((p, q), -1)
        floor, vertex = portals.nodes[q]
        if link >= 0:
            chain += [graph.links[link], _Walk(floor, [vertex])]
            continue
        row = int(np.flatnonzero(portals.of_floor[floor] == p)[0])
        walked = _back(portals.walk_pred[floor][row], vertex)[::-1]
        chain[-1] = _Walk(floor, [*_walked(chain[-1]), *walked[1:]])
    last_floor, last_vertex = portals.nodes[path[-1]]
    tail = _back(p_end, last_vertex)  # walking order: the portal first
    chain[-1] = _Walk(last_floor, [*_walked(chain[-1]), *tail[1:]])
    return float(dist[t_node]), chain


def _walked(item: _Walk | Link) -> list[int]:
    assert isinstance(item, _Walk)  # a chain ends with a walk
    return item.vertices


def _unreachable(origin: Endpoint, destination: Endpoint, accessible: bool) -> NoRoute:
    if origin.floor == destination.floor:
        why = "the destination is cut off from the origin by walls on its floor"
    else:
        why = "no stairs, lift, escalator or ramp joins the origin's part of the building to it"
        if accessible:
            why = "no lift or ramp (accessible: no stairs or escalators) joins it to the origin"
    return NoRoute("destination", why)


def _route(
    graph: RoutingGraph, chain: list[_Walk | Link], origin: Endpoint, destination: Endpoint
) -> Route:
    legs: list[Leg] = []
    changes: list[FloorChange] = []
    for k, item in enumerate(chain):
        if isinstance(item, Link):
            after = chain[k + 1]
            assert isinstance(after, _Walk)  # a link leads to a walk
            changes.append(
                FloorChange(item.kind, item.name, legs[-1].floor, after.floor, item.seconds)
            )
            continue
        walk = graph.floors[item.floor]
        assert walk is not None
        xy = walk.xy[np.asarray(item.vertices, dtype=np.int64)]
        if k == 0 and origin.xy is not None:
            xy = np.vstack([origin.xy[None, :], xy])
        if k == len(chain) - 1 and destination.xy is not None:
            xy = np.vstack([xy, destination.xy[None, :]])
        legs.append(Leg(item.floor, pulled_straight(walk, xy)))
    return _merged(Route(tuple(legs), tuple(changes)))


def _merged(route: Route) -> Route:
    """Runs of one shaft (stairs up two levels: two links through a leg of one point)
    as one change."""
    legs = [route.legs[0]]
    changes: list[FloorChange] = []
    for change, leg in zip(route.changes, route.legs[1:], strict=True):
        prev = changes[-1] if changes else None
        if (
            prev is not None
            and legs[-1].length_m == 0.0
            and prev.kind == change.kind
            and prev.name == change.name
        ):
            legs[-1] = leg
            changes[-1] = FloorChange(
                change.kind, change.name, prev.from_floor, change.to_floor,
                prev.seconds + change.seconds,
            )  # fmt: skip
            continue
        legs.append(leg)
        changes.append(change)
    return Route(tuple(legs), tuple(changes))


def pulled_straight(walk: FloorWalk, xy: FloatArray) -> FloatArray:
    """A vertex path pulled straight (module docstring), shape (k, 2), its first and last
    points kept."""
    xy = _deduplicated(xy)
    if xy.shape[0] <= 2:
        return xy
    clear = np.minimum(walk.clearance_at(xy), CLEARANCE_GOAL_M) - walk.plan.cell_m
    walked = np.concatenate([[0.0], np.cumsum(_profile(walk, xy[:-1], xy[1:])[1])])
    # only the corners of the grid path can be kept: the points between them are in line
    heading = np.diff(xy, axis=0)
    heading /= np.linalg.norm(heading, axis=1)[:, None]
    bends = np.flatnonzero(np.any(np.abs(np.diff(heading, axis=0)) > 1e-9, axis=1)) + 1
    corner = np.concatenate([[0], bends, [xy.shape[0] - 1]])
    m = corner.shape[0]
    keep = [0]
    i = 0
    while i < m - 1:
        best, j0, chunk = i + 1, i + 2, 4
        while j0 < m:
            js = np.arange(j0, min(m, j0 + chunk))
            chunk = min(2 * chunk, _PULL_CHUNK)  # most runs end near: test a few first
            ok = _sees(walk, xy, clear, walked, corner[i], corner[js])
            if ok.all():
                best, j0 = int(js[-1]), int(js[-1]) + 1
                continue
            bad = int(np.argmin(ok))
            if bad > 0:
                best = int(js[bad - 1])
            break
        keep.append(best)
        i = best
    out: FloatArray = xy[corner[keep]]
    return out


def _deduplicated(xy: FloatArray) -> FloatArray:
    if xy.shape[0] < 2:
        return xy
    moved = np.r_[True, np.any(np.diff(xy, axis=0) != 0.0, axis=1)]
    return xy[moved]


def _profile(walk: FloorWalk, a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The segments ``a -> b`` (shapes (m, 2)): their lowest clearance, and their lengths
    penalised near walls as the graph's edges are (``FloorWalk.penalty_at`` averaged over
    samples ``_SAMPLE_M`` apart; ``route_kernels``)."""
    plan = walk.plan
    low, mean = segment_profiles(
        a, b, walk.clearance_raster, walk.penalty_raster, float(plan.origin_m[0]),
        float(plan.origin_m[1]), float(plan.cell_m), _SAMPLE_M, WALL_PENALTY,
    )  # fmt: skip
    penalised: FloatArray = np.linalg.norm(b - a, axis=1) * (1.0 + mean)
    return low, penalised


def _sees(
    walk: FloorWalk,
    xy: FloatArray,
    clear: FloatArray,
    walked: FloatArray,
    i: int,
    js: NDArray[np.int64],
) -> NDArray[np.bool_]:
    """Whether the segments ``xy[i] -> xy[js]`` cross no wall, keep the clearance the path
    kept between their ends (``clear``: its lowest there) and cost no more than the path
    did (``walked``: its penalised metres so far)."""
    a = np.repeat(xy[i][None, :], js.size, axis=0)
    ok: NDArray[np.bool_] = ~crosses_wall(walk.plan, a, xy[js])
    low, penalised = _profile(walk, a, xy[js])
    need = np.minimum.accumulate(clear[i : js[-1] + 1])[js - i]
    ok &= (low >= need) & (penalised <= walked[js] - walked[i])
    return ok
