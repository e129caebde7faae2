"""Magnetic maps: a regular grid per floor, and its bilinear sampling.

A ``MagneticGrid`` holds, per square cell of a floor, the mean field magnitude ``|B|`` and
its variance and sample count, and where known the horizontal and vertical components
(DESIGN.md "Maps": 0.5 m cells, ``CELL_M``); a ``MagneticMap`` is a building's grids by
floor. Grids are built from surveys and traces by
``server.positioning.mapping.magnetic_gridding`` (``papers/001_*`` section IV-A), and
compared along a walk by ``server.positioning.magnetic.sequence_distance``.

Sampling (``sample``, ``sample_many``): bilinear interpolation between the four cell
centres around a point. With ``u = (x - x0) / c - 1/2``, ``v = (y - y0) / c - 1/2``,
``i = floor(u)``, ``j = floor(v)``, ``fx = u - i``, ``fy = v - j``::

    B(x, y) = (1 - fy) [(1 - fx) B[j, i] + fx B[j, i+1]] + fy [(1 - fx) B[j+1, i] + fx B[j+1, i+1]]

which is exact on a plane ``a + b x + c y``. Unknown centres are left out and the
weights of the known ones renormalised (``B = sum w_k B_k / sum w_k`` over the known
corners ``k``), so a single walked line, a strip one cell wide, can be sampled along its
whole width; the result is NaN only where the known corners carry (almost) no weight
(``MIN_CORNER_WEIGHT``) or outside the grid. Between the outermost centres and the
grid's edge a point takes the edge centres' values. The paper's Figure 7 map is
interpolated linearly between walked lines; here the lines feed the grid and the grid
is interpolated bilinearly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from server.positioning.magnetic import magnetic_kernels

FloatArray = NDArray[np.float64]
Component = Literal["magnitude", "horizontal", "vertical"]

CELL_M = 0.5  # DESIGN.md "Maps": magnetic grid of 0.5 m

# sampling: a point whose known corners carry less bilinear weight than this is unknown
MIN_CORNER_WEIGHT = 1e-6


@dataclass(frozen=True)
class MagneticGrid:
    """A magnetic map of one floor on a regular grid.

    Attributes
    ----------
    origin_m : tuple of float
        ``(x0, y0)``, lower-left corner of cell ``(0, 0)`` in the building frame (m).
    cell_m : float
        Cell side (m); cell ``(row, col)`` has its centre at
        ``(x0 + (col + 1/2) c, y0 + (row + 1/2) c)``.
    magnitude : ndarray, shape (ny, nx), float32
        Mean field magnitude ``|B|`` in µT; NaN where unknown.
    var : ndarray, shape (ny, nx), float32
        Unbiased variance of the magnitude samples in µT^2; NaN where unknown or where
        the cell holds a single sample.
    count : ndarray, shape (ny, nx), int32
        Number of magnitude samples that fell in the cell (also below ``min_count``).
    horizontal, vertical : ndarray, shape (ny, nx), float32, or None
        Mean horizontal / vertical component in µT, NaN where unknown; None when no
        sample carried the component.
    """

    origin_m: tuple[float, float]
    cell_m: float
    magnitude: NDArray[np.float32]
    var: NDArray[np.float32]
    count: NDArray[np.int32]
    horizontal: NDArray[np.float32] | None
    vertical: NDArray[np.float32] | None

    def sampling_arrays(self, component: Component) -> tuple[FloatArray, FloatArray]:
        """The field flattened with unknown cells as 0, and 1.0 / 0.0 for known / unknown:
        what bilinear sampling gathers from (made once per grid and component)."""
        cache: dict[str, tuple[FloatArray, FloatArray]] = self.__dict__.setdefault("_sampling", {})
        if component not in cache:
            field = getattr(self, component).ravel().astype(np.float64)
            known = ~np.isnan(field)
            cache[component] = (np.where(known, field, 0.0), known.astype(np.float64))
        return cache[component]

    def __post_init__(self) -> None:
        if not self.cell_m > 0:
            raise ValueError(f"cell_m must be positive, got {self.cell_m}")
        shape = self.magnitude.shape
        if len(shape) != 2:
            raise ValueError(f"magnitude must have shape (ny, nx), got {shape}")
        for name in ("var", "count", "horizontal", "vertical"):
            field = getattr(self, name)
            if field is not None and field.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {field.shape}")


@dataclass(frozen=True)
class MagneticMap:
    """Magnetic grids of a building, indexed by floor index (None: no map on that floor)."""

    grids: tuple[MagneticGrid | None, ...]
    version: str


def sample(grid: MagneticGrid, xy: ArrayLike, component: Component = "magnitude") -> FloatArray:
    """Sample a grid bilinearly at a batch of positions (see the module docstring).

    Parameters
    ----------
    grid : MagneticGrid
    xy : array_like, shape (n, 2)
        Positions (m).
    component : {"magnitude", "horizontal", "vertical"}
        Field to sample.

    Returns
    -------
    ndarray, shape (n,), float64
        Field in µT; NaN where none of the surrounding cell centres with weight is
        known, or outside the grid.
    """
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"xy must have shape (n, 2), got {pts.shape}")
    if getattr(grid, component) is None:
        raise ValueError(f"this grid has no {component} component")
    # _bilinear below, compiled (kernels)
    out: FloatArray = magnetic_kernels.bilinear(pts, *kernel_args(grid, component))
    return out


def kernel_args(
    grid: MagneticGrid, component: Component = "magnitude"
) -> magnetic_kernels.GridArgs:
    """The grid as the compiled sampling takes it (``magnetic_kernels.bilinear``,
    ``particle_kernels.constrained_step``)."""
    filled, known = grid.sampling_arrays(component)
    ny, nx = grid.magnitude.shape
    x0, y0 = grid.origin_m
    return float(x0), float(y0), float(grid.cell_m), nx, ny, filled, known, MIN_CORNER_WEIGHT


def sample_many(
    grid: MagneticGrid, xy: ArrayLike, component: Component = "magnitude"
) -> FloatArray:
    """Sample a grid bilinearly at windows of positions (one window per particle).

    Parameters
    ----------
    grid : MagneticGrid
    xy : array_like, shape (n, w, 2)
        Positions (m).
    component : {"magnitude", "horizontal", "vertical"}

    Returns
    -------
    ndarray, shape (n, w), float64
        As ``sample``.
    """
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[2] != 2:
        raise ValueError(f"xy must have shape (n, w, 2), got {pts.shape}")
    return _bilinear(grid, pts.reshape(-1, 2), component).reshape(pts.shape[:2])


def _bilinear(grid: MagneticGrid, pts: FloatArray, component: Component) -> FloatArray:
    """Bilinear interpolation of one field at ``pts`` of shape (k, 2), over the known
    corners only (see the module docstring)."""
    fields = {"magnitude": grid.magnitude, "horizontal": grid.horizontal, "vertical": grid.vertical}
    field = fields[component]
    if field is None:
        raise ValueError(f"this grid has no {component} component")
    ny, nx = field.shape
    # continuous cell-centre coordinates: centre (row j, col i) at (u, v) = (i, j)
    u = pts[:, 0] - grid.origin_m[0]
    u /= grid.cell_m
    u -= 0.5
    v = pts[:, 1] - grid.origin_m[1]
    v /= grid.cell_m
    v -= 0.5
    inside = (u >= -0.5) & (u <= nx - 0.5) & (v >= -0.5) & (v <= ny - 0.5)  # False for NaN
    # beyond the outermost centres a point takes the edge centres' values; fmin / fmax
    # also map NaN to a valid index (masked as outside below)
    u = np.fmax(np.fmin(u, nx - 1.0), 0.0)
    v = np.fmax(np.fmin(v, ny - 1.0), 0.0)
    # lower-left centre of the square around each point; the last row / column of centres
    # is reached from the square before it with f = 1
    i0 = np.fmin(np.floor(u), max(nx - 2, 0))
    j0 = np.fmin(np.floor(v), max(ny - 2, 0))
    fx = u - i0
    fy = v - j0
    base = (j0 * nx + i0).astype(np.intp)
    di, dj = min(nx - 1, 1), nx * min(ny - 1, 1)
    filled, known = grid.sampling_arrays(component)
    every = grid.__dict__.setdefault("_every_known", {})
    if component not in every:
        every[component] = bool(known.all())
    gx, gy = 1.0 - fx, 1.0 - fy
    total = np.zeros(pts.shape[0])
    weight = np.zeros(pts.shape[0])
    for offset, w in ((0, gx * gy), (di, fx * gy), (dj, gx * fy), (dj + di, fx * fy)):
        index = base + offset
        if not every[component]:  # (times 1.0 changes nothing)
            w *= known.take(index)
        weight += w
        w *= filled.take(index)
        total += w
    out: FloatArray = np.full(pts.shape[0], np.nan)
    np.divide(total, weight, out=out, where=inside & (weight > MIN_CORNER_WEIGHT))
    return out
