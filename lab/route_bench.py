"""How long a site's routing graph takes to build, how much memory it holds, and what a
route query costs (``indoorpos bench routes``).

Measured in one process, on the site's floor plans as the service reads them
(``geojson_plan.plan_from_geojson`` of each floor's GeoJSON), through the functions the
service calls:

* **Build.** ``routing_graph.routing_graph`` of the whole site (``build_s``; its links,
  portals and memory, ``RoutingGraph.nbytes``), and of each floor on its own: the walking
  graph's build time (``build_s``, the floor's plan features read, its grid, wall tests and
  clearance), vertices, edges (each undirected edge once) and memory (``FloorWalk.nbytes``).
  A build of the smallest floor runs first, untimed, so no figure pays for first calls.
  ``build_peak_mb`` is the peak of Python's allocations (``tracemalloc``, which numpy
  reports its arrays to) during a second, untimed build of the whole site: what building
  the graph needs beyond what the process already held.
* **Queries.** ``queries`` pairs of walkable vertices (their positions), drawn with the
  seed: a share ``cross_share`` of them between two different floors (both drawn at
  random), the others both on the largest floor (the most vertices). Each is timed
  (``time.perf_counter``) as the core serves a route request: ``routes.point_endpoint``
  for both ends, then ``routes.find_route``. A query that raises ``NoRoute`` (no stairs or
  lift joins the floors, or walls cut the two points apart) is timed too, and reported
  apart from the routes found. ``warmup`` queries of each kind run first, untimed, after
  every floor's vertex tree was built (the service builds it once per graph).
* **Routes.** Of the routes found: the median length, and on one floor the median and 95th
  percentile of the length over the straight line between the two points (pairs less
  than ``MIN_STRAIGHT_M`` apart left out).

The target (``bench/performance.md``): a route query on the largest plan within
``TARGET_P95_MS`` at the 95th percentile, judged on the same-floor routes found.
"""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lab.datasets.ilc import IlcSite
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.routes import NoRoute, find_route, point_endpoint
from server.positioning.plan.routing_graph import (
    FloorInput,
    FloorWalk,
    RoutingGraph,
    routing_graph,
)

TARGET_P95_MS = 20.0
"""A route query on the largest plan within this at the 95th percentile (ms)."""

MIN_STRAIGHT_M = 1.0  # pairs nearer than this have no meaningful detour ratio
_MB = 1e6


@dataclass(frozen=True)
class _Query:
    """One timed query: its kind, whether a route was found, the time (wall clock) and the
    route's length and straight line (NaN for no route, or across floors), and the time
    the query's thread spent on the CPU."""

    cross: bool
    found: bool
    ms: float
    length_m: float
    straight_m: float
    cpu_ms: float


def route_bench(
    site: IlcSite,
    *,
    queries: int = 500,
    cross_share: float = 0.2,
    seed: int = 0,
    warmup: int = 5,
) -> dict[str, Any]:
    """Build the site's routing graph and time route queries on it (module docstring).

    Parameters
    ----------
    site : IlcSite
        Its floors with a plan are routed on (``lab.datasets.ilc.read_site``).
    queries : int
        Timed queries (pairs of walkable vertices).
    cross_share : float
        Share of them between two floors (none when the site has one floor with a plan).
    seed : int
        Seed of the pairs.
    warmup : int
        Untimed queries of each kind run first.

    Returns
    -------
    dict
        ``site, floors`` (per floor: ``floor, level, walkable_m2, plan_s, build_s,
        vertices, edges, graph_mb``), ``build_s, links, portals, graph_mb,
        build_peak_mb``, ``largest_floor, queries, seed``; per kind (``same_floor``,
        ``cross_floor``): ``_queries, _found, _no_route``, ``_p50_ms, _p95_ms, _p99_ms,
        _max_ms`` of the routes found (wall clock), ``_cpu_p50_ms, _cpu_p95_ms`` (their
        CPU time), ``_no_route_p50_ms, _no_route_max_ms``,
        ``_length_median_m``; ``same_floor_detour_median, same_floor_detour_p95``;
        ``target_p95_ms, target_met`` (None: no same-floor route found).
    """
    if queries < 1:
        raise ValueError(f"queries must be at least 1, got {queries}")
    if not 0.0 <= cross_share <= 1.0:
        raise ValueError(f"cross_share must be in [0, 1], got {cross_share}")
    named = [(f.name, f.level, f.plan) for f in site.floors if f.plan is not None]
    if not named:
        raise ValueError(f"{site.name}: no floor has a plan")
    plans, plan_s = [], []
    for _, _, geojson in named:
        started = time.perf_counter()
        plans.append(plan_from_geojson(geojson))
        plan_s.append(time.perf_counter() - started)
    inputs = [
        FloorInput(site.name, level, plan, geojson)
        for (_, level, geojson), plan in zip(named, plans, strict=True)
    ]

    routing_graph([inputs[int(np.argmin([p.walkable.size for p in plans]))]])
    started = time.perf_counter()
    graph = routing_graph(inputs)
    build_s = time.perf_counter() - started
    floors = []
    for i, (name, level, _) in enumerate(named):
        started = time.perf_counter()
        routing_graph([inputs[i]])
        floor_s = time.perf_counter() - started
        walk, plan = graph.floors[i], plans[i]
        floors.append(
            {
                "floor": name,
                "level": level,
                "walkable_m2": float(plan.walkable.sum()) * plan.cell_m**2,
                "plan_s": plan_s[i],
                "build_s": floor_s,
                "vertices": walk.n if walk else 0,
                "edges": walk.costs.nnz // 2 if walk else 0,
                "graph_mb": walk.nbytes / _MB if walk else 0.0,
            }
        )
    tracemalloc.start()
    try:
        routing_graph(inputs)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()

    walks = [w for w in graph.floors if w is not None]
    if not walks:
        raise ValueError(f"{site.name}: no floor has walkable space")
    largest = max(walks, key=lambda w: w.n)
    n_cross = round(queries * cross_share) if len(walks) > 1 else 0
    for walk in walks:
        _ = walk.tree  # built once per graph, as the service does
    warm = _pairs(
        walks, largest, warmup, warmup if n_cross else 0, np.random.default_rng([seed, 1])
    )
    _timed(graph, warm)
    # no spinner or other thread here: it would take the GIL in the middle of a query
    done = _timed(
        graph, _pairs(walks, largest, queries - n_cross, n_cross, np.random.default_rng(seed))
    )

    result: dict[str, Any] = {
        "site": site.name,
        "floors": floors,
        "build_s": build_s,
        "links": len(graph.links),
        "portals": len(graph.portals.nodes),
        "graph_mb": graph.nbytes / _MB,
        "build_peak_mb": peak / _MB,
        "largest_floor": named[largest.floor][0],
        "queries": queries,
        "seed": seed,
    }
    for kind, cross in (("same_floor", False), ("cross_floor", True)):
        result |= _figures(kind, [q for q in done if q.cross == cross])
    same = [q for q in done if not q.cross and q.found and q.straight_m >= MIN_STRAIGHT_M]
    detour = np.array([q.length_m / q.straight_m for q in same])
    result["same_floor_detour_median"] = float(np.median(detour)) if detour.size else None
    result["same_floor_detour_p95"] = float(np.percentile(detour, 95)) if detour.size else None
    p95 = result["same_floor_p95_ms"]
    result["target_p95_ms"] = TARGET_P95_MS
    result["target_met"] = None if p95 is None else bool(p95 <= TARGET_P95_MS)
    return result


def _pairs(
    walks: Sequence[FloorWalk],
    largest: FloorWalk,
    n_same: int,
    n_cross: int,
    rng: np.random.Generator,
) -> list[tuple[FloorWalk, FloorWalk, int, int]]:
    """``(origin floor, destination floor, origin vertex, destination vertex)``: ``n_same``
    pairs on the largest floor and ``n_cross`` between two floors, shuffled."""
    ends = [(largest, largest)] * n_same
    for _ in range(n_cross):
        a, b = rng.choice(len(walks), size=2, replace=False)
        ends.append((walks[a], walks[b]))
    order = rng.permutation(len(ends))
    return [
        (ends[k][0], ends[k][1], int(rng.integers(ends[k][0].n)), int(rng.integers(ends[k][1].n)))
        for k in order
    ]


def _timed(
    graph: RoutingGraph, pairs: Sequence[tuple[FloorWalk, FloorWalk, int, int]]
) -> list[_Query]:
    out = []
    for start, end, a, b in pairs:
        xy_a, xy_b = start.xy[a], end.xy[b]
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            origin = point_endpoint(graph, start.floor, xy_a, "origin")
            destination = point_endpoint(graph, end.floor, xy_b, "destination")
            route = find_route(graph, origin, destination)
        except NoRoute:
            ms, cpu = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
            out.append(_Query(start is not end, False, ms, float("nan"), float("nan"), cpu))
            continue
        ms, cpu = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
        straight = float(np.linalg.norm(xy_b - xy_a)) if start is end else float("nan")
        out.append(_Query(start is not end, True, ms, route.length_m, straight, cpu))
    return out


def _figures(kind: str, done: Sequence[_Query]) -> dict[str, Any]:
    found = np.array([q.ms for q in done if q.found])
    cpu = np.array([q.cpu_ms for q in done if q.found])
    failed = np.array([q.ms for q in done if not q.found])
    lengths = np.array([q.length_m for q in done if q.found])

    def pct(values: np.ndarray[Any, Any], p: float) -> float | None:
        return float(np.percentile(values, p)) if values.size else None

    return {
        f"{kind}_queries": len(done),
        f"{kind}_found": int(found.size),
        f"{kind}_no_route": int(failed.size),
        f"{kind}_p50_ms": pct(found, 50),
        f"{kind}_p95_ms": pct(found, 95),
        f"{kind}_p99_ms": pct(found, 99),
        f"{kind}_max_ms": pct(found, 100),
        # the query's own CPU time: what the wall clock shows on a machine that is quiet
        f"{kind}_cpu_p50_ms": pct(cpu, 50),
        f"{kind}_cpu_p95_ms": pct(cpu, 95),
        f"{kind}_no_route_p50_ms": pct(failed, 50),
        f"{kind}_no_route_max_ms": pct(failed, 100),
        f"{kind}_length_median_m": pct(lengths, 50),
    }
