"""Scoring replayed fixes against the truth at the waypoints.

The estimate at a waypoint is the last fix at or before its timestamp (none yet: counted as
missing). ``summarize`` gives the error report (``model.error_metrics.error_report``) over all
paths and per floor; ``write_points`` every scored point as a CSV row.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.magnetic.field_grid import sample
from server.positioning.mapping.magnetic_gridding import known_share
from server.positioning.model.error_metrics import error_report
from server.positioning.model.events import Fix
from server.positioning.model.walk import Walk


@dataclass(frozen=True)
class WaypointEstimates:
    """Per waypoint: the truth and the last fix at or before it (NaN when none)."""

    true_xy_m: NDArray[np.float64]
    true_floor: NDArray[np.int64]
    est_xy_m: NDArray[np.float64]
    est_floor: NDArray[np.int64]
    sigma_m: NDArray[np.float64]
    t_ms: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    # the fix's radii holding 68 % and 95 % of the errors (NaN where it gives none)
    accuracy_68_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    accuracy_95_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))


def estimates_at_waypoints(
    trace: Walk, floor_index: int, fixes: Sequence[Fix]
) -> WaypointEstimates:
    n = trace.waypoint_t_ms.size
    est = np.full((n, 2), np.nan)
    est_floor = np.full(n, -1, dtype=np.int64)
    sigma = np.full(n, np.nan)
    r68 = np.full(n, np.nan)
    r95 = np.full(n, np.nan)
    if fixes:
        fix_t = np.array([f.t_ms for f in fixes], dtype=np.int64)
        order = np.argsort(fix_t, kind="stable")
        fix_t = fix_t[order]
        # index of the last fix with t <= waypoint t
        idx = np.searchsorted(fix_t, trace.waypoint_t_ms, side="right") - 1
        for row, i in enumerate(idx.tolist()):
            if i < 0:
                continue
            fix = fixes[int(order[i])]
            est[row] = (fix.x_m, fix.y_m)
            est_floor[row] = fix.floor
            sigma[row] = fix.uncertainty_m
            r68[row], r95[row] = fix.accuracy_68_m, fix.accuracy_95_m
    return WaypointEstimates(
        true_xy_m=trace.waypoint_xy_m.astype(np.float64),
        true_floor=np.full(n, floor_index, dtype=np.int64),
        est_xy_m=est,
        est_floor=est_floor,
        sigma_m=sigma,
        t_ms=trace.waypoint_t_ms.astype(np.int64),
        accuracy_68_m=r68,
        accuracy_95_m=r95,
    )


@dataclass(frozen=True)
class PathResult:
    path_id: str
    floor_index: int
    estimates: WaypointEstimates
    fixes: tuple[Fix, ...]


def _stack(paths: Sequence[PathResult]) -> WaypointEstimates:
    def cat(name: str, dtype: Any, shape: tuple[int, ...]) -> Any:
        parts = [getattr(p.estimates, name) for p in paths]
        return np.concatenate(parts) if parts else np.zeros(shape, dtype=dtype)

    return WaypointEstimates(
        true_xy_m=cat("true_xy_m", np.float64, (0, 2)),
        true_floor=cat("true_floor", np.int64, (0,)),
        est_xy_m=cat("est_xy_m", np.float64, (0, 2)),
        est_floor=cat("est_floor", np.int64, (0,)),
        sigma_m=cat("sigma_m", np.float64, (0,)),
        accuracy_68_m=cat("accuracy_68_m", np.float64, (0,)),
        accuracy_95_m=cat("accuracy_95_m", np.float64, (0,)),
    )


def _report(paths: Sequence[PathResult]) -> dict[str, Any]:
    est = _stack(paths)
    n = est.true_floor.size
    radii = est.accuracy_68_m.size == n and est.accuracy_95_m.size == n
    report = error_report(
        est.est_xy_m,
        est.true_xy_m,
        est.est_floor,
        est.true_floor,
        sigma_m=est.sigma_m,
        accuracy_68_m=est.accuracy_68_m if radii else None,
        accuracy_95_m=est.accuracy_95_m if radii else None,
    )
    return report.to_dict()


def summarize(
    paths: Sequence[PathResult],
    *,
    floor_names: Sequence[str] | None = None,
    maps: SiteMaps | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The extra fields and the error report over all paths; with ``floor_names`` (by
    floor index) also ``per_floor``: per floor name the error report over the paths walked
    on that floor and their number (``test_paths``), and, when ``maps`` carry a magnetic
    map, the floor's ``magnetic_coverage`` (share of walkable cells with a known field) and
    ``magnetic_at_waypoints`` (share of the test waypoints where the map gives a field)."""
    summary = {**extra, **_report(paths)}
    if floor_names is not None:
        per_floor: dict[str, dict[str, Any]] = {}
        for index, name in enumerate(floor_names):
            on_floor = [p for p in paths if p.floor_index == index]
            figures = {**_report(on_floor), "test_paths": len(on_floor)}
            if maps is not None and maps.magnetic is not None:
                grids, plans = maps.magnetic.grids, maps.plans
                grid = grids[index] if index < len(grids) else None
                figures["magnetic_coverage"] = known_share(
                    grid, plans[index] if index < len(plans) else None
                )
                truth = _stack(on_floor).true_xy_m
                figures["magnetic_at_waypoints"] = (
                    float(np.isfinite(sample(grid, truth)).mean())
                    if grid is not None and len(truth)
                    else None
                )
            per_floor[name] = figures
        summary["per_floor"] = per_floor
    return summary


POINT_COLUMNS = (
    "path",
    "t_ms",
    "true_x_m",
    "true_y_m",
    "true_floor",
    "est_x_m",
    "est_y_m",
    "est_floor",
    "sigma_m",
    "error_m",
    "accuracy_68_m",
    "accuracy_95_m",
)


def write_points(paths: Sequence[PathResult], out: Path) -> int:
    """Every scored point as a CSV row (``POINT_COLUMNS``; floors as indices, empty
    estimate fields where no fix came before the point), so that anyone can re-plot or
    re-score; returns the number of rows."""
    rows = 0
    with out.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(POINT_COLUMNS)
        for p in paths:
            e = p.estimates
            times = e.t_ms if e.t_ms.size == e.true_floor.size else np.full(e.true_floor.size, -1)
            for i in range(e.true_floor.size):
                known = bool(np.isfinite(e.est_xy_m[i]).all())
                error = float(np.hypot(*(e.est_xy_m[i] - e.true_xy_m[i]))) if known else None
                writer.writerow(
                    [
                        p.path_id,
                        int(times[i]),
                        f"{e.true_xy_m[i, 0]:.3f}",
                        f"{e.true_xy_m[i, 1]:.3f}",
                        int(e.true_floor[i]),
                        f"{e.est_xy_m[i, 0]:.3f}" if known else "",
                        f"{e.est_xy_m[i, 1]:.3f}" if known else "",
                        int(e.est_floor[i]) if known else "",
                        f"{e.sigma_m[i]:.3f}" if known else "",
                        f"{error:.3f}" if error is not None else "",
                        _cell(e.accuracy_68_m, i, known),
                        _cell(e.accuracy_95_m, i, known),
                    ]
                )
                rows += 1
    return rows


def _cell(values: NDArray[np.float64], i: int, known: bool) -> str:
    """A radius as a CSV cell: empty without an estimate or a radius."""
    if not known or i >= values.size or not np.isfinite(values[i]):
        return ""
    return f"{values[i]:.3f}"


def errors_m(paths: Sequence[PathResult]) -> list[float]:
    """The horizontal error of every point that has an estimate."""
    est = _stack(paths)
    ok = ~np.isnan(est.est_xy_m[:, 0])
    errors: list[float] = np.hypot(*(est.est_xy_m[ok] - est.true_xy_m[ok]).T).tolist()
    return errors
