"""The particle filter's move: each particle one noisy step on, and off the map where the
floor plan says no (``papers/001_*`` section III-B, Algorithm 1 lines 8-9).

Movement (Algorithm 1 line 8, with headings clockwise from north as in
``server.positioning.model.events``)::

    x_i^t = x_i^{t-1} + (S + delta_i) sin(theta + Delta_i)
    y_i^t = y_i^{t-1} + (S + delta_i) cos(theta + Delta_i)
    delta_i ~ N(0, sigma_S^2),   Delta_i ~ N(0, sigma_theta^2)

with ``S`` the reported step length (clipped at 0 after the noise) and ``theta`` the
reported heading. Line 9 removes particles outside reachable areas: a particle whose move
``a -> b`` the floor plan refuses (``b`` not reachable or the segment crosses a wall) gets
``log w = -inf`` and stays at ``a``, so no particle ever stands where the plan said no.
Dead particles are revived by the next resampling.

Moves are checked on the float32 positions that are stored (``particle`` module
docstring), computed by ``particle_kernels.step_ends`` or, in numpy, by
``move_ends_reference``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters import particle_kernels
from server.positioning.filters.particle_cloud import (
    MoveCheck,
    ParticleParams,
    Particles,
    live_rows,
    normalised,
    take_rows,
    unchecked,
)

FloatArray = NDArray[np.float64]


def move(
    p: Particles,
    length_m: float,
    heading_rad: float,
    rng: np.random.Generator,
    params: ParticleParams,
    valid_move: MoveCheck,
    compiled: bool = True,
) -> Particles:
    """Move every particle by one step (Algorithm 1 lines 8-9, module docstring).

    Parameters
    ----------
    p : Particles
    length_m : float
        Reported step length ``S`` (m).
    heading_rad : float
        Reported heading ``theta`` (rad, clockwise from north).
    rng : numpy.random.Generator
        Draws ``(2, n)`` normals: step-length noise, then heading noise.
    params : ParticleParams
    valid_move : callable
        ``valid_move(floor (m,), a (m, 2), b (m, 2)) -> (m,) bool``; called with the
        living particles only, on the float32 positions that will be stored.
    compiled : bool
        The new positions from ``particle_kernels.step_ends`` (else ``move_ends_reference``).

    Returns
    -------
    Particles
        Moved; particles whose move was refused are dead and stay where they were.
    """
    if not (math.isfinite(length_m) and math.isfinite(heading_rad)):
        raise ValueError(f"step must be finite, got length {length_m}, heading {heading_rad}")
    noise = rng.standard_normal((2, p.n))
    finite = np.isfinite(p.log_w)
    n_live = int(np.count_nonzero(finite))
    if n_live == 0:
        return p
    live = live_rows(finite, n_live)
    a = take_rows(p.xy, live).astype(np.float64)
    # b = a + length (sin, cos)(heading), rounded to the float32 that is stored (compiled:
    # particle_kernels.step_ends; move_ends_reference is the same in numpy)
    ends = particle_kernels.step_ends if compiled else move_ends_reference_args
    b32: NDArray[np.float32] = ends(
        a,
        np.ascontiguousarray(noise[:, live]),
        length_m,
        heading_rad,
        params.step_sd_m,
        params.heading_sd_rad,
    )
    ok = np.asarray(valid_move(take_rows(p.floor, live), a, b32.astype(np.float64)), dtype=bool)
    if ok.shape != (n_live,):
        raise ValueError(f"valid_move must return shape ({n_live},), got {ok.shape}")
    log_w = p.log_w.astype(np.float64)
    if n_live == p.n and ok.all():
        return unchecked(p, xy=b32, log_w=normalised(log_w))
    moved, refused = np.flatnonzero(ok), np.flatnonzero(~ok)  # among the living
    if not isinstance(live, slice):
        moved, refused = live[moved], live[refused]
    xy = p.xy.copy()
    for axis in (0, 1):  # column by column: scattering whole rows is ~4x slower
        xy[moved, axis] = b32[:, axis][ok]
    log_w[refused] = -np.inf
    return unchecked(p, xy=xy, log_w=normalised(log_w))


def move_ends_reference(
    a: FloatArray, noise: FloatArray, length_m: float, heading_rad: float, params: ParticleParams
) -> NDArray[np.float32]:
    """``particle_kernels.step_ends`` in numpy: the rows of ``a`` moved by one noisy step each."""
    return move_ends_reference_args(
        a, noise, length_m, heading_rad, params.step_sd_m, params.heading_sd_rad
    )


def move_ends_reference_args(
    a: FloatArray,
    noise: FloatArray,
    length_m: float,
    heading_rad: float,
    step_sd_m: float,
    heading_sd_rad: float,
) -> NDArray[np.float32]:
    """``move_ends_reference`` with the noise scales given as ``particle_kernels.step_ends`` takes
    them."""
    length = noise[0] * step_sd_m
    length += length_m
    np.maximum(length, 0.0, out=length)
    heading = noise[1] * heading_sd_rad
    heading += heading_rad
    b32 = np.empty((a.shape[0], 2), dtype=np.float32)
    for axis, turn in ((0, np.sin), (1, np.cos)):
        step = turn(heading)
        step *= length
        step += a[:, axis]
        b32[:, axis] = step
    return b32
