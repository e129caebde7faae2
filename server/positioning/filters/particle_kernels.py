"""Compiled (numba) forms of the particle filter's hot loops, one particle at a time,
where numpy needs several passes over temporary arrays: the move, the weight update,
resampling and a whole step on one floor; and ``warm_up``, which compiles every kernel of
the filter (these, those of ``plan.move_test_kernels`` and those of
``magnetic.magnetic_kernels``).

Each kernel computes what its numpy reference computes, with the same float64 operations
in the same order, so the answers agree exactly (the tests compare them on random
inputs):

* ``step_ends``: ``particle_move.move_ends_reference`` -- the noisy ends of the moves,
  rounded to float32 (``sin`` and ``cos`` may differ from numpy's in the last bit);
* ``mass_centered_weights``: the mass-centered branch of
  ``particle_weight_update.weight_update`` after the map sampling (window shift, eq (b)-(c),
  the median for unknown windows and ``particle_cloud.normalised``), whose log-sum-exp adds
  in another order than numpy's pairwise sum: the float32 log weights agree to a unit in
  the last place;
* ``constrained_step``: ``particle.step``'s move and mass-centered update for a cloud on
  one floor, in one call over the kernels above, ``move_test_kernels.valid_moves`` and
  ``magnetic_kernels.bilinear`` (``particle.step_on_floor``), with
  ``effective_sample_size`` and ``systematic_rows`` (``particle_resampling._resample``'s
  rows, in one merge pass over the sorted points).

Compiled on first use and cached on disk (``cache=True``); no Python object crosses into
them. Numba checks a cached kernel against its own source file only, while these call the
kernels of two other files: on import, ``drop_stale_caches`` compares those files with the
stamp it left beside the cache and, when either changed, empties this module's cache, so
an edit of ``move_test_kernels`` or ``magnetic_kernels`` never leaves a stale compiled step.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from server.positioning.magnetic import magnetic_kernels
from server.positioning.magnetic.magnetic_kernels import GridArgs, bilinear, dtw, mmse
from server.positioning.plan import move_test_kernels
from server.positioning.plan.move_test_kernels import PlanArgs, moves_cross, valid_moves

FloatArray = NDArray[np.float64]


@njit(cache=True)
def step_ends(
    a: FloatArray,
    noise: FloatArray,
    length_m: float,
    heading_rad: float,
    step_sd_m: float,
    heading_sd_rad: float,
) -> NDArray[np.float32]:
    """``particle_move.move``'s new positions: ``a + max(S + σ_S n0, 0) (sin, cos)(θ + σ_θ n1)``
    rounded to float32; ``noise`` is (2, n) for the n rows of ``a``."""
    n = a.shape[0]
    out = np.empty((n, 2), dtype=np.float32)
    for k in range(n):
        length = max(noise[0, k] * step_sd_m + length_m, 0.0)
        heading = noise[1, k] * heading_sd_rad + heading_rad
        out[k, 0] = math.sin(heading) * length + a[k, 0]
        out[k, 1] = math.cos(heading) * length + a[k, 1]
    return out


@njit(cache=True)
def normalised(log_w: FloatArray) -> NDArray[np.float32]:
    """``particle_cloud.normalised``: ``log_w - logsumexp(log_w)`` as float32."""
    top = -np.inf
    for x in log_w:
        if math.isfinite(x) and x > top:
            top = x
    out = np.full(log_w.shape[0], -np.inf, dtype=np.float32)
    if top == -np.inf:
        return out
    total = 0.0
    for x in log_w:
        if math.isfinite(x):
            total += math.exp(x - top)
    total = top + math.log(total)
    for k in range(log_w.shape[0]):
        out[k] = log_w[k] - total
    return out


@njit(cache=True)
def mass_centered_weights(
    mags: NDArray[np.float32],
    live: NDArray[np.intp],
    m_live: FloatArray,
    observed: NDArray[np.float32],
    count: int,
    log_w: NDArray[np.float32],
    t: float,
    log_k: float,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``particle_weight_update.weight_update`` after the map sampling, for the
    mass-centered update: the windows shifted with the new map magnitudes (``m_live`` for
    the rows ``live``, NaN for the dead), then eq (b)-(c) and the normalisation; the log
    weights come back unchanged when there is nothing to weigh by."""
    n, slots = mags.shape
    shifted = np.empty((n, slots), dtype=np.float32)
    for k in range(n):
        for j in range(slots - 1):
            shifted[k, j] = mags[k, j + 1]
        shifted[k, slots - 1] = np.nan
    for r in range(live.shape[0]):
        shifted[live[r], slots - 1] = m_live[r]
    if count < 2 or live.shape[0] == 0:
        return shifted, log_w
    first = slots - count
    award = np.empty(live.shape[0])
    known = np.zeros(live.shape[0], dtype=np.bool_)
    for r in range(live.shape[0]):
        row = live[r]
        total = 0.0
        for j in range(first, slots - 1):
            step = abs(float(shifted[row, j + 1]) - float(shifted[row, j]))
            total += abs(step - abs(float(observed[j + 1]) - float(observed[j])))
        total /= count - 1
        if math.isfinite(total):
            known[r] = True
            award[r] = max(total, t)
    if not known.any():
        return shifted, log_w
    if not known.all():
        middle = np.median(award[known])
        for r in range(live.shape[0]):
            if not known[r]:
                award[r] = middle
    log_w64 = log_w.astype(np.float64)
    for r in range(live.shape[0]):
        log_w64[live[r]] += log_k - math.log(award[r])
    return shifted, normalised(log_w64)


@njit(cache=True)
def constrained_step(
    xy: NDArray[np.float32],
    log_w: NDArray[np.float32],
    mags: NDArray[np.float32],
    observed: NDArray[np.float32],
    count: int,
    noise: FloatArray,
    length_m: float,
    heading_rad: float,
    step_sd_m: float,
    heading_sd_rad: float,
    has_plan: bool,
    plan: PlanArgs,
    has_grid: bool,
    grid: GridArgs,
    weigh: bool,
    t: float,
    log_k: float,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], float]:
    """``particle_move.move`` and, when ``weigh``, the mass-centered update, for a cloud on one
    floor: each living particle moved (``step_ends``), its move tested (``valid_moves``
    when ``has_plan``, else only for a finite end), the log weights normalised, then the
    map sampled at the living particles (``bilinear`` when ``has_grid``, else unknown) and
    ``mass_centered_weights``. ``observed`` and ``count`` are the windows after the step.
    Returns the new positions, log weights and map windows and the effective sample size
    (0 for a dead cloud, which comes back as it went in when it was dead before)."""
    n = xy.shape[0]
    live = np.empty(n, dtype=np.intp)
    n_live = 0
    for k in range(n):
        if math.isfinite(log_w[k]):  # else -inf: dead
            live[n_live] = k
            n_live += 1
    if n_live == 0:
        return xy, log_w, mags, 0.0
    # the moves of the living, then the array kernels over them (a call per particle
    # to a compiled helper measured 2.5x slower than these loops)
    a = np.empty((n_live, 2))
    b = np.empty((n_live, 2))
    b32 = np.empty((n_live, 2), dtype=np.float32)
    for r in range(n_live):
        k = live[r]
        a[r, 0], a[r, 1] = xy[k, 0], xy[k, 1]
        length = max(noise[0, k] * step_sd_m + length_m, 0.0)
        heading = noise[1, k] * heading_sd_rad + heading_rad
        b32[r, 0] = math.sin(heading) * length + a[r, 0]
        b32[r, 1] = math.cos(heading) * length + a[r, 1]
        b[r, 0], b[r, 1] = b32[r, 0], b32[r, 1]
    if has_plan:
        ok = valid_moves(a, b, *plan)
    else:
        ok = np.empty(n_live, dtype=np.bool_)
        for r in range(n_live):
            ok[r] = math.isfinite(b[r, 0]) and math.isfinite(b[r, 1])
    new_xy = xy.copy()
    log_w64 = np.full(n, -np.inf)
    moved = 0
    for r in range(n_live):
        if ok[r]:
            k = live[r]
            new_xy[k, 0], new_xy[k, 1] = b32[r, 0], b32[r, 1]
            log_w64[k] = log_w[k]
            live[moved] = k  # the living after the move, in order
            b[moved, 0], b[moved, 1] = b[r, 0], b[r, 1]
            moved += 1
    new_log_w = normalised(log_w64)
    if moved == 0:
        return new_xy, new_log_w, mags, 0.0
    new_mags = mags
    if weigh:
        m_live = bilinear(b[:moved], *grid) if has_grid else np.full(moved, np.nan)
        new_mags, new_log_w = mass_centered_weights(
            mags, live[:moved], m_live, observed, count, new_log_w, t, log_k
        )
    return new_xy, new_log_w, new_mags, effective_sample_size(new_log_w)


@njit(cache=True)
def _weights(log_w: NDArray[np.float32]) -> FloatArray:
    """``particle_cloud.weights``: the float64 weights renormalised."""
    w: FloatArray = np.exp(log_w.astype(np.float64))
    w /= w.sum()
    return w


@njit(cache=True)
def effective_sample_size(log_w: NDArray[np.float32]) -> float:
    """``1 / sum w_i^2`` of the weights (0 when every particle is dead)."""
    w = _weights(log_w)
    total = 0.0
    for x in w:
        total += x * x
    return 1.0 / total if math.isfinite(total) and total > 0.0 else 0.0


@njit(cache=True)
def systematic_rows(log_w: NDArray[np.float32], u: float) -> NDArray[np.intp]:
    """``particle_resampling._resample``'s rows: for each point ``(u + k) / n`` the first particle
    whose cumulative weight exceeds it (``searchsorted(..., side="right")``), in one merge
    pass over the sorted points."""
    n = log_w.shape[0]
    cdf = np.cumsum(_weights(log_w))
    cdf /= cdf[-1]
    rows = np.empty(n, dtype=np.intp)
    j = 0
    for k in range(n):
        point = (u + k) / n
        while j < n - 1 and cdf[j] <= point:
            j += 1
        rows[k] = j
    return rows


# ``constrained_step`` without a plan or a map: arrays of the right types, never read
NO_PLAN: PlanArgs = (
    np.zeros(1, dtype=np.bool_), 0.0, 0.0, 1.0, 0, 0, np.zeros(1, dtype=np.uint8),
    np.zeros(256), 0, 0.0, 0.0, 1.0, 1.0, 0, 0, np.zeros(1, dtype=np.intp), np.zeros((0, 8)),
)  # fmt: skip
NO_GRID: GridArgs = (0.0, 0.0, 1.0, 0, 0, np.zeros(1), np.zeros(1), 0.0)


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel on tiny inputs, so the first
    request that needs one does not wait for the compiler (a few seconds when cold)."""
    xy = np.zeros((1, 2))
    start = np.zeros(2, dtype=np.intp)
    segments = np.zeros((0, 8))
    moves_cross(xy, xy, 0.0, 0.0, 1.0, 1.0, 1, 1, start, segments)
    valid_moves(
        xy, xy, np.ones(1, dtype=np.bool_), 0.0, 0.0, 1.0, 1, 1, np.zeros(1, dtype=np.uint8),
        np.zeros(256), 0, 0.0, 0.0, 1.0, 1.0, 1, 1, start, segments,
    )  # fmt: skip
    bilinear(xy, 0.0, 0.0, 1.0, 1, 1, np.zeros(1), np.ones(1), 1e-9)
    mmse(np.zeros(2), np.zeros((1, 2)))
    dtw(np.zeros(2), np.zeros((1, 2)))
    step_ends(xy, np.zeros((2, 1)), 0.7, 0.0, 0.1, 0.1)
    mags = np.zeros((1, 2), dtype=np.float32)
    live = np.zeros(1, dtype=np.intp)
    mass_centered_weights(
        mags, live, np.zeros(1), np.zeros(2, dtype=np.float32), 2,
        np.zeros(1, dtype=np.float32), 0.05, 4.2,
    )  # fmt: skip
    far = np.full((1, 2), 1e6, dtype=np.float32)  # outside the dummy plan and map
    log_w = np.zeros(1, dtype=np.float32)
    for known in (False, True):
        constrained_step(
            far, log_w, mags, np.zeros(2, dtype=np.float32), 2, np.zeros((2, 1)), 0.7, 0.0,
            0.1, 0.1, known, NO_PLAN, known, NO_GRID, known, 0.05, 4.2,
        )  # fmt: skip
    systematic_rows(log_w, 0.5)


CALLEES = (Path(move_test_kernels.__file__), Path(magnetic_kernels.__file__))
STAMP_NAME = "particle_kernels.callees"


def drop_stale_caches(callees: tuple[Path, ...] = CALLEES, stamp_dir: Path | None = None) -> bool:
    """Empty the disk cache of this module's kernels when a file whose kernels they call
    has changed since the stamp beside the cache was written (numba would not notice);
    True when it did. A cache that cannot be written (a read-only install) is left as it
    is: it was built from the files beside it."""
    kernels = [k for k in globals().values() if hasattr(k, "_cache") and hasattr(k, "py_func")]
    stamp = ";".join(f"{f.name}:{f.stat().st_mtime_ns}:{f.stat().st_size}" for f in callees)
    cache: Any = getattr(constrained_step, "_cache")  # noqa: B009 (numba's, untyped)
    where = (stamp_dir or Path(cache._cache_path)) / STAMP_NAME
    try:
        if where.read_text() == stamp:
            return False
    except OSError:
        pass
    try:
        for kernel in kernels:
            kernel._cache.flush()
        where.parent.mkdir(parents=True, exist_ok=True)
        where.write_text(stamp)
    except OSError:
        return False
    return True


drop_stale_caches()
