"""Map quality of one floor: how much of it the current maps cover, how well their cells
are sampled, how fresh the contributions are, and what the emitters heard there look like.

The current maps are the building's latest radio map version (its reference points, RPs,
on this floor) and the floor's latest magnetic map version; contributions are the floor's
survey points (surveyed through the admin API or folded in from uploads).

Figures
-------
* Coverage. ``radio``: of the floor's walkable 1 m cells (cells of the lattice of whole
  metres whose centre is walkable), the share holding an RP of this floor (RPs are the
  means of the points of one 1 m cell, so an RP lies in its cell). ``magnetic``: of the
  walkable cells of the magnetic grid's lattice (0.5 m), the share with a known field
  (``mapping.magnetic_gridding.known_share``, with the grid laid over the whole plan first, so that
  walkable cells the grid does not reach count as unknown). Without a usable plan both
  are over the map's own extent: the 1 m cells of the RPs' bounding box, the grid's cells.
* Cells. Per RP: RSS readings folded into it (all emitters) and emitters heard; per
  heard RP x emitter with at least 2 readings, the RSS variance. Per known magnetic cell:
  samples; per cell with at least 2 samples, the field variance.
* Freshness. Newest and oldest ``created_at`` of the floor's points; per 1 m cell holding
  points, the age of its newest point.
* Emitters. ``seen``: heard at an RP of this floor in the radio map. ``fixed``:
  ``signatures.identify_fixed_aps`` over the floor's WiFi readings that carry a time.
  ``retired``: seen, but heard by no point created in the ``retired_after_days`` before the
  floor's newest point. ``positions``: ``path_loss.fit_emitter`` over the floor's readings
  of each of the ``max_emitters`` most-read emitters (ties by kind and key).

Rasterising a plan and fitting emitters take a good part of a second on a mall floor: the
service (``services.map_quality``) runs ``floor_figures`` in a worker thread.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.mapping.magnetic_gridding import known_share
from server.positioning.mapping.signatures import identify_fixed_aps
from server.positioning.plan.floor_plan import FloorPlan
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.radio.path_loss import fit_emitter

RADIO_CELL_M = 1.0  # radio coverage and freshness are counted over 1 m cells
DAY_S = 86_400.0
KINDS = ("wifi", "ble")


@dataclass(frozen=True)
class QualityParams:
    max_emitters: int = 50  # emitters whose position is fitted, the most-read first
    retired_after_days: int = 30  # window before the newest contribution


@dataclass(frozen=True)
class Percentiles:
    p10: float
    p50: float
    p90: float


@dataclass(frozen=True)
class Coverage:
    radio: float | None
    magnetic: float | None
    walkable_area_known: bool


@dataclass(frozen=True)
class RadioCells:
    n_reference_points: int
    readings_per_rp: Percentiles | None
    emitters_per_rp: Percentiles | None
    var_db2: Percentiles | None


@dataclass(frozen=True)
class MagneticCells:
    known_cells: int
    samples_per_cell: Percentiles | None
    var_ut2: Percentiles | None


@dataclass(frozen=True)
class Freshness:
    newest: datetime | None
    oldest: datetime | None
    n_cells: int
    cell_age_days: Percentiles | None
    n_points: int
    n_surveyed_points: int
    n_uploads: int


@dataclass(frozen=True)
class EmitterPosition:
    kind: str
    key: str
    x_m: float
    y_m: float
    xy_std_m: tuple[float, float] | None
    p0_dbm: float
    exponent: float
    n: int
    residual_rms_db: float


@dataclass(frozen=True)
class Emitters:
    seen: int
    fixed: int
    retired: int
    positions: tuple[EmitterPosition, ...]
    unlocated: int


@dataclass(frozen=True)
class QualityPoint:
    """A survey point as plain values: where, when, from which upload, what it heard."""

    x_m: float
    y_m: float
    t_ms: int | None
    created_at: datetime
    upload_id: str | None
    readings: dict[str, Any]


@dataclass(frozen=True)
class FloorFigures:
    """The figures of one floor (module docstring)."""

    coverage: Coverage
    radio_cells: RadioCells
    magnetic_cells: MagneticCells
    freshness: Freshness
    emitters: Emitters


def floor_figures(
    plan_geojson: dict[str, Any] | None,
    rp_xy: NDArray[np.float64],
    count: NDArray[np.int32],
    var: NDArray[np.float64] | None,
    seen: set[tuple[str, str]],
    grid: MagneticGrid | None,
    points: Sequence[QualityPoint],
    params: QualityParams,
    now: datetime,
) -> FloorFigures:
    """The figures of the module docstring for a floor's RPs (``rp_xy``; readings
    ``count`` and RSS variance ``var`` per RP x emitter; ``seen``: the emitters heard at
    one), its magnetic ``grid`` and its survey ``points`` (CPU work: run it in a thread)."""
    radio_plan = _plan(plan_geojson, RADIO_CELL_M)
    # the magnetic plan on the grid's own cells: a 0.5 m cell counts when its centre does
    magnetic_plan = _plan(plan_geojson, grid.cell_m) if grid is not None else None
    coverage = Coverage(
        radio=_radio_coverage(rp_xy, radio_plan),
        magnetic=known_share(grid, magnetic_plan),
        walkable_area_known=radio_plan is not None,
    )
    radio_cells = RadioCells(
        n_reference_points=int(rp_xy.shape[0]),
        readings_per_rp=_percentiles(count.sum(axis=1)),
        emitters_per_rp=_percentiles((count > 0).sum(axis=1)),
        # a single reading has no variance (the map stores a default there)
        var_db2=_percentiles(var[count >= 2]) if var is not None else None,
    )
    if grid is not None:
        known = np.isfinite(grid.magnitude)
        magnetic_cells = MagneticCells(
            known_cells=int(np.count_nonzero(known)),
            samples_per_cell=_percentiles(grid.count[known]),
            var_ut2=_percentiles(grid.var[known & (grid.count >= 2)]),
        )
    else:
        magnetic_cells = MagneticCells(known_cells=0, samples_per_cell=None, var_ut2=None)
    return FloorFigures(
        coverage,
        radio_cells,
        magnetic_cells,
        _freshness(points, now),
        _emitters(points, seen, params),
    )


def _plan(geojson: dict[str, Any] | None, cell_m: float) -> FloorPlan | None:
    """The floor's walkable raster at ``cell_m``; None without a plan or a usable one."""
    if not geojson:
        return None
    try:
        return plan_from_geojson(geojson, cell_m=cell_m)
    except ValueError:
        return None


def _percentiles(values: ArrayLike) -> Percentiles | None:
    """10th, 50th and 90th percentiles of the finite values; None when there are none."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    p10, p50, p90 = np.percentile(v, [10.0, 50.0, 90.0]).tolist()
    return Percentiles(p10, p50, p90)


def _radio_coverage(rp_xy: NDArray[np.float64], plan: FloorPlan | None) -> float | None:
    """Share of the walkable 1 m cells holding an RP (``plan`` rasterised at 1 m); without
    a plan, of the 1 m cells of the RPs' bounding box. None when no cell counts."""
    cells = np.floor(rp_xy / RADIO_CELL_M).astype(np.int64).reshape(-1, 2)  # (col, row)
    if plan is None:
        if cells.shape[0] == 0:
            return 0.0
        box = cells.max(axis=0) - cells.min(axis=0) + 1
        return int(np.unique(cells, axis=0).shape[0]) / int(box[0] * box[1])
    ny, nx = plan.walkable.shape
    col = cells[:, 0] - round(plan.origin_m[0] / plan.cell_m)
    row = cells[:, 1] - round(plan.origin_m[1] / plan.cell_m)
    inside = (col >= 0) & (col < nx) & (row >= 0) & (row < ny)
    has_rp = np.zeros_like(plan.walkable)
    has_rp[row[inside], col[inside]] = True
    n_walkable = int(np.count_nonzero(plan.walkable))
    return int(np.count_nonzero(has_rp & plan.walkable)) / n_walkable if n_walkable else None


def _freshness(points: Sequence[QualityPoint], now: datetime) -> Freshness:
    if not points:
        return Freshness(None, None, 0, None, 0, 0, 0)
    created_s = np.array([p.created_at.timestamp() for p in points])
    xy = np.array([(p.x_m, p.y_m) for p in points], dtype=np.float64)
    cells, cell_of = np.unique(
        np.floor(xy / RADIO_CELL_M).astype(np.int64), axis=0, return_inverse=True
    )
    newest_s = np.full(cells.shape[0], -np.inf)
    np.maximum.at(newest_s, cell_of.ravel(), created_s)
    uploads = {p.upload_id for p in points if p.upload_id is not None}
    return Freshness(
        newest=max(p.created_at for p in points),
        oldest=min(p.created_at for p in points),
        n_cells=int(cells.shape[0]),
        cell_age_days=_percentiles(np.maximum(now.timestamp() - newest_s, 0.0) / DAY_S),
        n_points=len(points),
        n_surveyed_points=sum(p.upload_id is None for p in points),
        n_uploads=len(uploads),
    )


def _emitters(
    points: Sequence[QualityPoint], seen: set[tuple[str, str]], params: QualityParams
) -> Emitters:
    # one row per reading: point, emitter (index into keys), RSS
    point_of: list[int] = []
    key_of: list[tuple[str, str]] = []
    rss: list[float] = []
    for i, p in enumerate(points):
        for kind in KINDS:
            for key, value, *_ in p.readings.get(kind) or ():
                point_of.append(i)
                key_of.append((kind, str(key).lower()))
                rss.append(float(value))
    keys = sorted(set(key_of))
    index = {k: i for i, k in enumerate(keys)}
    pt = np.asarray(point_of, dtype=np.int64)
    em = np.fromiter((index[k] for k in key_of), dtype=np.int64, count=len(key_of))
    rssi = np.asarray(rss, dtype=np.float64)
    ok = np.isfinite(rssi)
    pt, em, rssi = pt[ok], em[ok], rssi[ok]
    xy = np.array([(p.x_m, p.y_m) for p in points], dtype=np.float64).reshape(-1, 2)
    t_ms = np.array([np.nan if p.t_ms is None else p.t_ms for p in points], dtype=np.float64)

    # fixed APs: WiFi readings with a time
    is_wifi = np.array([kind == "wifi" for kind, _ in keys], dtype=bool)
    timed = is_wifi[em] & np.isfinite(t_ms[pt])
    fixed = identify_fixed_aps(
        em[timed], rssi[timed], t_ms[pt[timed]], xy[pt[timed]], n_emitters=len(keys)
    )

    # retired: seen in the map, heard by no point of the window before the newest one
    if points:
        created_s = np.array([p.created_at.timestamp() for p in points])
        recent = created_s >= created_s.max() - params.retired_after_days * DAY_S
        heard_recent = {keys[i] for i in np.unique(em[recent[pt]]).tolist()}
    else:
        heard_recent = set()

    # positions of the most-read emitters
    n_readings = np.bincount(em, minlength=len(keys))
    ranked = sorted(np.flatnonzero(n_readings).tolist(), key=lambda i: (-n_readings[i], keys[i]))
    order = np.argsort(em, kind="stable")
    starts = np.concatenate([[0], np.cumsum(n_readings)])
    positions = []
    for i in ranked[: params.max_emitters]:
        rows = order[starts[i] : starts[i + 1]]
        fit = fit_emitter(xy[pt[rows]], rssi[rows])
        if fit is None:
            continue
        std = fit.xy_std_m
        positions.append(
            EmitterPosition(
                kind=keys[i][0],
                key=keys[i][1],
                x_m=float(fit.xy[0]),
                y_m=float(fit.xy[1]),
                xy_std_m=(float(std[0]), float(std[1])) if np.all(np.isfinite(std)) else None,
                p0_dbm=fit.p0_dbm,
                exponent=fit.exponent,
                n=fit.n,
                residual_rms_db=fit.residual_rms_db,
            )
        )
    return Emitters(
        seen=len(seen),
        fixed=int(np.count_nonzero(fixed.fixed)),
        retired=len(seen - heard_recent),
        positions=tuple(positions),
        unlocated=min(len(ranked), params.max_emitters) - len(positions),
    )
