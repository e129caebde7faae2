"""Building magnetic grids from positioned samples: walked lines, gridding, merging, coverage.

Map building (``papers/001_*`` section IV-A, "Magnetic positioning model")
------------------------------------------------------------------------------
Samples come from static survey points, walked survey lines and training traces, each a
position ``(x, y)`` in metres with a field magnitude ``|B|`` in µT and, where the phone's
attitude allowed it, the horizontal and vertical components.

* Walked lines. A surveyor walks a straight line at constant speed from ``a`` (time
  ``t_a``) to ``b`` (time ``t_b``); a sample taken at time ``t`` lies at::

      p(t) = a + (t - t_a) / (t_b - t_a) * (b - a),      t_a <= t <= t_b

  (``samples_along_line``); samples taken outside ``[t_a, t_b]`` are dropped.
* Gridding. The grid has its lower-left corner at ``origin = (x0, y0)`` and square cells
  of side ``c`` (0.5 m by default, DESIGN.md "Maps"). A sample falls in the cell::

      row = floor((y - y0) / c),   col = floor((x - x0) / c)

  Per cell, over its ``n`` samples: ``count = n``, ``mean = sum v / n`` and the unbiased
  variance ``var = sum (v - mean)^2 / (n - 1)``, two passes of ``np.bincount`` (sums, then
  squared deviations from the cell mean), so the variance of a field of ~50 µT with
  ~0.1 µT spread loses nothing to cancellation. A cell is *known* when ``n >= min_count``;
  unknown cells hold NaN, never 0. ``var`` is NaN also where ``n < 2`` (undefined).
  A component (horizontal, vertical) is averaged over its own finite samples with the
  same rule, so a cell can know its magnitude but not its components.

Merging (``merge_grids``): a new survey is gridded on its own and folded into the floor's
current grid cell by cell with the pairwise update of Chan, Golub and LeVeque (the
parallel form of Welford's running moments). For cells with ``(n_a, mean_a, M2_a)`` and
``(n_b, mean_b, M2_b)``, where ``M2 = var (n - 1)``::

    n = n_a + n_b,   d = mean_b - mean_a,
    mean = mean_a + d n_b / n,   M2 = M2_a + M2_b + d^2 n_a n_b / n

which gives the moments of the union of the two sample sets whatever the order of the
merges. Both grids must share the cell size and the lattice (origins a whole number of
cells apart); the result covers the union of their extents. Components are merged as
means weighted by the magnitude counts (the grid keeps no per-component count).

``known_share`` is the coverage of a grid: the share of a floor's walkable cells whose
magnitude is known.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from server.positioning.magnetic.field_grid import CELL_M, MagneticGrid
from server.positioning.plan.floor_plan import FloorPlan, walkable_at

FloatArray = NDArray[np.float64]

# most cells one floor's grid may have: 1 km x 1 km at 0.5 m (about 100 MB while two such
# grids are merged). A grid spanning more comes from a misplaced sample, not a building.
MAX_GRID_CELLS = 4_000_000


class GridTooLarge(ValueError):
    """A grid would have more than its ``max_cells`` cells; raised before allocating."""


def check_cells(nx: int, ny: int, cell_m: float, max_cells: int) -> None:
    """Raise GridTooLarge when an ``nx`` x ``ny`` grid has more than ``max_cells`` cells."""
    if nx * ny > max_cells:
        raise GridTooLarge(
            f"the samples span {nx * cell_m:.0f} m x {ny * cell_m:.0f} m ({nx * ny} cells "
            f"of {cell_m:g} m; at most {max_cells}): a sample lies far outside the building"
        )


@dataclass(frozen=True)
class MagneticSamples:
    """Positioned magnetic samples from one source (survey points, a line, a trace).

    Attributes
    ----------
    xy : array_like, shape (n, 2)
        Positions in metres.
    magnitude : array_like, shape (n,)
        ``|B|`` in µT, finite.
    horizontal, vertical : array_like, shape (n,), or None
        Components in µT, NaN where the attitude was unknown; None when the source has
        no components at all.
    """

    xy: ArrayLike
    magnitude: ArrayLike
    horizontal: ArrayLike | None = None
    vertical: ArrayLike | None = None


def samples_along_line(
    start_xy: ArrayLike,
    end_xy: ArrayLike,
    t_start_ms: float,
    t_end_ms: float,
    sample_t_ms: ArrayLike,
    values: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Place the samples of a walked survey line (``papers/001_*`` section IV-A).

    The surveyor leaves ``start_xy`` at ``t_start_ms`` and reaches ``end_xy`` at
    ``t_end_ms`` at constant speed; each sample is placed by linear interpolation of its
    time. Samples taken before the start or after the end are dropped.

    Parameters
    ----------
    start_xy, end_xy : array_like, shape (2,)
        Marked end points of the line (m).
    t_start_ms, t_end_ms : float
        Times at the end points (ms), ``t_end_ms > t_start_ms``.
    sample_t_ms : array_like, shape (n,)
        Sample times (ms).
    values : array_like, shape (n,) or (n, k)
        Sample values (e.g. magnitude, horizontal, vertical in µT).

    Returns
    -------
    xy : ndarray, shape (n_kept, 2), float64
        Sample positions (m).
    values : ndarray, shape (n_kept,) or (n_kept, k), float64
        The values of the kept samples, in input order.
    """
    a = np.asarray(start_xy, dtype=np.float64)
    b = np.asarray(end_xy, dtype=np.float64)
    t = np.asarray(sample_t_ms, dtype=np.float64)
    vals = np.asarray(values, dtype=np.float64)
    if a.shape != (2,) or b.shape != (2,):
        raise ValueError(f"start_xy and end_xy must have shape (2,), got {a.shape}, {b.shape}")
    if t.ndim != 1:
        raise ValueError(f"sample_t_ms must have shape (n,), got {t.shape}")
    if vals.ndim not in (1, 2) or vals.shape[0] != t.shape[0]:
        raise ValueError(f"values must have shape ({t.shape[0]},) or ({t.shape[0]}, k)")
    duration = float(t_end_ms) - float(t_start_ms)
    if not duration > 0:
        raise ValueError(f"t_end_ms must be after t_start_ms, got {t_start_ms}, {t_end_ms}")
    frac = (t - float(t_start_ms)) / duration
    keep = (frac >= 0.0) & (frac <= 1.0)
    frac = frac[keep]
    xy = a + frac[:, None] * (b - a)
    return xy, vals[keep]


def grid_from_samples(
    xy: ArrayLike,
    magnitude: ArrayLike,
    *,
    horizontal: ArrayLike | None = None,
    vertical: ArrayLike | None = None,
    cell_m: float = CELL_M,
    extent: tuple[float, float, float, float] | None = None,
    min_count: int = 1,
    max_cells: int = MAX_GRID_CELLS,
) -> MagneticGrid:
    """Grid positioned magnetic samples (see the module docstring).

    Parameters
    ----------
    xy : array_like, shape (n, 2)
        Sample positions (m), finite.
    magnitude : array_like, shape (n,)
        ``|B|`` in µT, finite.
    horizontal, vertical : array_like, shape (n,), optional
        Components in µT; NaN where unavailable for a sample.
    cell_m : float
        Cell side (m).
    extent : tuple (x0, y0, x1, y1), optional
        Area to grid; cells cover ``[x0, x0 + nx c) x [y0, y0 + ny c)`` with
        ``nx = ceil((x1 - x0) / c)``; samples outside are not counted. By default the
        bounding box of the samples on the lattice of multiples of ``cell_m``, with a
        margin of one cell on each side.
    min_count : int
        Fewest samples for a cell to be known.
    max_cells : int
        Largest grid made; GridTooLarge (a ValueError) before allocating a larger one.

    Returns
    -------
    MagneticGrid
        With read-only arrays.
    """
    pts = np.asarray(xy, dtype=np.float64)
    mag = np.asarray(magnitude, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"xy must have shape (n, 2), got {pts.shape}")
    n = pts.shape[0]
    if mag.shape != (n,):
        raise ValueError(f"magnitude must have shape ({n},), got {mag.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("xy must be finite")
    if not np.all(np.isfinite(mag)):
        raise ValueError("magnitude must be finite")
    components = {}
    for name, given in (("horizontal", horizontal), ("vertical", vertical)):
        if given is not None:
            comp = np.asarray(given, dtype=np.float64)
            if comp.shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {comp.shape}")
            components[name] = comp
    if not cell_m > 0:
        raise ValueError(f"cell_m must be positive, got {cell_m}")
    if min_count < 1:
        raise ValueError(f"min_count must be at least 1, got {min_count}")

    if extent is None:
        if n == 0:
            raise ValueError("extent is required when there are no samples")
        lo = np.floor(pts.min(axis=0) / cell_m) - 1.0
        hi = np.floor(pts.max(axis=0) / cell_m) + 1.0
        x0, y0 = float(lo[0] * cell_m), float(lo[1] * cell_m)
        nx, ny = int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1
    else:
        x0, y0, x1, y1 = (float(e) for e in extent)
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"extent must be (x0, y0, x1, y1) with x1 > x0, y1 > y0: {extent}")
        # round first so that an extent of whole cells is not widened by rounding error
        nx = int(np.ceil(round((x1 - x0) / cell_m, 9)))
        ny = int(np.ceil(round((y1 - y0) / cell_m, 9)))

    check_cells(nx, ny, cell_m, max_cells)
    col = np.floor((pts[:, 0] - x0) / cell_m).astype(np.int64)
    row = np.floor((pts[:, 1] - y0) / cell_m).astype(np.int64)
    inside = (col >= 0) & (col < nx) & (row >= 0) & (row < ny)
    cell = (row * nx + col)[inside]
    n_cells = nx * ny

    count, mean, m2 = _cell_moments(cell, mag[inside], n_cells)
    known = count >= min_count
    mean = np.where(known, mean, np.nan)
    var = np.full(n_cells, np.nan)
    np.divide(m2, count - 1, out=var, where=known & (count >= 2))

    fields: dict[str, NDArray[np.float32] | None] = {"horizontal": None, "vertical": None}
    for name, comp in components.items():
        c_count, c_mean, _ = _cell_moments(cell, comp[inside], n_cells)
        if c_count.any():
            fields[name] = _frozen(np.where(c_count >= min_count, c_mean, np.nan), ny, nx)

    return MagneticGrid(
        origin_m=(x0, y0),
        cell_m=float(cell_m),
        magnitude=_frozen(mean, ny, nx),
        var=_frozen(var, ny, nx),
        count=_frozen_count(count, ny, nx),
        horizontal=fields["horizontal"],
        vertical=fields["vertical"],
    )


def grid_from_sources(
    sources: Sequence[MagneticSamples],
    *,
    cell_m: float = CELL_M,
    extent: tuple[float, float, float, float] | None = None,
    min_count: int = 1,
    max_cells: int = MAX_GRID_CELLS,
) -> MagneticGrid:
    """Grid the samples of several sources of one floor together.

    The samples are concatenated and gridded once (``grid_from_samples``), so counts,
    means and variances are those of all samples; a source without a component
    contributes NaN for it.

    Parameters
    ----------
    sources : sequence of MagneticSamples
        Survey points, placed line samples (``samples_along_line``), training traces.
    cell_m, extent, min_count, max_cells
        As in ``grid_from_samples``.

    Returns
    -------
    MagneticGrid
    """
    names = ("magnitude", "horizontal", "vertical")
    xy: list[FloatArray] = []
    columns: dict[str, list[FloatArray]] = {name: [] for name in names}
    for k, source in enumerate(sources):
        pts = np.asarray(source.xy, dtype=np.float64)
        pts = pts.reshape(0, 2) if pts.size == 0 else pts
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ValueError(f"sources[{k}].xy must have shape (n, 2), got {pts.shape}")
        xy.append(pts)
        for name in names:
            given = getattr(source, name)
            values = np.full(len(pts), np.nan) if given is None else np.asarray(given, float)
            if values.shape != (len(pts),):
                raise ValueError(
                    f"sources[{k}].{name} must have shape ({len(pts)},), got {values.shape}"
                )
            columns[name].append(values)
    joined = {name: np.concatenate(columns[name]) if xy else np.empty(0) for name in names}
    has = {name: any(getattr(source, name) is not None for source in sources) for name in names}
    return grid_from_samples(
        np.concatenate(xy) if xy else np.empty((0, 2)),
        joined["magnitude"],
        horizontal=joined["horizontal"] if has["horizontal"] else None,
        vertical=joined["vertical"] if has["vertical"] else None,
        cell_m=cell_m,
        extent=extent,
        min_count=min_count,
        max_cells=max_cells,
    )


def merge_grids(a: MagneticGrid, b: MagneticGrid, max_cells: int = MAX_GRID_CELLS) -> MagneticGrid:
    """Fold two grids of one floor into one (see the module docstring).

    Parameters
    ----------
    a, b : MagneticGrid
        Same ``cell_m``; origins a whole number of cells apart. A cell whose magnitude is
        NaN counts as empty.
    max_cells : int
        Largest union made; GridTooLarge (a ValueError) before allocating a larger one.

    Returns
    -------
    MagneticGrid
        Over the union of both extents; counts add, means and variances are those of the
        union of both cells' samples.
    """
    c = a.cell_m
    if not np.isclose(b.cell_m, c, rtol=0.0, atol=1e-9):
        raise ValueError(f"cell sizes differ: {a.cell_m} and {b.cell_m}")
    shift = (np.asarray(b.origin_m) - np.asarray(a.origin_m)) / c
    if not np.allclose(shift, np.round(shift), rtol=0.0, atol=1e-6):
        raise ValueError(f"origins {a.origin_m} and {b.origin_m} are not on one lattice")
    # cell offsets of each grid's corner from the union's lower-left corner
    lo = np.minimum(0, np.round(shift).astype(np.int64))
    off_a = -lo
    off_b = np.round(shift).astype(np.int64) - lo
    nx = int(max(off_a[0] + a.magnitude.shape[1], off_b[0] + b.magnitude.shape[1]))
    ny = int(max(off_a[1] + a.magnitude.shape[0], off_b[1] + b.magnitude.shape[0]))
    check_cells(nx, ny, c, max_cells)

    def placed(
        grid: MagneticGrid, off: NDArray[np.int64], values: ArrayLike, fill: float
    ) -> FloatArray:
        out = np.full((ny, nx), fill)
        h, w = grid.magnitude.shape
        out[off[1] : off[1] + h, off[0] : off[0] + w] = values
        return out

    moments = []
    for grid, off in ((a, off_a), (b, off_b)):
        mean = placed(grid, off, grid.magnitude, np.nan)
        n = np.where(np.isnan(mean), 0.0, placed(grid, off, grid.count, 0.0))
        var = placed(grid, off, grid.var, np.nan)
        m2 = np.where(np.isnan(var) | (n < 2), 0.0, var * (n - 1))
        moments.append((n, np.nan_to_num(mean), m2))
    (na, ma, m2a), (nb, mb, m2b) = moments
    n = na + nb
    with np.errstate(invalid="ignore", divide="ignore"):
        d = mb - ma
        mean = np.where(n > 0, ma + d * nb / n, np.nan)
        m2 = m2a + m2b + np.where(n > 0, d * d * na * nb / n, 0.0)
        var = np.where(n >= 2, m2 / (n - 1), np.nan)

    components: dict[str, NDArray[np.float32] | None] = {}
    for name in ("horizontal", "vertical"):
        parts = [
            (placed(g, off, field, np.nan), w)
            for g, off, w in ((a, off_a, na), (b, off_b, nb))
            if (field := getattr(g, name)) is not None
        ]
        if not parts:
            components[name] = None
            continue
        weight = sum(np.where(np.isnan(v), 0.0, w) for v, w in parts)
        total = sum(np.where(np.isnan(v), 0.0, v * w) for v, w in parts)
        with np.errstate(invalid="ignore", divide="ignore"):
            components[name] = _frozen(np.where(weight > 0, total / weight, np.nan), ny, nx)

    origin = (a.origin_m[0] + float(lo[0]) * c, a.origin_m[1] + float(lo[1]) * c)
    return MagneticGrid(
        origin_m=origin,
        cell_m=c,
        magnitude=_frozen(mean, ny, nx),
        var=_frozen(var, ny, nx),
        count=_frozen_count(n.astype(np.int64), ny, nx),
        horizontal=components["horizontal"],
        vertical=components["vertical"],
    )


def known_share(grid: MagneticGrid | None, plan: FloorPlan | None) -> float | None:
    """Share of a floor's walkable cells whose magnitude is known (the map's coverage).

    A cell counts as walkable when its centre is (``floor_plan.walkable_at``); with a plan
    the grid is first widened, on its own lattice, to the plan's extent, so walkable cells
    the grid does not reach count as unknown. Without a plan every cell of the grid
    counts. No grid: nothing is known (0). None when no cell counts at all.
    """
    if grid is None:
        return 0.0
    if plan is not None:
        c, (gx, gy) = grid.cell_m, grid.origin_m
        (px, py), (py_n, px_n) = plan.origin_m, plan.walkable.shape
        x0 = gx + math.floor((px - gx) / c) * c
        y0 = gy + math.floor((py - gy) / c) * c
        extent = (x0, y0, px + px_n * plan.cell_m, py + py_n * plan.cell_m)
        empty = grid_from_samples(np.zeros((0, 2)), np.zeros(0), cell_m=c, extent=extent)
        grid = merge_grids(grid, empty)
    ny, nx = grid.magnitude.shape
    known = np.isfinite(grid.magnitude).ravel()
    if plan is None:
        counted = np.ones(known.shape, dtype=bool)
    else:
        x0, y0 = grid.origin_m
        col, row = np.meshgrid(np.arange(nx), np.arange(ny))  # row-major, like magnitude
        centres = np.column_stack(
            [x0 + (col.ravel() + 0.5) * grid.cell_m, y0 + (row.ravel() + 0.5) * grid.cell_m]
        )
        counted = walkable_at(plan, centres)
    n_counted = int(np.count_nonzero(counted))
    return int(np.count_nonzero(known & counted)) / n_counted if n_counted else None


def _cell_moments(
    cell: NDArray[np.int64], values: FloatArray, n_cells: int
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """Count, mean and sum of squared deviations per cell over the finite values."""
    ok = np.isfinite(values)
    cell, values = cell[ok], values[ok]
    # bincount is typed as returning integers; with weights it returns float64 (no copy)
    count = np.bincount(cell, minlength=n_cells).astype(np.int64, copy=False)
    total = np.bincount(cell, weights=values, minlength=n_cells).astype(np.float64, copy=False)
    mean: FloatArray = np.divide(total, count, out=np.full(n_cells, np.nan), where=count > 0)
    squares = (values - mean[cell]) ** 2
    m2 = np.bincount(cell, weights=squares, minlength=n_cells).astype(np.float64, copy=False)
    return count, mean, m2


def _frozen(values: FloatArray, ny: int, nx: int) -> NDArray[np.float32]:
    out = values.astype(np.float32).reshape(ny, nx)
    out.flags.writeable = False
    return out


def _frozen_count(values: NDArray[np.int64], ny: int, nx: int) -> NDArray[np.int32]:
    out = values.astype(np.int32).reshape(ny, nx)
    out.flags.writeable = False
    return out
