"""Coverage grid of one floor: per square cell, how well the current radio map knows it.

The grid is laid on the lattice of multiples of ``cell_m`` over the floor: over the
bounding box of the walkable area ``W`` of its plan when it has a usable one
(``geojson_plan``), else over the box of the map's reference points (RPs) and the survey
points. A cell is *in the area* when it overlaps ``W`` (a positive area in common, so a
cell that only touches the outline is not); without a plan every cell of the box is. Every
cell of the grid is reported, data or none: thin coverage shows as cells without.

Per cell, with the RPs and the survey points whose position falls in it (a point on an
edge belongs to the cell above / to the right):

* ``readings``: RSS readings folded into the cell's RPs, all emitters (0 without an RP);
* ``points``: survey points (surveyed or uploaded, folded into the map or not yet);
* ``emitters``: distinct emitters heard at the cell's RPs;
* ``var_db2``: mean RSS variance over the cell's RP x emitter entries with at least 2
  readings (a single reading has no variance); NaN without one;
* ``age_days``: days from the newest survey point of the cell to ``now`` (NaN without a
  point);
* ``nearest_rp_m``: distance ``d`` from the cell's centre to the nearest RP of the floor;
* ``expected_error_m``: the RMS radial error of a radio fix of a phone at the centre,

      e = sqrt(2 σ² + d²),

  with σ the per-axis error of a fix (``radio.fix_error.FixErrorModel.sigma``, the table
  learned with the map or the default) of a scan matching the emitters heard at the
  nearest RP (what a scan there would match), the better of a WiFi and a BLE scan.
  A fix of an isotropic Gaussian error of per-axis σ has a mean square radial error 2σ²;
  the map knows nothing nearer the phone than its nearest RP, so the fix is taken to
  scatter around that RP, ``d`` from the truth: a bias of ``d``. A cell far from every RP
  thus looks worse however well the RPs themselves were sampled. NaN when the floor has no
  RP.

Laying the grid over a large plan (boxes against a walkable area of thousands of vertices)
is CPU work: the service runs ``coverage_grid`` in a worker thread.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from shapely.geometry.base import BaseGeometry

from server.positioning.plan.geojson_format import PlanError
from server.positioning.plan.geojson_plan import read, walkable_area
from server.positioning.radio.fix_error import FixErrorModel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

DAY_S = 86_400.0
MAX_CELLS = 40_000  # a grid of more cells is refused: ask for larger cells
MIN_OVERLAP = 1e-6  # share of a cell W must cover for the cell to be in the area
TILE = 8  # cells per side of the tiles the walkable area is clipped to


class TooManyCells(ValueError):
    """The floor's extent at the asked cell size needs more than ``MAX_CELLS`` cells;
    ``min_cell_m`` is the smallest size that fits."""

    def __init__(self, n_cells: int, max_cells: int, min_cell_m: float) -> None:
        super().__init__(
            f"the floor takes {n_cells} cells at this size, more than {max_cells}: "
            f"ask for cells of at least {min_cell_m:g} m"
        )
        self.min_cell_m = min_cell_m


@dataclass(frozen=True)
class CoverageGrid:
    """The figures of the module docstring, each an array of shape ``(rows, cols)``:
    row ``i``, column ``j`` is the cell ``[x0 + j c, x0 + (j + 1) c) x [y0 + i c,
    y0 + (i + 1) c)`` with ``(x0, y0) = origin_m`` and ``c = cell_m``."""

    origin_m: tuple[float, float]
    cell_m: float
    walkable_area_known: bool
    in_area: NDArray[np.bool_]
    readings: IntArray
    points: IntArray
    emitters: IntArray
    var_db2: FloatArray
    age_days: FloatArray
    nearest_rp_m: FloatArray
    expected_error_m: FloatArray

    @property
    def shape(self) -> tuple[int, int]:
        rows, cols = self.in_area.shape
        return int(rows), int(cols)


def coverage_grid(
    plan_geojson: Mapping[str, Any] | None,
    rp_xy: FloatArray,
    count: NDArray[np.integer[Any]],
    var_db2: NDArray[np.floating[Any]],
    kinds: Sequence[str],
    point_xy: FloatArray,
    point_created_s: FloatArray,
    now_s: float,
    fix_error: FixErrorModel,
    cell_m: float,
    max_cells: int = MAX_CELLS,
) -> CoverageGrid:
    """The coverage grid of a floor (module docstring).

    Parameters
    ----------
    plan_geojson : mapping or None
        The floor's plan (``geojson_format``); None, or one without a walkable area, lays
        the grid over the data's box.
    rp_xy : ndarray, shape (n_rp, 2)
        The floor's RPs (m).
    count, var_db2 : ndarray, shape (n_rp, n_em)
        Readings and RSS variance (dB²) per RP x emitter.
    kinds : sequence of str, length n_em
        Each emitter's kind (``"wifi"``, ``"ble"``).
    point_xy : ndarray, shape (n_points, 2)
        The floor's survey points (m).
    point_created_s : ndarray, shape (n_points,)
        Their creation times (Unix seconds).
    now_s : float
        The time ages are counted to (Unix seconds).
    fix_error : FixErrorModel
        The map's fix-error table.
    cell_m : float
        Cell side (m), positive.
    max_cells : int
        The most cells a grid may have.

    Returns
    -------
    CoverageGrid

    Raises
    ------
    TooManyCells
        The grid would have more than ``max_cells`` cells.
    ValueError
        A bad ``cell_m``.
    """
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be positive, not {cell_m}")
    rp_xy = np.asarray(rp_xy, dtype=np.float64).reshape(-1, 2)
    point_xy = np.asarray(point_xy, dtype=np.float64).reshape(-1, 2)
    count = np.asarray(count)
    area = _walkable(plan_geojson)
    if area is not None:
        x_min, y_min, x_max, y_max = area.bounds
    elif rp_xy.shape[0] + point_xy.shape[0]:
        both = np.concatenate([rp_xy, point_xy])
        (x_min, y_min), (x_max, y_max) = both.min(axis=0), both.max(axis=0)
    else:
        return _empty(cell_m)
    extent = (float(x_min), float(y_min), float(x_max), float(y_max))
    x0, y0, rows, cols = _lattice(extent, cell_m, planned=area is not None)
    if rows * cols > max_cells:
        raise TooManyCells(rows * cols, max_cells, _fitting_cell_m(extent, area, max_cells))
    origin = (float(x0), float(y0))
    shape = (rows, cols)
    in_area = (
        _overlapping(area, origin, cell_m, shape)
        if area is not None
        else np.ones(shape, dtype=bool)
    )

    n_cells = rows * cols
    rp_cell, rp_in = _cell_of(rp_xy, origin, cell_m, shape)
    heard = count > 0
    sampled = count >= 2
    readings = np.bincount(rp_cell[rp_in], count.sum(axis=1)[rp_in], minlength=n_cells)
    var_sum = np.where(sampled, var_db2, 0.0).sum(axis=1)
    var_n = np.bincount(rp_cell[rp_in], sampled.sum(axis=1)[rp_in], minlength=n_cells)
    var_total = np.bincount(rp_cell[rp_in], var_sum[rp_in], minlength=n_cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        var_mean = np.where(var_n > 0, var_total / var_n, np.nan)

    emitters = np.zeros(n_cells, dtype=np.int64)
    if np.any(rp_in):
        cells, inverse = np.unique(rp_cell[rp_in], return_inverse=True)
        heard_in = np.zeros((cells.size, heard.shape[1]), dtype=bool)
        np.logical_or.at(heard_in, inverse.ravel(), heard[rp_in])
        emitters[cells] = heard_in.sum(axis=1)

    point_cell, point_in = _cell_of(point_xy, origin, cell_m, shape)
    points = np.bincount(point_cell[point_in], minlength=n_cells)
    newest_s = np.full(n_cells, -np.inf)
    np.maximum.at(newest_s, point_cell[point_in], np.asarray(point_created_s, np.float64)[point_in])
    with np.errstate(invalid="ignore"):
        age = np.where(np.isfinite(newest_s), np.maximum(now_s - newest_s, 0.0) / DAY_S, np.nan)

    centres = _centres(origin, cell_m, shape)
    if rp_xy.shape[0]:
        d, nearest = cKDTree(rp_xy).query(centres)
        sigma = _rp_sigma(heard, kinds, fix_error)[nearest]
        error = np.sqrt(2.0 * sigma**2 + d**2)
    else:
        d = error = np.full(n_cells, np.nan)

    return CoverageGrid(
        origin_m=origin,
        cell_m=float(cell_m),
        walkable_area_known=area is not None,
        in_area=in_area,
        readings=readings.astype(np.int64).reshape(shape),
        points=points.astype(np.int64).reshape(shape),
        emitters=emitters.reshape(shape),
        var_db2=var_mean.reshape(shape),
        age_days=age.reshape(shape),
        nearest_rp_m=np.asarray(d, dtype=np.float64).reshape(shape),
        expected_error_m=np.asarray(error, dtype=np.float64).reshape(shape),
    )


def rows_of(values: NDArray[Any], decimals: int | None = None) -> list[list[Any]]:
    """A grid's array as nested lists, row by row, NaN as None, floats rounded to
    ``decimals`` (integers and booleans as they are)."""
    if values.dtype.kind != "f":
        return values.tolist()  # type: ignore[no-any-return]
    rounded = np.round(values, decimals) if decimals is not None else values
    return [[None if math.isnan(v) else v for v in row] for row in rounded.tolist()]


def _walkable(geojson: Mapping[str, Any] | None) -> BaseGeometry | None:
    """The plan's walkable area ``W``; None without a plan or a usable one."""
    if not geojson:
        return None
    try:
        area, _ = walkable_area(read(geojson, strict=False))
    except (PlanError, ValueError):
        return None
    return area


def _lattice(
    extent: tuple[float, float, float, float], cell_m: float, *, planned: bool
) -> tuple[float, float, int, int]:
    """``(x0, y0, rows, cols)`` of the cells over an extent: a plan's cells end at its far
    edge, the data's box keeps a point lying on it (in a cell of its own)."""
    x_min, y_min, x_max, y_max = extent
    # multiples of the cell, without the float's noise (0.3 * 3 = 0.8999999999999999)
    x0 = round(math.floor(x_min / cell_m) * cell_m, 9)
    y0 = round(math.floor(y_min / cell_m) * cell_m, 9)
    if planned:
        cols = max(math.ceil((x_max - x0) / cell_m), 1)
        rows = max(math.ceil((y_max - y0) / cell_m), 1)
    else:
        cols = math.floor((x_max - x0) / cell_m) + 1
        rows = math.floor((y_max - y0) / cell_m) + 1
    return x0, y0, rows, cols


def _fitting_cell_m(
    extent: tuple[float, float, float, float], area: BaseGeometry | None, max_cells: int
) -> float:
    """The smallest cell side, in whole centimetres, whose grid over the extent has at
    most ``max_cells`` cells."""
    width, height = extent[2] - extent[0], extent[3] - extent[1]
    cm = max(math.floor(100 * math.sqrt(width * height / max_cells)), 1)
    while True:  # a few steps: the lattice's extra row and column at most
        _, _, rows, cols = _lattice(extent, cm / 100, planned=area is not None)
        if rows * cols <= max_cells:
            return cm / 100
        cm += 1


def _empty(cell_m: float) -> CoverageGrid:
    def zeros(dtype: type) -> NDArray[Any]:
        return np.zeros((0, 0), dtype=dtype)

    return CoverageGrid(
        origin_m=(0.0, 0.0),
        cell_m=float(cell_m),
        walkable_area_known=False,
        in_area=zeros(bool),
        readings=zeros(np.int64),
        points=zeros(np.int64),
        emitters=zeros(np.int64),
        var_db2=zeros(np.float64),
        age_days=zeros(np.float64),
        nearest_rp_m=zeros(np.float64),
        expected_error_m=zeros(np.float64),
    )


def _centres(origin: tuple[float, float], cell_m: float, shape: tuple[int, int]) -> FloatArray:
    """Cell centres, row by row, shape ``(rows * cols, 2)``."""
    rows, cols = shape
    xs = origin[0] + (np.arange(cols) + 0.5) * cell_m
    ys = origin[1] + (np.arange(rows) + 0.5) * cell_m
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _cell_of(
    xy: FloatArray, origin: tuple[float, float], cell_m: float, shape: tuple[int, int]
) -> tuple[IntArray, NDArray[np.bool_]]:
    """Flat index (row * cols + col) of the cell holding each point, and whether the
    point is in the grid at all (an index of 0 where it is not)."""
    rows, cols = shape
    col = np.floor((xy[:, 0] - origin[0]) / cell_m).astype(np.int64)
    row = np.floor((xy[:, 1] - origin[1]) / cell_m).astype(np.int64)
    inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    return np.where(inside, row * cols + col, 0), inside


def _overlapping(
    area: BaseGeometry, origin: tuple[float, float], cell_m: float, shape: tuple[int, int]
) -> NDArray[np.bool_]:
    """Which cells have a positive area (over ``MIN_OVERLAP`` of the cell) in common
    with ``area``: the cells inside it and, of those meeting its boundary, the ones it
    covers more than a touch of. The boundary's cells are measured against the part of
    ``area`` clipped to their tile of ``TILE`` x ``TILE`` cells, not the whole of a plan's
    thousands of vertices (a 200 m square floor of 400 rooms in 1 m cells: the whole grid
    in 1.0 s instead of 1.8 s)."""
    rows, cols = shape
    corners = _centres(origin, cell_m, shape) - cell_m / 2
    boxes = shapely.box(
        corners[:, 0], corners[:, 1], corners[:, 0] + cell_m, corners[:, 1] + cell_m
    )
    shapely.prepare(area)
    inside = shapely.contains_properly(area, boxes)
    edge = np.flatnonzero(shapely.intersects(area, boxes) & ~inside)
    tile = (edge // cols // TILE) * (cols // TILE + 1) + (edge % cols) // TILE
    for t in np.unique(tile).tolist():
        cells = edge[tile == t]
        x0, y0 = corners[cells].min(axis=0)
        x1, y1 = corners[cells].max(axis=0) + cell_m
        piece = shapely.clip_by_rect(area, x0, y0, x1, y1)
        shared = shapely.area(shapely.intersection(boxes[cells], piece))
        inside[cells] = shared > MIN_OVERLAP * cell_m**2
    return np.asarray(inside, dtype=bool).reshape(rows, cols)


def _rp_sigma(
    heard: NDArray[np.bool_], kinds: Sequence[str], fix_error: FixErrorModel
) -> FloatArray:
    """Per RP, the smaller σ of a WiFi and a BLE scan matching the emitters of their kind
    heard there; an RP hearing nothing gets the σ of one emitter of the worse kind."""
    kind_of = np.asarray(list(kinds), dtype=object)
    names = sorted(set(kind_of.tolist())) or ["wifi"]
    best = np.full(heard.shape[0], max(fix_error.sigma(k, 1) for k in names))
    for kind in names:
        n = heard[:, kind_of == kind].sum(axis=1)
        values, inverse = np.unique(n, return_inverse=True)
        table = np.array([fix_error.sigma(kind, int(v)) for v in values.tolist()])
        best = np.where(n > 0, np.minimum(best, table[inverse.ravel()]), best)
    return best
