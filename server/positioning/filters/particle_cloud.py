"""The particle cloud and its parameters (``papers/001_*`` section III-B), and the array
helpers the filter's steps (``server.positioning.filters.particle`` and its
``particle_*`` parts) share.

Numbers are stored as float32 (positions, log weights, magnitudes) and float64 only in
the arithmetic; see ``particle`` for the filter itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Literal, TypeVar

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import ArrayLike, NDArray

from server.positioning.model.params import NonNegative, Params, Positive, Share

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
FloorArray = NDArray[np.int16]

MoveCheck = Callable[[FloorArray, FloatArray, FloatArray], BoolArray]
"""``valid_move(floor (n,), a (n, 2), b (n, 2)) -> (n,) bool``: the move is allowed."""
PointCheck = Callable[[FloorArray, FloatArray], BoolArray]
"""``valid_point(floor (n,), xy (n, 2)) -> (n,) bool``: a particle may stand there."""
MapSampler = Callable[[FloorArray, FloatArray], ArrayLike]
"""``sample_map(floor (n,), xy (n, 2)) -> (n,)`` map magnitude in µT, NaN where unknown."""
Weighting = Literal["mass_centered", "dtw"]

MAX_PARTICLES = 20_000  # the most particles a session may ask for


@dataclass(frozen=True)
class ParticleParams(Params):
    """Parameters of the particle filter (``papers/001_*`` values where the paper has one)."""

    # particle count N, papers/001_* section IV-A; at most MAX_PARTICLES, which keeps a
    # session's step under some 20 ms and its stored state under 1 MB
    n: Annotated[int, Ge(1), Le(MAX_PARTICLES)] = 3000
    # sliding window W in steps, eq (b); section IV-B, Figure 8 (at most 50: the state
    # holds N x (W + 1) magnitudes)
    window: Annotated[int, Ge(1), Le(50)] = 3
    k: Positive = 70.0  # award parameter K, eq (c); section IV-B, Figure 9 (cancels, see above)
    t: Positive = 0.05  # award threshold T in µT, eq (c); section IV-B, Figure 10
    # delta of Algorithm 1 line 8 (the paper gives no value): 14 % of a 0.7 m step, above
    # the +-8 % distance error of Weinberg's step-length model (papers/002_* section 5.2),
    # since single steps vary more than a walked distance
    step_sd_m: NonNegative = 0.1
    # Delta of Algorithm 1 line 8 (no value in the paper): the phone heading error used
    # by step_ekf (r_heading_rad2)
    heading_sd_rad: NonNegative = math.radians(10.0)
    # resample when N_eff < fraction * N: ref [24] resamples below a threshold N_T, N/2
    # is the common choice; 1.0 resamples at every step as Algorithm 1 line 13
    resample_ess_fraction: Share = 0.5
    # disc radius around a WiFi/BLE fix: WiFi alone errs by more than 10 m at 80 %
    # (papers/001_* Figure 11), so the cloud must reach beyond that
    init_radius_m: Positive = 15.0
    # the DTW baseline's samples per step (particle_weight_update.py, "DTW baseline"): the
    # magnetometer samples a Magicol-style matcher compares over a step, a 50 Hz
    # magnetometer over the paper's 0.67 s step period (section IV-B); 1 compares the step
    # magnitudes only
    dtw_samples_per_step: Annotated[int, Ge(1), Le(100)] = 34


@dataclass(frozen=True)
class Particles:
    """A particle cloud; never modified in place (every step returns a new one).

    Attributes
    ----------
    xy : ndarray, shape (n, 2), float32
        Positions (m).
    floor : ndarray, shape (n,), int16
        Floor index of each particle.
    log_w : ndarray, shape (n,), float32
        Normalised log weights (``logsumexp(log_w) == 0``); ``-inf`` for a dead particle,
        all ``-inf`` when the cloud died.
    mags : ndarray, shape (n, W + 1), float32
        Map magnitudes (µT) at each particle's last ``W + 1`` positions, oldest first;
        only the last ``count`` columns are meaningful; NaN where the map is unknown.
    observed : ndarray, shape (W + 1,), float32
        Observed magnitudes (µT), oldest first; only the last ``count`` are meaningful.
    count : int
        Filled slots of the windows, ``0 <= count <= W + 1``.
    """

    xy: NDArray[np.float32]
    floor: FloorArray
    log_w: NDArray[np.float32]
    mags: NDArray[np.float32]
    observed: NDArray[np.float32]
    count: int

    def __post_init__(self) -> None:
        n = self.log_w.shape[0] if self.log_w.ndim == 1 else -1
        w = self.observed.shape[0] if self.observed.ndim == 1 else -1
        expected = {
            "xy": ((n, 2), np.float32),
            "floor": ((n,), np.int16),
            "log_w": ((n,), np.float32),
            "mags": ((n, w), np.float32),
            "observed": ((w,), np.float32),
        }
        for name, (shape, dtype) in expected.items():
            array = getattr(self, name)
            if array.shape != shape or array.dtype != dtype:
                raise ValueError(
                    f"{name} must be {np.dtype(dtype).name} of shape {shape}, "
                    f"got {array.dtype.name} of shape {array.shape}"
                )
        if w < 2:
            raise ValueError(f"the windows need W + 1 >= 2 slots, got {w}")
        if not 0 <= self.count <= w:
            raise ValueError(f"count must be in [0, {w}], got {self.count}")

    @property
    def n(self) -> int:
        """Number of particles (dead ones included)."""
        return int(self.log_w.shape[0])

    def check_decoded(self) -> None:
        """What a stored cloud must hold beyond its shapes (``state_codec``): finite
        positions, log weights finite or ``-inf``."""
        if not np.isfinite(self.xy).all():
            raise ValueError("xy must be finite")
        if np.isnan(self.log_w).any() or (self.log_w == np.inf).any():
            raise ValueError("log_w must be finite or -inf")


@dataclass(frozen=True)
class Estimate:
    """Position estimate of a cloud.

    Attributes
    ----------
    xy : ndarray, shape (2,), float64
        Weighted mean position (m).
    cov : ndarray, shape (2, 2), float64
        Weighted covariance of the particle positions (m^2).
    floor : int
        Floor holding the largest total weight.
    ess : float
        Effective sample size ``1 / sum w_i^2``.
    floor_prob : float
        Share of the weight on ``floor``.
    """

    xy: FloatArray
    cov: FloatArray
    floor: int
    ess: float
    floor_prob: float = 1.0


def from_points(xy: ArrayLike, floor: int, window: int) -> Particles:
    """A cloud of equally weighted particles at given points, windows empty.

    Parameters
    ----------
    xy : array_like, shape (n, 2)
        Positions (m), ``n >= 1``, finite (e.g. from ``floor_plan.random_walkable_points``).
    floor : int
        Floor index of every particle.
    window : int
        Window ``W`` in steps; the windows hold ``W + 1`` magnitudes.

    Returns
    -------
    Particles
    """
    pts = np.array(xy, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] == 0:
        raise ValueError(f"xy must have shape (n, 2) with n >= 1, got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("xy must be finite")
    if window < 1:
        raise ValueError(f"window must be at least 1, got {window}")
    n = pts.shape[0]
    return Particles(
        xy=pts,
        floor=np.full(n, floor, dtype=np.int16),
        log_w=np.full(n, -math.log(n), dtype=np.float32),
        mags=np.full((n, window + 1), np.nan, dtype=np.float32),
        observed=np.full(window + 1, np.nan, dtype=np.float32),
        count=0,
    )


def unchecked(p: Particles, **changes: object) -> Particles:
    """``dataclasses.replace`` of a cloud without ``__post_init__``'s checks, for the steps' own
    results (their arrays are right by construction): the checks cost ~10 µs a call,
    several times a step. Clouds from outside are checked (``Particles``,
    ``state_codec``)."""
    new = object.__new__(Particles)
    new.__dict__.update(p.__dict__)
    new.__dict__.update(changes)
    return new


def normalised(log_w: FloatArray) -> NDArray[np.float32]:
    """``log_w - logsumexp(log_w)`` as float32; all ``-inf`` stays all ``-inf``.

    The log-sum-exp is written out (shift by the maximum): ``scipy.special.logsumexp``
    takes 76 µs on 3,000 weights (scipy 1.17, array-API dispatch) against 7 µs here, and
    a step normalises twice.
    """
    finite = np.isfinite(log_w)
    live = log_w if finite.all() else log_w[finite]
    if live.size == 0:
        return np.full(log_w.shape, -np.inf, dtype=np.float32)
    top = float(live.max())
    shifted = live - top
    total = top + math.log(float(np.exp(shifted, out=shifted).sum()))
    shifted = log_w - total
    return shifted.astype(np.float32)


def live_rows(finite: BoolArray, n_live: int) -> slice | NDArray[np.intp]:
    """The living rows: all of them as a slice (a view, ~30 µs less per array at N = 3000
    than an index array), else their indices."""
    return slice(None) if n_live == finite.shape[0] else np.flatnonzero(finite)


_A = TypeVar("_A", bound=np.generic)


def take_rows(array: NDArray[_A], rows: slice | NDArray[np.intp]) -> NDArray[_A]:
    """``array[rows]`` along the first axis; ``np.take`` for an index array (fancy
    indexing of an (n, 2) array is ~8x slower, numpy 2.4)."""
    return array[rows] if isinstance(rows, slice) else np.take(array, rows, axis=0)


def weights(p: Particles) -> FloatArray:
    """Weights of a living cloud in float64, renormalised after the float32 rounding."""
    w = p.log_w.astype(np.float64)
    np.exp(w, out=w)
    w /= w.sum()
    return w
