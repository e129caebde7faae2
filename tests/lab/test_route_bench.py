"""The route benchmark runs and reports what it says, on a toy site (no timing is
asserted: the figures of ILC site2 are in the bench's own output)."""

from __future__ import annotations

import math
from typing import Any

import pytest

from lab.datasets.ilc import IlcFloor, IlcSite
from lab.route_bench import route_bench

KINDS = ("same_floor", "cross_floor")
PER_KIND = (
    "queries", "found", "no_route", "p50_ms", "p95_ms", "p99_ms", "max_ms",
    "cpu_p50_ms", "cpu_p95_ms", "no_route_p50_ms", "no_route_max_ms", "length_median_m",
)  # fmt: skip


def _area(kind: str, x0: float, y0: float, x1: float, y1: float, **extra: Any) -> dict[str, Any]:
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {
        "type": "Feature",
        **extra,
        "properties": {"kind": kind},
        "geometry": {"type": "Polygon", "coordinates": [ring]},
    }


def _floor(name: str, level: int, stairs: bool, island: bool = False) -> IlcFloor:
    """A 30 m x 12 m hall with a shop across most of its width, the stairs in a corner
    (or none) and, on the ground floor, a walkable island no walk reaches."""
    features = [_area("walkable", 0, 0, 30, 12), _area("unit", 10, 0, 12, 9)]
    if stairs:
        features.append(_area("stairs", 26, 8, 29, 11, id="stairs-a"))
    if island:
        features.append(_area("walkable", 34, 0, 44, 6))
    plan = {"type": "FeatureCollection", "features": features}
    return IlcFloor(name, level, 44.0, 12.0, plan, ())


@pytest.fixture(scope="module")
def site() -> IlcSite:
    # F1 and F2 joined by the stairs, F3 with none: some cross-floor queries find no route
    return IlcSite(
        "toy",
        (
            _floor("F1", 0, stairs=True, island=True),
            _floor("F2", 1, stairs=True),
            _floor("F3", 2, stairs=False),
        ),
    )


@pytest.fixture(scope="module")
def result(site: IlcSite) -> dict[str, Any]:
    return route_bench(site, queries=60, cross_share=0.5, seed=3, warmup=1)


def test_reports_every_figure(result: dict[str, Any]) -> None:
    per_kind = [f"{kind}_{name}" for kind in KINDS for name in PER_KIND]
    assert list(result) == [
        "site", "floors", "build_s", "links", "portals", "graph_mb", "build_peak_mb",
        "largest_floor", "queries", "seed", *per_kind, "same_floor_detour_median",
        "same_floor_detour_p95", "target_p95_ms", "target_met",
    ]  # fmt: skip
    assert (result["site"], result["queries"], result["seed"]) == ("toy", 60, 3)
    assert result["largest_floor"] == "F1"  # the island's vertices
    assert result["target_met"] is (result["same_floor_p95_ms"] <= result["target_p95_ms"])


def test_floors_and_the_whole_graph(result: dict[str, Any]) -> None:
    floors = result["floors"]
    assert [f["floor"] for f in floors] == ["F1", "F2", "F3"]
    assert [f["level"] for f in floors] == [0, 1, 2]
    for f in floors:
        assert f["vertices"] > 0
        assert f["edges"] > f["vertices"]  # a grid of 8 neighbours
        assert f["graph_mb"] > 0
        assert f["plan_s"] > 0
        assert f["build_s"] > 0
    # the hall less the shop, and the island
    assert floors[1]["walkable_m2"] == pytest.approx(30 * 12 - 2 * 9)
    assert floors[0]["walkable_m2"] == pytest.approx(30 * 12 - 2 * 9 + 10 * 6)
    assert floors[0]["vertices"] > floors[1]["vertices"]
    assert result["links"] == 1  # the stairs, F1 to F2
    assert result["portals"] == 2
    assert result["graph_mb"] >= sum(f["graph_mb"] for f in floors)
    assert result["build_s"] > 0
    assert result["build_peak_mb"] > 0


def test_counts_routes_found_and_refused(result: dict[str, Any]) -> None:
    assert result["same_floor_queries"] == result["cross_floor_queries"] == 30
    for kind in KINDS:
        assert result[f"{kind}_found"] + result[f"{kind}_no_route"] == 30
        assert result[f"{kind}_found"] > 0, kind  # F1 <-> F2 by the stairs
        assert result[f"{kind}_no_route"] > 0, kind  # the island; F3
        times = [result[f"{kind}_{p}_ms"] for p in ("p50", "p95", "p99", "max")]
        assert all(math.isfinite(t) and t > 0 for t in times), kind
        assert times == sorted(times), kind
        assert 0 < result[f"{kind}_no_route_p50_ms"] <= result[f"{kind}_no_route_max_ms"]
        assert result[f"{kind}_length_median_m"] > 0
    # a route is never shorter than the straight line between its ends
    assert 1.0 - 1e-9 <= result["same_floor_detour_median"] <= result["same_floor_detour_p95"]


def test_the_seed_fixes_the_queries(site: IlcSite, result: dict[str, Any]) -> None:
    again = route_bench(site, queries=60, cross_share=0.5, seed=3, warmup=0)
    for name in ("found", "no_route", "length_median_m"):
        for kind in KINDS:
            assert again[f"{kind}_{name}"] == result[f"{kind}_{name}"]


def test_one_floor_has_no_cross_floor_queries() -> None:
    got = route_bench(IlcSite("one", (_floor("F1", 0, stairs=False),)), queries=5, warmup=0)
    assert (got["same_floor_queries"], got["cross_floor_queries"]) == (5, 0)
    assert got["cross_floor_p95_ms"] is None
    assert got["same_floor_no_route"] == 0
    assert isinstance(got["target_met"], bool)


def test_refuses_no_queries_and_no_plans(site: IlcSite) -> None:
    with pytest.raises(ValueError, match="queries"):
        route_bench(site, queries=0)
    with pytest.raises(ValueError, match="cross_share"):
        route_bench(site, cross_share=1.5)
    with pytest.raises(ValueError, match="no floor has a plan"):
        route_bench(IlcSite("bare", (IlcFloor("F1", 0, 1.0, 1.0, None, ()),)))
