"""Map-constrained particle filter with the mass-centered magnetic weight update.

The filter of ``papers/001_*`` (Shao et al.) section III-B, Algorithm 1, as pure steps
over an immutable particle cloud; the engine (WiFi/BLE initialisation, floor plans,
magnetic maps, re-initialisation policy) glues them together. This module starts the
cloud and runs one pass of Algorithm 1 (lines 7-13); the parts of the filter are in

* ``particle_move``: the move with its noise and the floor plan's test (lines 8-9);
* ``particle_weight_update``: the mass-centered weight update (section III-C/D, eq b-c),
  the DTW baseline (section IV-B) and other likelihoods;
* ``particle_resampling``: systematic resampling when the effective sample size is low;
* ``particle_estimate``: the position with its uncertainty and the floor (line 14);

the cloud and its parameters are in ``particle_cloud``, the compiled loops in
``particle_kernels`` (with those of ``plan.move_test_kernels`` and
``magnetic.magnetic_kernels``).

State. Particle ``i`` is ``(x_i, y_i, floor_i, log w_i)`` and the map magnitudes
``s_i^{t-W}, ..., s_i^t`` (µT) at its last ``W + 1`` positions, oldest first (NaN where
the map is unknown); the cloud also holds the observed magnitudes
``s_obs^{t-W}, ..., s_obs^t`` and how many of those ``W + 1`` slots are filled. The
magnitudes travel with their particle through resampling, so eq (b) compares each
particle's own history with the observed one.

Initialisation (Algorithm 1 lines 1-3): ``N`` particles uniform on the disc of radius
``r`` around the WiFi/BLE fix ``l`` (redrawn until they are reachable, when a test is
given), all with weight ``1/N``.

Numbers are stored as float32 (positions, log weights, magnitudes) and every step reads
the stored values, so a cloud that went through the state codec (``state_codec``) between
steps continues exactly as one that did not. Moves are checked on the float32 positions
that are stored. Randomness comes only from the ``rng`` passed in.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from server.positioning.filters import particle_kernels
from server.positioning.filters.particle_cloud import (
    MapSampler,
    MoveCheck,
    ParticleParams,
    Particles,
    PointCheck,
    Weighting,
    from_points,
    unchecked,
)
from server.positioning.filters.particle_move import move
from server.positioning.filters.particle_resampling import alive, resample_when_low
from server.positioning.filters.particle_weight_update import weight_update
from server.positioning.magnetic import field_grid
from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.plan import floor_plan
from server.positioning.plan.floor_plan import FloorPlan

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_INIT_ROUNDS = 32  # redraw rounds in ``initialise`` before giving up


def initialise(
    centre_xy: ArrayLike,
    floor: int,
    rng: np.random.Generator,
    params: ParticleParams,
    *,
    radius_m: float | None = None,
    valid_point: PointCheck | None = None,
) -> Particles:
    """Spread ``params.n`` particles around a WiFi/BLE fix (Algorithm 1 lines 1-3).

    Points are uniform on the disc of radius ``radius_m`` around ``centre_xy``
    (``r = R sqrt(u)``, ``phi = 2 pi v``), rounded to float32 and, with ``valid_point``,
    redrawn until that test accepts them, so they are uniform over the reachable part of
    the disc.

    Parameters
    ----------
    centre_xy : array_like, shape (2,)
        The fix (m).
    floor : int
        Its floor.
    rng : numpy.random.Generator
    params : ParticleParams
    radius_m : float, optional
        Disc radius (m); ``params.init_radius_m`` by default.
    valid_point : callable, optional
        ``valid_point(floor (n,), xy (n, 2)) -> (n,) bool``.

    Returns
    -------
    Particles

    Raises
    ------
    ValueError
        When ``valid_point`` accepts too few points of the disc to fill the cloud.
    """
    c = np.asarray(centre_xy, dtype=np.float64).reshape(2)
    radius = params.init_radius_m if radius_m is None else float(radius_m)
    if not (np.all(np.isfinite(c)) and math.isfinite(radius) and radius >= 0):
        raise ValueError(f"bad disc: centre {c.tolist()}, radius_m {radius}")
    n = params.n
    if valid_point is None:
        return from_points(_disc(c, radius, n, rng), floor, params.window)
    chunks: list[FloatArray] = []
    found = drawn = 0
    for _ in range(_INIT_ROUNDS):
        # draw for the acceptance rate seen so far (at least 1/64), 20 % to spare
        rate = max(found / drawn if drawn else 1.0, 1.0 / 64.0)
        m = math.ceil((n - found) / rate * 1.2) + 16
        pts = _disc(c, radius, m, rng)
        ok = np.asarray(valid_point(np.full(m, floor, dtype=np.int16), pts), dtype=bool)
        chunks.append(pts[ok])
        found += int(ok.sum())
        drawn += m
        if found >= n:
            return from_points(np.concatenate(chunks)[:n], floor, params.window)
    raise ValueError(
        f"only {found} of {drawn} points within {radius} m of {c.tolist()} are reachable; "
        f"cannot place {n} particles"
    )


def step(
    p: Particles,
    length_m: float,
    heading_rad: float,
    observed_ut: float | None,
    rng: np.random.Generator,
    params: ParticleParams,
    valid_move: MoveCheck,
    sample_map: MapSampler,
    weighting: Weighting = "mass_centered",
    compiled: bool = True,
) -> Particles:
    """One pass of Algorithm 1 lines 7-13: move, weight, resample when ``N_eff`` is low.

    Parameters
    ----------
    p : Particles
    length_m, heading_rad : float
        The step (``particle_move.move``).
    observed_ut : float or None
        Magnitude measured at the step (µT); None when the phone sent none (no update).
    rng : numpy.random.Generator
    params : ParticleParams
    valid_move, sample_map : callable
        As in ``particle_move.move`` and
        ``particle_weight_update.mass_centered_update``.
    weighting : {"mass_centered", "dtw"}
        Eq (c) with the MMSE, or the DTW baseline.
    compiled : bool
        The compiled move and update (else their numpy references: with the references of
        ``valid_move`` and ``sample_map`` too, the filter in numpy alone).

    Returns
    -------
    Particles
        Possibly dead (``alive`` is False): the caller re-initialises.
    """
    p = move(p, length_m, heading_rad, rng, params, valid_move, compiled)
    if not alive(p):
        return p
    if observed_ut is not None:
        p = weight_update(p, observed_ut, sample_map, params, weighting, compiled)
    return resample_when_low(p, rng, params)


def step_on_floor(
    p: Particles,
    length_m: float,
    heading_rad: float,
    observed_ut: float | None,
    rng: np.random.Generator,
    params: ParticleParams,
    plan: FloorPlan | None,
    grid: MagneticGrid | None,
) -> Particles:
    """``step`` with the mass-centered update for a cloud whose particles share one floor,
    in one compiled pass (``particle_kernels.constrained_step``) and a compiled resampling.

    Parameters
    ----------
    p : Particles
        Every particle on the floor of ``plan`` and ``grid``.
    length_m, heading_rad, observed_ut, rng, params
        As in ``step`` (same random draws, in the same order).
    plan : FloorPlan or None
        The floor's plan (``floor_plan.valid_moves`` tests the moves); None: any finite end.
    grid : MagneticGrid or None
        The floor's magnetic map (``field_grid.sample``); None: unknown everywhere.

    Returns
    -------
    Particles
        What ``step`` returns with ``valid_move`` and ``sample_map`` made of ``plan`` and
        ``grid`` (to float rounding of the sums: the tests compare them).
    """
    if not (math.isfinite(length_m) and math.isfinite(heading_rad)):
        raise ValueError(f"step must be finite, got length {length_m}, heading {heading_rad}")
    if observed_ut is not None and not math.isfinite(observed_ut):
        raise ValueError(f"observed_ut must be finite, got {observed_ut}")
    slots = p.observed.shape[0]
    if slots != params.window + 1:
        raise ValueError(f"cloud window {slots - 1} differs from params.window {params.window}")
    noise = rng.standard_normal((2, p.n))
    weigh = observed_ut is not None
    observed = np.append(p.observed[1:], np.float32(observed_ut)) if weigh else p.observed
    count = min(p.count + 1, slots) if weigh else p.count
    xy, log_w, mags, ess = particle_kernels.constrained_step(
        np.ascontiguousarray(p.xy), np.ascontiguousarray(p.log_w),
        np.ascontiguousarray(p.mags), observed, count, noise, length_m, heading_rad,
        params.step_sd_m, params.heading_sd_rad,
        plan is not None,
        particle_kernels.NO_PLAN if plan is None else floor_plan.kernel_args(plan),
        grid is not None,
        particle_kernels.NO_GRID if grid is None else field_grid.kernel_args(grid),
        weigh, params.t, math.log(params.k),
    )  # fmt: skip
    if ess == 0.0:  # dead (``step`` returns it before the update)
        return unchecked(p, xy=xy, log_w=log_w)
    if ess < params.resample_ess_fraction * p.n:
        rows = particle_kernels.systematic_rows(log_w, rng.random())
        xy, mags = np.take(xy, rows, axis=0), np.take(mags, rows, axis=0)
        log_w = np.full(p.n, -math.log(p.n), dtype=np.float32)
    return unchecked(p, xy=xy, log_w=log_w, mags=mags, observed=observed, count=count)


def _disc(c: FloatArray, radius: float, m: int, rng: np.random.Generator) -> FloatArray:
    """``m`` points uniform on a disc, rounded to float32 and returned as float64."""
    u = rng.random((2, m))
    r = radius * np.sqrt(u[0])
    phi = 2.0 * math.pi * u[1]
    pts = np.column_stack([c[0] + r * np.cos(phi), c[1] + r * np.sin(phi)])
    return pts.astype(np.float32).astype(np.float64)
