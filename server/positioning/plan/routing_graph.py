"""A site's routing graph: each floor's walkable space as a weighted graph, and the links
between floors (stairs, lifts, escalators, ramps, IMDF ``traversal`` relationships).

Floors. The vertices of a floor are the points of a square grid of side ``SPACING_M``
that lie in its plan's walkable raster (``floor_plan``); two grid neighbours (the 8
around a point) are joined when the segment between them meets no wall, so a wall is
crossed only where a door cut a gap in it (``geojson_plan``). An edge costs the seconds
it takes to walk, made dearer near walls so that routes keep a clearance where the space
allows it::

    cost(a, b) = |b - a| / v * (1 + k * (p(a) + p(b)) / 2),
    p = max(0, 1 - c / min(c_goal, c_near))

with ``v = WALK_SPEED_M_S``, ``c`` a point's distance to the nearest wall or edge of the
walkable area (a Euclidean distance transform of the raster with the walls drawn into
it), ``c_near`` the largest ``c`` within ``c_goal`` of the point (a square window: the
clearance the space around allows), ``c_goal = CLEARANCE_GOAL_M`` and ``k =
WALL_PENALTY``. In a corridor up to ``2 c_goal`` wide the cheapest line runs down its
middle (where ``p = 0``); in a hall, at least ``c_goal`` from the walls. A narrow
passage costs nothing extra along its middle, so the penalty moves a route across a
corridor but hardly ever sends it round by another way. Durations of a route are its
walked metres over ``v``: the penalty only chooses the line.

Links. A plan marks where a walk may leave its floor with ``"stairs"``, ``"elevator"``
and ``"escalator"`` areas (``geojson_format``: the IMDF units of those categories too).
Within a building, the same feature on two levels is one shaft: matched by the
feature's ``id``, else its ``name``, else by footprints of the same kind that overlap
(by at least ``OVERLAP_SHARE`` of the smaller) in the building's frame. Stairs and
escalators join consecutive levels of their shaft; a lift joins every pair of its
levels, so its wait is paid once per ride. IMDF ``relationship`` features of category
``traversal`` (or ``stairs``, ``elevator``, ``escalator``, ``ramp``) join the features
their ``origin`` and ``destination`` name, anywhere in the site, one way when their
``direction`` is ``"directed"``; the kind is the category, or the intermediary's kind for
a traversal through a stairs or lift unit. A link's cost is time, by kind and levels
(``LINK_SECONDS``); ``accessible`` routes use lifts, ramps and level traversals only.

Search. Floors are searched one at a time with Dijkstra's algorithm
(``scipy.sparse.csgraph.dijkstra``), and floors are joined through a small graph of the
links' end vertices ("portals") whose edges are the links and, within each floor, the
cheapest walk between its portals (computed once, with the predecessors that give the
walk back): a route query runs Dijkstra on the origin's floor, on the destination's floor
when the route may change floors, and on the portal graph (``routes``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree
from shapely.geometry.base import BaseGeometry

from server.positioning.plan.floor_plan import FloorPlan, crosses_wall, walkable_at
from server.positioning.plan.geojson_format import DOOR_KINDS, feature_kind, text
from server.positioning.plan.navigation_graph import grid_pairs
from server.positioning.plan.zones import feature_name

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

LAYOUT = 1
"""The version of how a graph is built: part of its digest (``RoutingGraph.digest``), so
that vertex ids kept by a session are read only by a graph built the same way."""

SPACING_M = 1.0
"""Grid side (m). A floor of 17,000 m² (the largest of the ILC mall's) has 17,000
vertices, searched in about 5 ms; at 0.5 m it would take 22 ms. A door narrower than the
grid may have no grid link through it: each door has a vertex of its own (``DOOR_REACH_M``)."""

DOOR_REACH_M = 1.6
"""A door's vertex is joined to the grid vertices this near that it sees (m)."""

WALK_SPEED_M_S = 1.2
"""Walking speed indoors (m/s), for durations and edge costs."""

CLEARANCE_GOAL_M = 1.2
"""Distance from walls (m) beyond which a vertex costs no more than open space."""

WALL_PENALTY = 0.5
"""How much dearer a metre is right at a wall than where the space around allows. On
536 pairs of points over the nine floors of the ILC mall, routes are then 0.993 times
the length of a fine grid's shortest walk at the median, 1.025 at the 95th percentile
(1.047 with 1.0, 1.061 with 2.0; ``tests/positioning/plan/test_routes.py``)."""

OVERLAP_SHARE = 0.25
"""Share of the smaller footprint two link features of adjacent levels must overlap."""

SHAFT_REACH_M = 10.0
"""How far apart (m) the features of one shaft on adjacent levels may lie when they are
matched by id or name."""

LINK_REACH_M = 2.0
"""How far from a link feature (or a place) its end vertex may lie (m)."""

STAIRS, ELEVATOR, ESCALATOR, RAMP, TRAVERSAL = (
    "stairs", "elevator", "escalator", "ramp", "traversal",
)  # fmt: skip
LINK_KINDS = (STAIRS, ELEVATOR, ESCALATOR)

LINK_SECONDS: Mapping[str, tuple[float, float]] = {
    STAIRS: (5.0, 15.0),  # (fixed, per level): a flight of about 20 steps
    ESCALATOR: (5.0, 20.0),  # boarding, then about 8 m of incline at 0.5 m/s
    ELEVATOR: (30.0, 4.0),  # the wait for the car, then the ride
    RAMP: (5.0, 30.0),
    TRAVERSAL: (5.0, 15.0),
}
"""A link's seconds: ``fixed + per_level * |levels|`` (a traversal on one level: its
straight-line length walked, plus ``fixed``)."""

RELATIONSHIP_CATEGORIES = frozenset({TRAVERSAL, "traversal.path", *LINK_KINDS, RAMP})


@dataclass(frozen=True, eq=False)
class FloorWalk:
    """One floor's walking graph.

    Attributes
    ----------
    floor : int
        Index into the site's floors.
    level, building_id :
        The floor's level and building.
    plan : FloorPlan
    xy : ndarray, shape (n, 2)
        Vertex positions (m, floor frame).
    clearance_m : ndarray, shape (n,)
        Each vertex's distance to the nearest wall or edge of the walkable area.
    costs : csr_matrix, shape (n, n)
        Seconds of each edge, penalised near walls (module docstring); symmetric.
    clearance_raster : ndarray, shape (ny, nx), float32
        The clearance of every cell of the plan's raster (0 where not walkable).
    penalty_raster : ndarray, shape (ny, nx), float32
        ``k p`` of the module docstring for every cell.
    """

    floor: int
    level: int
    building_id: str
    plan: FloorPlan
    xy: FloatArray
    clearance_m: FloatArray
    costs: csr_matrix
    clearance_raster: NDArray[np.float32] = field(repr=False)
    penalty_raster: NDArray[np.float32] = field(repr=False)

    @cached_property
    def tree(self) -> cKDTree:
        return cKDTree(self.xy)

    @property
    def n(self) -> int:
        return int(self.xy.shape[0])

    def clearance_at(self, xy: FloatArray) -> FloatArray:
        """The raster's clearance at points, shape (m,) (0 outside the raster)."""
        return _raster_at(self.plan, self.clearance_raster, xy, 0.0)

    def penalty_at(self, xy: FloatArray) -> FloatArray:
        """``k p`` at points, shape (m,) (``k`` outside the raster)."""
        return _raster_at(self.plan, self.penalty_raster, xy, WALL_PENALTY)

    @property
    def nbytes(self) -> int:
        c = self.costs
        return int(
            self.xy.nbytes + self.clearance_m.nbytes + c.data.nbytes + c.indices.nbytes
            + c.indptr.nbytes + self.clearance_raster.nbytes + self.penalty_raster.nbytes
        )  # fmt: skip


def _raster_at(
    plan: FloorPlan, raster: NDArray[np.float32], xy: FloatArray, outside: float
) -> FloatArray:
    ny, nx = raster.shape
    ix = np.floor((xy[:, 0] - plan.origin_m[0]) / plan.cell_m).astype(np.int64)
    iy = np.floor((xy[:, 1] - plan.origin_m[1]) / plan.cell_m).astype(np.int64)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    out = np.full(xy.shape[0], outside)
    out[inside] = raster[iy[inside], ix[inside]]
    return out


@dataclass(frozen=True)
class Link:
    """A way between two vertices that is not a walk on a floor: ``a`` and ``b`` are
    ``(floor, vertex)``; ``directed`` links go from ``a`` to ``b`` only."""

    kind: str
    name: str | None
    a: tuple[int, int]
    b: tuple[int, int]
    seconds: float
    directed: bool = False
    level_change: bool = True  # between two levels (a traversal may stay on one)

    @property
    def accessible(self) -> bool:
        """Taken by accessible routes: a lift, a ramp, a way through on one level."""
        return self.kind in (ELEVATOR, RAMP) or (self.kind == TRAVERSAL and not self.level_change)


@dataclass(frozen=True)
class Place:
    """A named place of a plan (a unit, an amenity, an anchor, a ``"poi"``): a point or
    an area of floor ``floor``."""

    id: str
    name: str
    floor: int
    shape: BaseGeometry = field(repr=False)
    category: str | None = None


@dataclass(frozen=True, eq=False)
class Portals:
    """The links' end vertices and the walks between them.

    ``nodes[i] = (floor, vertex)``; ``walk_pred[floor]`` holds, for the portals of that
    floor (rows in the order of ``of_floor[floor]``), Dijkstra's predecessors over the
    floor's vertices; ``edges`` the portal graph as (from, to, seconds, link index or -1
    for a walk), each pair once with its cheapest way."""

    nodes: tuple[tuple[int, int], ...]
    of_floor: Mapping[int, IntArray]
    walk_pred: Mapping[int, NDArray[np.int32]]
    edges: tuple[IntArray, IntArray, FloatArray, IntArray]

    @cached_property
    def index(self) -> dict[tuple[int, int], int]:
        return {node: i for i, node in enumerate(self.nodes)}


@dataclass(frozen=True, eq=False)
class RoutingGraph:
    """A site's routing graph (module docstring): per floor index its walking graph
    (None for a floor without a plan), the links, the named places and the portals."""

    floors: tuple[FloorWalk | None, ...]
    links: tuple[Link, ...]
    places: tuple[Place, ...]
    portals: Portals
    digest: str = ""

    @property
    def nbytes(self) -> int:
        floors = sum(f.nbytes for f in self.floors if f is not None)
        return floors + sum(p.nbytes for p in self.portals.walk_pred.values())


def floor_walk(
    plan: FloorPlan,
    floor: int,
    level: int,
    building_id: str,
    doors: Sequence[BaseGeometry] = (),
) -> FloorWalk | None:
    """The walking graph of one floor's plan (None when no grid point is walkable), with a
    vertex at the middle of each of ``doors``."""
    ny, nx = plan.walkable.shape
    x0, y0 = plan.origin_m
    s = SPACING_M
    gx = (np.arange(math.floor(x0 / s), math.ceil((x0 + nx * plan.cell_m) / s)) + 0.5) * s
    gy = (np.arange(math.floor(y0 / s), math.ceil((y0 + ny * plan.cell_m) / s)) + 0.5) * s
    mesh = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    grid = mesh[walkable_at(plan, mesh)]
    if grid.shape[0] == 0:
        return None
    a, b = grid_pairs(grid, s)
    middles = [d.centroid for d in doors if not d.is_empty]
    xy = np.vstack([grid, np.array([(p.x, p.y) for p in middles]).reshape(-1, 2)])
    if middles:
        near = cKDTree(grid).query_ball_point(xy[grid.shape[0] :], DOOR_REACH_M)
        a = np.concatenate([a, *(np.full(len(m), grid.shape[0] + k) for k, m in enumerate(near))])
        b = np.concatenate([b, *(np.asarray(m, dtype=np.int64) for m in near)])
    keep = ~crosses_wall(plan, xy[a], xy[b])
    a, b = a[keep].astype(np.int64), b[keep].astype(np.int64)
    raster = clearance_raster(plan)
    penalties = penalty_raster(raster, plan.cell_m)
    clearance = _raster_at(plan, raster, xy, 0.0)
    penalty = _raster_at(plan, penalties, xy, WALL_PENALTY)
    seconds = np.linalg.norm(xy[b] - xy[a], axis=1) / WALK_SPEED_M_S
    seconds *= 1.0 + (penalty[a] + penalty[b]) / 2.0
    n = xy.shape[0]
    costs = csr_matrix(
        (np.concatenate([seconds, seconds]), (np.concatenate([a, b]), np.concatenate([b, a]))),
        shape=(n, n),
    )
    return FloorWalk(floor, level, building_id, plan, xy, clearance, costs, raster, penalties)


def penalty_raster(clearance: NDArray[np.float32], cell_m: float) -> NDArray[np.float32]:
    """``k p`` of the module docstring for every cell of a clearance raster."""
    reach = 2 * round(CLEARANCE_GOAL_M / cell_m) + 1
    near = ndimage.maximum_filter(clearance, size=reach, mode="constant", cval=0.0)
    room = np.maximum(np.minimum(near, CLEARANCE_GOAL_M), 1e-6)
    penalty = WALL_PENALTY * np.maximum(0.0, 1.0 - clearance / room)
    return np.asarray(penalty, dtype=np.float32)


def clearance_raster(plan: FloorPlan) -> NDArray[np.float32]:
    """Per raster cell, the distance (m) from its centre to the nearest cell that is not
    walkable or that a wall runs through (0 for those)."""
    blocked = ~plan.walkable
    walls = plan.walls
    if walls.shape[0]:
        length = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
        count = np.maximum(2, np.ceil(length / (plan.cell_m / 2)).astype(np.int64) + 1)
        seg = np.repeat(np.arange(walls.shape[0]), count)
        start = np.cumsum(count) - count
        t = (np.arange(seg.shape[0]) - start[seg]) / (count[seg] - 1)
        px = walls[seg, 0] + t * (walls[seg, 2] - walls[seg, 0])
        py = walls[seg, 1] + t * (walls[seg, 3] - walls[seg, 1])
        ix = np.floor((px - plan.origin_m[0]) / plan.cell_m).astype(np.int64)
        iy = np.floor((py - plan.origin_m[1]) / plan.cell_m).astype(np.int64)
        ny, nx = blocked.shape
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        blocked = blocked.copy()
        blocked[iy[ok], ix[ok]] = True
    # beyond the raster nothing is walkable: a border of blocked cells, or the EDT would
    # measure from the blocked cells inside only (no wall along the raster's far edges)
    open_ = np.pad(~blocked, 1, constant_values=False)
    distance = ndimage.distance_transform_edt(open_)[1:-1, 1:-1] * plan.cell_m
    return np.asarray(np.maximum(distance - plan.cell_m / 2, 0.0), dtype=np.float32)


@dataclass(frozen=True)
class FloorInput:
    """What the routing graph reads of one floor of the site."""

    building_id: str
    level: int
    plan: FloorPlan | None
    geojson: Mapping[str, Any] | None


def routing_graph(floors: Sequence[FloorInput], digest: str = "") -> RoutingGraph:
    """The site's routing graph (module docstring); ``floors`` in the site's floor order."""
    features = [_features(f.geojson) for f in floors]
    walks = tuple(
        floor_walk(f.plan, i, f.level, f.building_id, _doors(features[i]))
        if f.plan is not None
        else None
        for i, f in enumerate(floors)
    )
    links = [*_shaft_links(floors, walks, features), *_relationship_links(floors, walks, features)]
    places = tuple(p for i, found in enumerate(features) for p in _places(i, found))
    return RoutingGraph(walks, tuple(links), places, _portals(walks, links), digest)


# ---------------------------------------------------------------- links


@dataclass(frozen=True)
class _Feature:
    id: str | None
    name: str | None
    kind: str | None
    feature_type: str | None
    category: str | None
    properties: Mapping[str, Any]
    shape: BaseGeometry | None


def _features(geojson: Mapping[str, Any] | None) -> list[_Feature]:
    out = []
    for feature in (geojson or {}).get("features") or ():
        if not isinstance(feature, Mapping):
            continue
        properties = feature.get("properties")
        properties = properties if isinstance(properties, Mapping) else {}
        raw_id = feature.get("id", properties.get("id"))
        try:
            geometry = feature.get("geometry")
            shape = (
                shapely.geometry.shape(dict(geometry)) if isinstance(geometry, Mapping) else None
            )
            if shape is not None and (shape.is_empty or not shape.is_valid):
                shape = shapely.make_valid(shape) if not shape.is_empty else None
        except (KeyError, TypeError, ValueError, AttributeError, shapely.errors.ShapelyError):
            shape = None
        feature_type = text(feature.get("feature_type", properties.get("feature_type")))
        out.append(
            _Feature(
                id=str(raw_id) if isinstance(raw_id, str | int) else None,
                name=feature_name(properties),
                kind=feature_kind(feature),
                feature_type=feature_type,
                category=text(properties.get("category")),
                properties=properties,
                shape=shape,
            )
        )
    return out


def _doors(features: Sequence[_Feature]) -> list[BaseGeometry]:
    return [f.shape for f in features if f.kind in DOOR_KINDS and f.shape is not None]


def end_vertex(walk: FloorWalk, shape: BaseGeometry, reach_m: float = LINK_REACH_M) -> int | None:
    """The vertex that stands for a feature: the one inside it nearest its representative
    point, else the nearest within ``reach_m`` of it (None: no vertex that close)."""
    xy = shapely.get_coordinates(shape.representative_point())[0]
    x0, y0, x1, y1 = shape.bounds
    box = np.flatnonzero(
        (walk.xy[:, 0] >= x0 - reach_m) & (walk.xy[:, 0] <= x1 + reach_m)
        & (walk.xy[:, 1] >= y0 - reach_m) & (walk.xy[:, 1] <= y1 + reach_m)
    )  # fmt: skip
    if box.size == 0:
        return None
    if shapely.get_dimensions(shape) == 2:
        inside = box[shapely.contains_xy(shape, walk.xy[box, 0], walk.xy[box, 1])]
        if inside.size:
            return int(inside[np.argmin(np.sum((walk.xy[inside] - xy) ** 2, axis=1))])
    gap = np.asarray(shapely.distance(shape, shapely.points(walk.xy[box])), dtype=np.float64)
    best = int(np.argmin(gap))
    return int(box[best]) if gap[best] <= reach_m else None


def link_seconds(kind: str, levels: int, metres: float = 0.0) -> float:
    fixed, per_level = LINK_SECONDS.get(kind, LINK_SECONDS[TRAVERSAL])
    return fixed + per_level * abs(levels) + metres / WALK_SPEED_M_S


def _shaft_links(
    floors: Sequence[FloorInput],
    walks: Sequence[FloorWalk | None],
    features: Sequence[list[_Feature]],
) -> list[Link]:
    """Links of the same stairs, lift or escalator on several levels (module docstring)."""
    ends: list[_End] = []
    for i, found in enumerate(features):
        walk = walks[i]
        if walk is None:
            continue
        for f in found:
            if f.kind in LINK_KINDS and f.shape is not None:
                vertex = end_vertex(walk, f.shape)
                if vertex is not None:
                    ends.append((i, f, vertex))
    groups: list[list[_End]] = []
    left = ends
    for key in (lambda f: f.id, lambda f: f.name):  # by id, then by name
        shafts, left = _keyed(floors, left, key)
        groups += shafts
    groups += _overlapping(floors, left)
    links = []
    for group in groups:
        by_level = sorted(group, key=lambda e: floors[e[0]].level)
        kind = by_level[0][1].kind or STAIRS
        name = next((e[1].name for e in by_level if e[1].name), None)
        pairs = (
            [(p, q) for k, p in enumerate(by_level) for q in by_level[k + 1 :]]
            if kind == ELEVATOR
            else list(itertools.pairwise(by_level))
        )
        for p, q in pairs:
            levels = floors[q[0]].level - floors[p[0]].level
            links.append(Link(kind, name, (p[0], p[2]), (q[0], q[2]), link_seconds(kind, levels)))
    return links


_End = tuple[int, "_Feature", int]  # floor, feature, vertex


def _keyed(
    floors: Sequence[FloorInput], ends: list[_End], key: Callable[[_Feature], str | None]
) -> tuple[list[list[_End]], list[_End]]:
    """Shafts of features that share a ``key`` (an id, a name) in a building, one feature
    a floor on two floors or more, each within ``SHAFT_REACH_M`` of the one a level below
    it; and the ends left over (a generic name on several features of a floor, ids
    numbered per floor, a name far from its namesake: matched by footprint instead)."""
    by_key: dict[tuple[str, str, str], list[_End]] = {}
    for end in ends:
        value = key(end[1])
        if value is not None:
            by_key.setdefault((floors[end[0]].building_id, end[1].kind or "", value), []).append(
                end
            )
    groups, used = [], set()
    for group in by_key.values():
        on = [e[0] for e in group]
        if len(set(on)) < 2 or len(set(on)) != len(on):
            continue
        by_level = sorted(group, key=lambda e: floors[e[0]].level)
        if all(
            p[1].shape is not None and q[1].shape is not None
            and p[1].shape.distance(q[1].shape) <= SHAFT_REACH_M
            for p, q in itertools.pairwise(by_level)
        ):  # fmt: skip
            groups.append(group)
            used |= {id(e) for e in group}
    return groups, [e for e in ends if id(e) not in used]


def _overlapping(floors: Sequence[FloorInput], ends: list[_End]) -> list[list[_End]]:
    """Shafts of the features left: same kind, same building, adjacent levels of it,
    footprints that overlap by ``OVERLAP_SHARE`` of the smaller (found with a spatial tree,
    joined by union-find)."""
    if len(ends) < 2:
        return []
    order: dict[str, list[int]] = {}
    for floor in floors:
        order.setdefault(floor.building_id, []).append(floor.level)
    rank = {b: {lvl: k for k, lvl in enumerate(sorted(set(v)))} for b, v in order.items()}
    shapes = [e[1].shape if e[1].shape is not None else shapely.Point() for e in ends]
    parent = list(range(len(ends)))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    tree = shapely.STRtree(shapes)
    for a, b in zip(*tree.query(shapes, predicate="intersects"), strict=True):
        (i, f, _), (j, e, _) = ends[a], ends[b]
        building = floors[i].building_id
        if a >= b or f.kind != e.kind or building != floors[j].building_id:
            continue
        if abs(rank[building][floors[i].level] - rank[building][floors[j].level]) != 1:
            continue
        smaller = min(shapes[a].area, shapes[b].area)
        if smaller > 0 and shapes[a].intersection(shapes[b]).area >= OVERLAP_SHARE * smaller:
            parent[root(a)] = root(b)
    groups: dict[int, list[_End]] = {}
    for k, end in enumerate(ends):
        groups.setdefault(root(k), []).append(end)
    return [g for g in groups.values() if len({e[0] for e in g}) > 1]


def _relationship_links(
    floors: Sequence[FloorInput],
    walks: Sequence[FloorWalk | None],
    features: Sequence[list[_Feature]],
) -> list[Link]:
    """Links of IMDF ``relationship`` features (module docstring)."""
    by_id: dict[str, tuple[int, _Feature]] = {}
    for i, found in enumerate(features):
        for f in found:
            if f.id is not None and f.feature_type != "relationship":
                by_id.setdefault(f.id, (i, f))
    links = []
    for found in features:
        for rel in found:
            if rel.feature_type != "relationship" or rel.category not in RELATIONSHIP_CATEGORIES:
                continue
            ends = [_referenced(rel.properties.get(k), by_id) for k in ("origin", "destination")]
            origin, destination = ends
            if origin is None or destination is None:
                continue
            (fa, a), (fb, b) = origin, destination
            wa, wb = walks[fa], walks[fb]
            if wa is None or wb is None or a.shape is None or b.shape is None:
                continue
            va, vb = end_vertex(wa, a.shape), end_vertex(wb, b.shape)
            if va is None or vb is None:
                continue
            kind = _relationship_kind(rel, by_id)
            levels = floors[fb].level - floors[fa].level
            metres = float(np.linalg.norm(wa.xy[va] - wb.xy[vb])) if fa == fb else 0.0
            name = rel.name or next((f.name for f in _intermediaries(rel, by_id) if f.name), None)
            directed = rel.properties.get("direction") == "directed"
            links.append(
                Link(
                    kind,
                    name,
                    (fa, va),
                    (fb, vb),
                    link_seconds(kind, levels, metres),
                    directed,
                    level_change=levels != 0,
                )
            )
    return links


def _referenced(ref: Any, by_id: Mapping[str, tuple[int, _Feature]]) -> tuple[int, _Feature] | None:
    if isinstance(ref, Mapping):
        ref = ref.get("id")
    return by_id.get(str(ref)) if isinstance(ref, str | int) else None


def _intermediaries(rel: _Feature, by_id: Mapping[str, tuple[int, _Feature]]) -> list[_Feature]:
    raw = rel.properties.get("intermediary")
    refs = raw if isinstance(raw, list) else [raw] if raw is not None else []
    return [found[1] for r in refs if (found := _referenced(r, by_id)) is not None]


def _relationship_kind(rel: _Feature, by_id: Mapping[str, tuple[int, _Feature]]) -> str:
    if rel.category in (*LINK_KINDS, RAMP):
        return rel.category or TRAVERSAL
    for f in _intermediaries(rel, by_id):
        if f.kind in LINK_KINDS:
            return f.kind or TRAVERSAL
        if f.category == RAMP:
            return RAMP
    return TRAVERSAL


# ---------------------------------------------------------------- places


PLACE_FEATURE_TYPES = frozenset({"unit", "amenity", "anchor", "occupant"})
POI_KIND = "poi"


def _places(floor: int, features: Sequence[_Feature]) -> list[Place]:
    """The named places of a floor: IMDF units, amenities and anchors with a name, and
    ``"poi"`` features."""
    out = []
    for k, f in enumerate(features):
        if f.shape is None or f.name is None:
            continue
        if f.kind != POI_KIND and f.feature_type not in PLACE_FEATURE_TYPES:
            continue
        out.append(Place(f.id or f"{floor}.{k}", f.name, floor, f.shape, f.category))
    return out


# ---------------------------------------------------------------- portals


def _portals(walks: Sequence[FloorWalk | None], links: Sequence[Link]) -> Portals:
    nodes = sorted({end for link in links for end in (link.a, link.b)})
    index = {node: i for i, node in enumerate(nodes)}
    of_floor: dict[int, IntArray] = {}
    for i, (floor, _) in enumerate(nodes):
        of_floor.setdefault(floor, np.zeros(0, dtype=np.int64))
        of_floor[floor] = np.append(of_floor[floor], i)
    best: dict[tuple[int, int], tuple[float, int]] = {}

    def offer(p: int, q: int, seconds: float, via: int) -> None:
        if math.isfinite(seconds) and ((p, q) not in best or seconds < best[(p, q)][0]):
            best[(p, q)] = (seconds, via)

    walk_pred: dict[int, NDArray[np.int32]] = {}
    for floor, members in of_floor.items():
        walk = walks[floor]
        assert walk is not None  # links end on floors with a walking graph
        vertices = [nodes[m][1] for m in members]
        dist, pred = dijkstra(walk.costs, indices=vertices, return_predecessors=True)
        walk_pred[floor] = pred.astype(np.int32)
        for r, p in enumerate(members):
            for q, v in zip(members, vertices, strict=True):
                if p != q and math.isfinite(dist[r, v]):
                    offer(int(p), int(q), float(dist[r, v]), -1)
    for k, link in enumerate(links):
        offer(index[link.a], index[link.b], link.seconds, k)
        if not link.directed:
            offer(index[link.b], index[link.a], link.seconds, k)
    pairs = list(best.items())
    edges = (
        np.array([p for (p, _), _ in pairs], dtype=np.int64),
        np.array([q for (_, q), _ in pairs], dtype=np.int64),
        np.array([c for _, (c, _) in pairs], dtype=np.float64),
        np.array([v for _, (_, v) in pairs], dtype=np.int64),
    )
    return Portals(tuple(nodes), of_floor, walk_pred, edges)
