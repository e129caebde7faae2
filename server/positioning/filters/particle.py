"""Map-constrained particle filter with the mass-centered magnetic weight update.

The filter of ``papers/001_*`` (Shao et al.) section III-B, Algorithm 1, as pure steps
over an immutable particle cloud; the engine (WiFi/BLE initialisation, floor plans,
magnetic maps, re-initialisation policy) glues them together.

State. Particle ``i`` is ``(x_i, y_i, floor_i, log w_i)`` and the map magnitudes
``s_i^{t-W}, ..., s_i^t`` (µT) at its last ``W + 1`` positions, oldest first (NaN where
the map is unknown); the cloud also holds the observed magnitudes
``s_obs^{t-W}, ..., s_obs^t`` and how many of those ``W + 1`` slots are filled. The
magnitudes travel with their particle through resampling, so eq (b) compares each
particle's own history with the observed one.

Initialisation (Algorithm 1 lines 1-3): ``N`` particles uniform on the disc of radius
``r`` around the WiFi/BLE fix ``l`` (redrawn until they are reachable, when a test is
given), all with weight ``1/N``.

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

Mass-centered weight update (section III-C/D, eq b-c). After each step the map magnitude
at the new positions and the observed magnitude enter the windows, and::

    MMSE(i, t) = 1/W sum_{j=0}^{W-1} | |s_i^{t-j} - s_i^{t-j-1}| - |s_obs^{t-j} - s_obs^{t-j-1}| |
                                                                                         (b)
    w_i^t = K w_i^{t-1} / max(MMSE(i, t), T)                                             (c)

(``magnetic.sequence_distance.mmse``). Until the window is full the mean runs over the steps
it holds; with fewer than two magnitudes the weights are left alone. Weights are
kept as normalised logarithms: ``log w_i <- log w_i + log K - log max(MMSE, T)``, then
``log w_i -= log sum_j exp(log w_j)``. ``K`` multiplies every weight alike, so it cancels
in this normalisation (and in any resampling, which only sees relative weights): eq (c)
as printed does not depend on ``K``. The paper's sensitivity to ``K`` (Figure 9) must come from
something the paper does not print; ``K`` is applied anyway so the update is eq (c) as
written. A particle whose window meets an unknown map cell has no MMSE; it is neither
rewarded nor punished but gets the median ``max(MMSE, T)`` of the living particles that
have one (with none, the weights stay as they are). The paper's map covers every
reachable place, so it has no such rule.

DTW baseline (section IV-B, the Magicol method [11]): the same filter and window, with
the classic DTW distance ``D_i`` between the observed and the particle's magnetic
sequences over the window (``server.positioning.magnetic.sequence_distance.dtw_distance``) in place
of the MMSE::

    w_i^t = K w_i^{t-1} / max(D_i / L, T)

A Magicol-style matcher compares the magnetometer's samples over the last steps, not one
magnitude per step, and its cost grows with the square of the sequence length: the
sequences here hold ``dtw_samples_per_step`` samples per step (``L = W m + 1`` for a full
window; the default, 34, is a 50 Hz magnetometer over the paper's 0.67 s step period), so
the baseline does the work the paper timed. A step event carries one magnitude, and the
cloud keeps one map magnitude per particle and step, so both sequences are interpolated
linearly between those (``sequence_distance.densified``); ``dtw_samples_per_step = 1``
compares the step magnitudes alone. Only the sequence distance changes -- same award,
same cap, same window, same treatment of unknown cells. ``D_i / L`` is, like the MMSE, a
mean absolute error in µT per sample (a constant error ``e`` gives ``e`` in both), so
``T`` means the same for both. DTW compares raw magnitudes: unlike eq (b) it does not
cancel a magnetometer offset (section II, Figure 1).

Resampling: systematic (``papers/001_*`` ref [24], Arulampalam et al. 2002, Algorithm 2)
with one uniform draw ``u ~ U[0, 1/N)`` and the ``N`` points ``u + k/N``; particle ``i``
is copied ``floor(N w_i)`` or ``ceil(N w_i)`` times; weights reset to ``1/N``. Algorithm 1
resamples at every step; here (``step``) the cloud is resampled when the effective sample
size ``N_eff = 1 / sum w_i^2`` falls below ``resample_ess_fraction * N`` (ref [24]
resamples below a threshold ``N_T``; ``N_T = N/2`` by default, the common choice), which
keeps the weights' memory across steps where the field says little;
``resample_ess_fraction = 1`` resamples at every step whose weights are not all equal, as
Algorithm 1 does (on the acceptance corridor of the tests both converge alike).

Estimate: the weighted mean ``sum w_i (x_i, y_i)`` (Algorithm 1 line 14 is the plain mean
of the resampled particles, the same thing in expectation) with the weighted covariance
``sum w_i (p_i - mean)(p_i - mean)^T`` as its uncertainty, the floor holding most weight,
and ``N_eff``.

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
    Estimate,
    MapSampler,
    MoveCheck,
    ParticleParams,
    Particles,
    PointCheck,
    Weighting,
    from_points,
    live_rows,
    normalised,
    take_rows,
    unchecked,
    weights,
)
from server.positioning.magnetic import field_grid
from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.magnetic.sequence_distance import densified, dtw_distance, mmse
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


def mass_centered_update(
    p: Particles, observed_ut: float, sample_map: MapSampler, params: ParticleParams
) -> Particles:
    """Push a step's magnitudes into the windows and weight by eq (b)-(c).

    Parameters
    ----------
    p : Particles
        After ``move`` (or just initialised, to record the first magnitude).
    observed_ut : float
        Field magnitude the phone measured at this step (µT), finite.
    sample_map : callable
        ``sample_map(floor (m,), xy (m, 2)) -> (m,)`` map magnitude, NaN where unknown;
        called with the living particles only.
    params : ParticleParams

    Returns
    -------
    Particles
    """
    return _weight_update(p, observed_ut, sample_map, params, "mass_centered")


def dtw_update(
    p: Particles, observed_ut: float, sample_map: MapSampler, params: ParticleParams
) -> Particles:
    """As ``mass_centered_update`` with the DTW distance of the baseline (module docstring)."""
    return _weight_update(p, observed_ut, sample_map, params, "dtw")


def alive(p: Particles) -> bool:
    """Whether any particle has a finite weight."""
    return bool(np.isfinite(p.log_w).any())


def effective_sample_size(p: Particles) -> float:
    """``N_eff = 1 / sum w_i^2`` (0 for a dead cloud)."""
    if not alive(p):
        return 0.0
    w = weights(p)
    return float(1.0 / np.dot(w, w))


def systematic_resample(p: Particles, rng: np.random.Generator) -> Particles:
    """Systematic resampling (ref [24]); ``N`` kept, weights reset to ``1/N``.

    Parameters
    ----------
    p : Particles
        A living cloud.
    rng : numpy.random.Generator
        Draws one uniform number.

    Returns
    -------
    Particles
        Rows (position, floor, map magnitudes) copied by ``searchsorted`` of the points
        ``(u + k) / N`` in the cumulative weights; the observed window is shared.

    Raises
    ------
    ValueError
        When every particle is dead.
    """
    if not alive(p):
        raise ValueError("cannot resample a cloud whose particles are all dead")
    return _resample(p, weights(p), rng)


def _resample(p: Particles, w: FloatArray, rng: np.random.Generator) -> Particles:
    """``systematic_resample`` of a living cloud with weights ``w`` (``_weights``)."""
    n = p.n
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    # points below 1, so the index stays below n; a dead particle (zero weight) spans an
    # empty interval [cdf[i-1], cdf[i]) and is never chosen
    points = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cdf, points, side="right")
    return unchecked(
        p,
        xy=np.take(p.xy, idx, axis=0),
        floor=p.floor.take(idx),
        log_w=np.full(n, -math.log(n), dtype=np.float32),
        mags=np.take(p.mags, idx, axis=0),
    )


def estimate(p: Particles) -> Estimate:
    """Weighted mean, weighted covariance, majority floor by weight (and the weight on
    it) and ``N_eff``.

    Raises
    ------
    ValueError
        When every particle is dead.
    """
    if not alive(p):
        raise ValueError("a cloud whose particles are all dead has no estimate")
    w, d, mean = _weighted_mean(p)
    # d = xy - mean (in place of the float64 copy) and d * w[:, None], column by column:
    # broadcasting over rows of two is ~3x slower (the same numbers, the same C-ordered
    # arrays for the product)
    dw = np.empty_like(d)
    for axis in (0, 1):
        np.subtract(d[:, axis], mean[axis], out=d[:, axis])
        np.multiply(d[:, axis], w, out=dw[:, axis])
    cov = dw.T @ d
    cov = 0.5 * (cov + cov.T)
    floor, floor_prob = _majority_floor(p, w)
    ess = float(1.0 / np.dot(w, w))
    return Estimate(xy=mean, cov=cov, floor=floor, ess=ess, floor_prob=floor_prob)


def position(p: Particles) -> tuple[FloatArray, int]:
    """``estimate``'s mean and floor alone (what a scan compares with its fix), without
    the covariance.

    Raises
    ------
    ValueError
        When every particle is dead.
    """
    if not alive(p):
        raise ValueError("a cloud whose particles are all dead has no estimate")
    w, _, mean = _weighted_mean(p)
    return mean, _majority_floor(p, w)[0]


def _weighted_mean(p: Particles) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The weights, the positions (a float64 copy, the caller's to change) and their
    weighted mean, of a living cloud."""
    w = weights(p)
    xy = p.xy.astype(np.float64)
    return w, xy, w @ xy


def _majority_floor(p: Particles, w: FloatArray) -> tuple[int, float]:
    """The floor holding the most weight and the share it holds."""
    first = p.floor[0]
    if (p.floor == first).all():  # one floor: no need to sort them
        return int(first), 1.0
    floors, which = np.unique(p.floor, return_inverse=True)
    per_floor = np.bincount(which, weights=w)
    return int(floors[np.argmax(per_floor)]), float(per_floor.max())


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
        The step (``move``).
    observed_ut : float or None
        Magnitude measured at the step (µT); None when the phone sent none (no update).
    rng : numpy.random.Generator
    params : ParticleParams
    valid_move, sample_map : callable
        As in ``move`` and ``mass_centered_update``.
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
        p = _weight_update(p, observed_ut, sample_map, params, weighting, compiled)
    return resample_when_low(p, rng, params)


def resample_when_low(p: Particles, rng: np.random.Generator, params: ParticleParams) -> Particles:
    """``systematic_resample`` of a living cloud whose ``N_eff`` fell below
    ``params.resample_ess_fraction * N`` (module docstring, "Resampling"), else the cloud
    as it is."""
    w = weights(p)  # as effective_sample_size and systematic_resample, computed once
    if 1.0 / np.dot(w, w) < params.resample_ess_fraction * p.n:
        return _resample(p, w, rng)
    return p


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


def _weight_update(
    p: Particles,
    observed_ut: float,
    sample_map: MapSampler,
    params: ParticleParams,
    weighting: Weighting,
    compiled: bool = True,
) -> Particles:
    """Shared body of the two updates (module docstring); the mass-centered one after the
    map sampling in one compiled pass (``particle_kernels.mass_centered_weights``) unless
    ``compiled`` is False (the numpy reference below, which the DTW baseline runs)."""
    if not math.isfinite(observed_ut):
        raise ValueError(f"observed_ut must be finite, got {observed_ut}")
    slots = p.observed.shape[0]
    if slots != params.window + 1:
        raise ValueError(f"cloud window {slots - 1} differs from params.window {params.window}")
    finite = np.isfinite(p.log_w)
    n_live = int(np.count_nonzero(finite))
    live = live_rows(finite, n_live)
    xy = take_rows(p.xy, live).astype(np.float64)
    m_live = np.asarray(sample_map(take_rows(p.floor, live), xy), np.float64)
    if m_live.shape != (n_live,):
        raise ValueError(f"sample_map must return shape ({n_live},), got {m_live.shape}")
    observed = np.append(p.observed[1:], np.float32(observed_ut))
    count = min(p.count + 1, slots)
    if compiled and weighting == "mass_centered":
        rows = np.arange(p.n, dtype=np.intp) if isinstance(live, slice) else live
        mags, log_w32 = particle_kernels.mass_centered_weights(
            np.ascontiguousarray(p.mags),
            rows,
            m_live,
            observed,
            count,
            np.ascontiguousarray(p.log_w),
            params.t,
            math.log(params.k),
        )
        return unchecked(p, mags=mags, observed=observed, count=count, log_w=log_w32)
    # the windows move one slot to the left; the new magnitudes fill the last column
    mags = np.empty(p.mags.shape, dtype=np.float32)
    # shifted through the flat buffer (a strided 2-D copy is ~10x slower): row i's
    # last slot briefly holds row i + 1's oldest magnitude, then the new one
    mags.reshape(-1)[:-1] = p.mags.reshape(-1)[1:]
    if n_live == p.n:
        mags[:, -1] = m_live
    else:
        mags[:, -1] = np.nan
        mags[live, -1] = m_live
    out = unchecked(p, mags=mags, observed=observed, count=count)
    if count < 2 or n_live == 0:
        return out
    obs = observed[-count:]
    cand = take_rows(mags, live)[:, -count:]
    if weighting == "mass_centered":
        d = mmse(obs, cand)
    else:  # the sampled sequences of the DTW baseline (module docstring)
        per_step = params.dtw_samples_per_step
        seq, sampled = densified(obs, per_step), densified(cand, per_step)
        distance = particle_kernels.dtw if compiled else dtw_distance
        d = distance(seq, np.ascontiguousarray(sampled)) / seq.shape[0]
    known = np.isfinite(d)
    if not known.any():
        return out
    award = np.maximum(d, params.t)  # eq (c): K / max(distance, T)
    if not known.all():
        award[~known] = np.median(award[known])
    gain = np.log(award)
    np.subtract(math.log(params.k), gain, out=gain)
    log_w = p.log_w.astype(np.float64)
    if n_live == p.n:
        log_w += gain
    else:
        log_w[live] += gain
    return unchecked(out, log_w=normalised(log_w))


def mass_centered_update_reference(
    p: Particles, observed_ut: float, sample_map: MapSampler, params: ParticleParams
) -> Particles:
    """``mass_centered_update`` in numpy (the reference the compiled pass is tested
    against)."""
    return _weight_update(p, observed_ut, sample_map, params, "mass_centered", compiled=False)


def reweight(p: Particles, log_likelihood: ArrayLike) -> Particles:
    """Weights multiplied by a likelihood given as its log per particle, normalised."""
    ll = np.asarray(log_likelihood, dtype=np.float64)
    log_w = normalised(np.add(p.log_w, ll, dtype=np.float64))
    if log_w.shape != p.log_w.shape:
        raise ValueError(f"log_likelihood must broadcast to shape {p.log_w.shape}, got {ll.shape}")
    return unchecked(p, log_w=log_w)


def _disc(c: FloatArray, radius: float, m: int, rng: np.random.Generator) -> FloatArray:
    """``m`` points uniform on a disc, rounded to float32 and returned as float64."""
    u = rng.random((2, m))
    r = radius * np.sqrt(u[0])
    phi = 2.0 * math.pi * u[1]
    pts = np.column_stack([c[0] + r * np.cos(phi), c[1] + r * np.sin(phi)])
    return pts.astype(np.float32).astype(np.float64)
