"""Wireless-aided magnetic profile matching and its accuracy indicators (``papers/000_*``
section III-A and III-B, the magnetic side of eq 10-14, 23-24).

A profile is the field magnitude the phone measured at its last steps, placed by dead
reckoning: ``offsets_m[j]`` is step ``j``'s position relative to the newest one. Its
features are the gradients ``g_j = m_j - m_0`` (each element minus the first, section
III-A), which a phone's magnetometer bias does not change. The search area is a circle
around the last wireless fix whose radius is three times that fix's predicted error
(the "wireless-aided magnetic matching" of the paper's reference [3]); every point of a
lattice of ``spacing_m`` inside it is a candidate end of the profile, with the map's
gradients ``G_j(c) = B(c + offsets_j) - B(c + offsets_0)`` sampled bilinearly
(``magnetic.sample``). The likelihood of a candidate is Gaussian per feature (eq 10-11),
with each sample's spread from its map cell (its own variance where the cell has
``min_count`` samples, else ``default_sd_ut``: the paper's (0.03 Gauss)^2 = (3 µT)^2 and
20 samples, section IV-B) and the two ends' spreads added for a difference::

    log zeta(c) = -1/2 sum_j [ (g_j - G_j(c))^2 / s_j^2 + log(2 pi s_j^2) ],
    s_j^2 = sd(c + offsets_j)^2 + sd(c + offsets_0)^2

The fix is the likelihood-weighted mean of the ``kappa`` most likely candidates (eq 12).

Indicators of the fix (metres):

* SS (eq 13-14, ``c_i^m = 1 / m_i``): ``alpha_ss_mag`` times the mean of ``1 / |g_j|``
  over the profile's gradients (at least ``min_gradient_ut``): a flat profile is one that
  many places share.
* WD (eq 23-24): for each chosen candidate, its DSF is the mean distance to the
  ``kappa_d`` other candidates whose map features are most likely under its own Gaussian,
  and WD their likelihood-weighted mean.
* SD (eq 20-22) needs the horizontal and vertical components of the phone's profile,
  which a magnitude-only profile does not carry: NaN, so it takes no part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from server.positioning.magnetic.field_grid import MagneticGrid, sample

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MagneticFix:
    """A magnetic profile's position and its indicators.

    Attributes
    ----------
    x_m, y_m : float
        End of the profile (the newest step), eq 12.
    ss_m, wd_m : float
        The indicators of the module docstring; NaN where they cannot be computed.
    candidates : int
        Lattice points inside the circle where the map knows the whole profile.
    """

    x_m: float
    y_m: float
    ss_m: float
    wd_m: float
    candidates: int


def lattice(centre: tuple[float, float], radius_m: float, spacing_m: float) -> FloatArray:
    """Points of a square lattice of ``spacing_m`` (aligned with the origin) inside the
    circle, shape (n, 2)."""
    cx, cy = centre
    xs = np.arange(
        math.floor((cx - radius_m) / spacing_m), math.ceil((cx + radius_m) / spacing_m) + 1
    )
    ys = np.arange(
        math.floor((cy - radius_m) / spacing_m), math.ceil((cy + radius_m) / spacing_m) + 1
    )
    gx, gy = np.meshgrid(xs * spacing_m, ys * spacing_m)
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    return pts[np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) <= radius_m]


def cell_sd(grid: MagneticGrid, xy: FloatArray, min_count: int, default_sd_ut: float) -> FloatArray:
    """Spread of the map's magnitude at each point's cell: its own where the cell holds
    ``min_count`` samples or more, else ``default_sd_ut`` (also outside the grid)."""
    ny, nx = grid.magnitude.shape
    col = np.floor((xy[..., 0] - grid.origin_m[0]) / grid.cell_m).astype(np.int64)
    row = np.floor((xy[..., 1] - grid.origin_m[1]) / grid.cell_m).astype(np.int64)
    inside = (col >= 0) & (col < nx) & (row >= 0) & (row < ny)
    col, row = np.clip(col, 0, nx - 1), np.clip(row, 0, ny - 1)
    var = grid.var[row, col].astype(np.float64)
    enough = inside & (grid.count[row, col] >= min_count) & np.isfinite(var)
    return np.where(enough, np.sqrt(np.where(enough, var, 0.0)), default_sd_ut)


def _log_gauss(obs: FloatArray, mean: FloatArray, var: FloatArray) -> FloatArray:
    """Sum over the last axis of Gaussian log-densities."""
    out: FloatArray = -0.5 * np.sum((obs - mean) ** 2 / var + np.log(2.0 * math.pi * var), axis=-1)
    return out


def match(
    grid: MagneticGrid,
    offsets_m: FloatArray,
    magnitude_ut: FloatArray,
    centre: tuple[float, float],
    radius_m: float,
    *,
    spacing_m: float = 1.0,
    kappa: int = 5,
    kappa_d: int = 5,
    alpha_ss: float = 50.0,
    min_gradient_ut: float = 0.1,
    min_count: int = 20,
    default_sd_ut: float = 3.0,
) -> MagneticFix | None:
    """Match a profile inside the circle (module docstring); None when fewer than
    ``kappa`` candidates know the whole profile or the profile has under two steps.

    Parameters
    ----------
    grid : MagneticGrid
        The floor's magnetic map.
    offsets_m : ndarray, shape (n, 2)
        Each step's position relative to the newest (the last row is 0, 0).
    magnitude_ut : ndarray, shape (n,)
        Field magnitude measured at each step, oldest first.
    centre, radius_m :
        The search circle.
    """
    n = magnitude_ut.shape[0]
    if n < 2:
        return None
    cand = lattice(centre, radius_m, spacing_m)
    if cand.shape[0] < kappa:
        return None
    pts = cand[:, None, :] + offsets_m[None, :, :]  # (c, n, 2)
    field = sample(grid, pts.reshape(-1, 2)).reshape(cand.shape[0], n)
    known = np.isfinite(field).all(axis=1)
    if np.count_nonzero(known) < kappa:
        return None
    cand, pts, field = cand[known], pts[known], field[known]
    sd = cell_sd(grid, pts, min_count, default_sd_ut)
    feats = field[:, 1:] - field[:, :1]  # (c, n-1) the map's gradients
    var = sd[:, 1:] ** 2 + sd[:, :1] ** 2
    observed = magnitude_ut[1:] - magnitude_ut[0]
    log_zeta = _log_gauss(observed[None, :], feats, var)
    best = np.argsort(-log_zeta, kind="stable")[:kappa]
    w = np.exp(log_zeta[best] - log_zeta[best[0]])
    w /= w.sum()
    xy = w @ cand[best]
    ss = alpha_ss * float(np.mean(1.0 / np.maximum(np.abs(observed), min_gradient_ut)))
    # DSF of each chosen candidate: the others most likely under its own Gaussian
    others = _log_gauss(feats[None, :, :], feats[best][:, None, :], var[best][:, None, :])
    others[np.arange(best.size), best] = -np.inf
    k = min(kappa_d, cand.shape[0] - 1)
    wd = math.nan
    if k >= 1:
        similar = np.argsort(-others, axis=1, kind="stable")[:, :k]
        dsf = np.hypot(*(cand[similar] - cand[best][:, None, :]).transpose(2, 0, 1)).mean(axis=1)
        wd = float(w @ dsf)
    return MagneticFix(float(xy[0]), float(xy[1]), ss, wd, int(cand.shape[0]))
