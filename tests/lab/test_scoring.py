"""Scoring: the estimate at a waypoint, and the per-floor figures of a summary."""

from __future__ import annotations

import numpy as np
import pytest

from lab import scoring
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.magnetic.field_grid import MagneticMap
from server.positioning.mapping.magnetic_gridding import grid_from_samples, known_share
from server.positioning.model.events import Fix
from server.positioning.plan.geojson_plan import plan_from_geojson
from tests.support.lab_fakes import ilc_trace


def _fix(t_ms: int, x_m: float, floor: int = 0) -> Fix:
    return Fix(t_ms, x_m, 0.0, floor, None, (4.0, 0.0, 0.0, 4.0), "wifi")


def test_estimate_is_the_last_fix_at_or_before_the_waypoint() -> None:
    trace = ilc_trace()
    fixes = [_fix(250, 7.0, floor=1), _fix(150, 4.0), _fix(200, 5.5)]
    est = scoring.estimates_at_waypoints(trace, 0, fixes)
    assert np.isnan(est.est_xy_m[0]).all()  # nothing yet at t=100
    assert est.est_xy_m[1, 0] == 5.5  # the fix at exactly t=200
    assert est.est_xy_m[2, 0] == 7.0
    assert est.est_floor.tolist() == [-1, 0, 1]
    assert est.sigma_m[1] == pytest.approx(2.0)


def _path(path_id: str, floor_index: int, rng: np.random.Generator, n: int) -> scoring.PathResult:
    truth = rng.uniform(0.0, 30.0, (n, 2))
    est = truth + rng.normal(0.0, 3.0, (n, 2))
    est[0] = np.nan  # no fix yet at the first waypoint
    est_floor = np.where(rng.random(n) < 0.8, floor_index, floor_index + 1)
    estimates = scoring.WaypointEstimates(
        true_xy_m=truth,
        true_floor=np.full(n, floor_index, dtype=np.int64),
        est_xy_m=est,
        est_floor=est_floor.astype(np.int64),
        sigma_m=np.full(n, 2.0),
    )
    return scoring.PathResult(path_id, floor_index, estimates, ())


def test_per_floor_figures_add_up_to_the_overall_ones() -> None:
    rng = np.random.default_rng(5)
    paths = [_path("a", 0, rng, 12), _path("b", 1, rng, 7), _path("c", 0, rng, 9)]
    plain = scoring.summarize(paths, engine="e")
    summary = scoring.summarize(paths, floor_names=["B1", "F1", "F2"], engine="e")
    assert {k: v for k, v in summary.items() if k != "per_floor"} == plain
    per_floor = summary["per_floor"]
    assert list(per_floor) == ["B1", "F1", "F2"]
    for key in ("n_points", "n_missing", "test_paths"):
        overall = summary.get(key, len(paths))
        assert sum(f[key] for f in per_floor.values()) == overall, key
    for name, index in (("B1", 0), ("F1", 1)):
        on_floor = [p.estimates for p in paths if p.floor_index == index]
        est = np.concatenate([e.est_xy_m for e in on_floor])
        truth = np.concatenate([e.true_xy_m for e in on_floor])
        found = ~np.isnan(est[:, 0])
        errors = np.hypot(*(est[found] - truth[found]).T)
        hits = np.concatenate([e.est_floor == index for e in on_floor])[found]
        assert per_floor[name]["mean_m"] == pytest.approx(float(np.mean(errors)))
        assert per_floor[name]["p90_m"] == pytest.approx(float(np.percentile(errors, 90)))
        assert per_floor[name]["floor_hit_rate"] == pytest.approx(float(np.mean(hits)))
        assert "magnetic_coverage" not in per_floor[name]  # no maps given
    assert per_floor["F2"]["test_paths"] == per_floor["F2"]["n_points"] == 0
    assert per_floor["F2"]["mean_m"] is None


CORRIDOR = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"kind": "outline"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [[[0, 0], [2, 0], [2, 4], [0, 4], [0, 0]]],
            },
        }
    ],
}


def test_magnetic_coverage_counts_known_walkable_cells() -> None:
    plan = plan_from_geojson(CORRIDOR)
    # 1 m cells over the floor: the 8 cells of columns 0 and 1 are walkable; samples fall in
    # three of them, and in one cell beside the corridor
    centres = [(0.5, 0.5), (1.5, 1.5), (0.5, 2.5), (0.5, 2.7), (3.5, 0.5)]
    grid = grid_from_samples(
        centres, [50.0, 51.0, 52.0, 53.0, 54.0], cell_m=1.0, extent=(0.0, 0.0, 4.0, 4.0)
    )
    assert known_share(grid, plan) == 3 / 8
    assert known_share(grid, None) == 4 / 16  # without a plan: all cells
    assert known_share(None, plan) == 0.0
    beside = grid_from_samples([(3.5, 3.5)], [50.0], cell_m=1.0, extent=(3.0, 3.0, 4.0, 4.0))
    # a grid that reaches no walkable cell: the plan's walkable cells count, none known
    assert known_share(beside, plan) == 0.0

    floors = (FloorRef("toy", "F1", 0), FloorRef("toy", "F2", 1))
    maps = SiteMaps(floors, None, "v", plans=(plan, None), magnetic=MagneticMap((grid, None), "v"))
    # two waypoints walked on F1: one in a known cell, one at the centre of an unknown one
    truth = np.array([(0.5, 0.5), (1.5, 3.5)])
    walked = scoring.PathResult(
        "p",
        0,
        scoring.WaypointEstimates(
            true_xy_m=truth,
            true_floor=np.zeros(2, dtype=np.int64),
            est_xy_m=truth,
            est_floor=np.zeros(2, dtype=np.int64),
            sigma_m=np.ones(2),
        ),
        (),
    )
    summary = scoring.summarize([walked], floor_names=["F1", "F2"], maps=maps)
    per_floor = summary["per_floor"]
    assert per_floor["F1"]["magnetic_coverage"] == 3 / 8
    assert per_floor["F1"]["magnetic_at_waypoints"] == 0.5
    assert per_floor["F2"]["magnetic_coverage"] == 0.0  # no training field on that floor
    assert per_floor["F2"]["magnetic_at_waypoints"] is None  # and no waypoint walked there
