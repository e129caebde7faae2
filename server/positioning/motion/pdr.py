"""Pedestrian dead reckoning from raw accelerometer samples: steps and their lengths.

Step detection, three detectors on one pipeline
---------------------------------------------
Samples are first put on a uniform grid of ``grid_ms`` at fixed multiples of absolute
time (linear interpolation), so the result does not depend on the phone's rate or on how
the samples were cut into batches. On the grid:

* gravity ``g`` is the running mean of the acceleration magnitude (a first-order
  low-pass with ``gravity_tau_s``; ``papers/002_*`` eq 6 averages the magnitude while the
  phone is static, and walking averages to the same value);
* the detector signal is

  - ``"cui"`` and ``"wang"``: the magnitude minus gravity, ``a_i - g`` (``papers/002_*``
    eq 5);
  - ``"mansour"``: the acceleration along the vertical minus gravity (``papers/003_*``
    section III: "peak and valley of the vertical acceleration relative to the surface of
    the Earth"), the vertical being the low-passed acceleration direction;

* the signal is smoothed by a centred moving average over ``2N + 1`` grid samples
  (``papers/002_*`` eq 7), which is also the low-pass filter of ``papers/003_*`` III.

Then local extrema of the smoothed signal drive one of three state machines:

* ``"cui"`` (``papers/002_*`` section 5.1): a step at every peak above
  ``threshold_ms2`` at least ``min_step_ms`` after the previous one;
* ``"mansour"`` (``papers/003_*`` section III): a peak above ``+threshold_ms2``
  (0.65 m/s² in the paper) must be followed by a valley below ``-threshold_ms2`` between
  ``min_peak_valley_ms`` (the paper's 100 ms) and ``max_peak_valley_ms`` later; extra
  extremes of the same sign within ``false_extreme_ms`` are false extremes and only the
  largest counts; steps are at least ``min_step_ms`` apart (the 0.2 s shortest gait
  cycle of the paper);
* ``"wang"`` (``papers/004_*`` Algorithm 2, "Motion analysis"): the acceleration rises
  from a minimum to the next maximum; that rise is a step when it lasts between
  ``min_peak_valley_ms`` and ``max_peak_valley_ms`` (Wang's ``[T_min, T_max]``) and spans
  between ``wang_min_rise_ms2`` and ``wang_max_rise_ms2`` (``[Δa_min, Δa_max]``; the
  paper gives no values: twice ``threshold_ms2``, and 20 m/s²), ends above
  ``threshold_ms2`` (a peak, not the return to rest after the last step) and comes at
  least ``min_step_ms`` after the previous step. Algorithm 2's step-length update at turns is
  ``calibrated_step_m`` below (and the ``map_markov`` engine's personal scale).

Everything is incremental: the state carries the last raw sample, the filter memories,
the un-smoothed tail and the state machine, so a step that straddles two batches is found
once, at the same time and with the same length as if the samples had come in one batch.

Step length
-----------
From the step's peak-to-valley range ``Δa`` of the smoothed signal:

* ``"weinberg"``: ``S = K (Δa)^(1/4)`` (``papers/002_*`` eq 8) with ``K = 0.861`` (their
  Table 2). Their K reproduces their trained 0.6 m steps only for ``Δa`` in units of g
  (``(0.6 / 0.861)^4 = 0.236``), so ``Δa`` is divided by g here;
* ``"mansour"``: ``sl = m (Δa)^(1/4)`` clamped to [0.6, 0.9] m with ``m = 0.55`` and
  ``Δa`` in m/s² (``papers/003_*`` eq 1).

``calibrated_step_m`` is ``papers/003_*`` eq 18 (and the step-length update of
``papers/004_*`` Algorithm 2): the distance between two known points walked in a
straight line divided by the number of steps between them.

Turns and straight walking are labelled per step by ``turns``, and straight stretches
are straightened by ``straight_lines``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Annotated, Literal

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray
from scipy.signal import lfilter

from server.positioning.model.params import AtLeastOne, NonNegativeInt, ParamError, Params, Positive
from server.positioning.model.state_codec import shape

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

G = 9.80665

Detector = Literal["mansour", "cui", "wang"]
LengthModel = Literal["mansour", "weinberg"]


@dataclass(frozen=True)
class PdrParams(Params):
    """Step detection and step length parameters (paper values where the paper has one)."""

    detector: Detector = "mansour"
    length_model: LengthModel = "mansour"
    grid_ms: Annotated[int, Ge(5), Le(1000)] = (
        20  # 50 Hz grid, the rate of the phones in papers/003_* and ILC 2.0
    )
    half_window: Annotated[int, Ge(1), Le(100)] = 5  # N of papers/002_* eq 7: 11 samples, 0.22 s
    gravity_tau_s: Positive = 5.0
    vertical_tau_s: Positive = 1.0  # low-pass giving the vertical for the "mansour" signal
    threshold_ms2: Positive = 0.65  # papers/003_* III
    min_peak_valley_ms: NonNegativeInt = 100  # papers/003_* III
    max_peak_valley_ms: AtLeastOne = 800  # half of the longest gait cycle, 1.6 s (papers/003_*)
    min_step_ms: NonNegativeInt = 200  # shortest gait cycle, 0.2 s (papers/003_* III)
    false_extreme_ms: NonNegativeInt = 150
    weinberg_k: Positive = 0.861  # papers/002_* Table 2
    mansour_m: Positive = 0.55  # papers/003_* eq 1
    min_step_m: Positive = 0.6  # papers/003_* eq 1
    max_step_m: Positive = 0.9  # papers/003_* eq 1
    max_gap_ms: AtLeastOne = 2000  # a longer gap between samples restarts the detector
    wang_min_rise_ms2: Positive = 1.3  # Δa_min of papers/004_* Algorithm 2 (no value given)
    wang_max_rise_ms2: Positive = 20.0  # Δa_max of papers/004_* Algorithm 2 (no value given)

    def check(self) -> None:
        if not self.min_step_m <= self.max_step_m:
            raise ParamError("max_step_m", "must not be below min_step_m")
        if not self.wang_min_rise_ms2 <= self.wang_max_rise_ms2:
            raise ParamError("wang_max_rise_ms2", "must not be below wang_min_rise_ms2")


@dataclass(frozen=True)
class Steps:
    """Steps found in a batch, in time order.

    Attributes
    ----------
    t_ms : ndarray, shape (k,), int64
        Time of each step (its completing extreme on the grid).
    accel_range : ndarray, shape (k,), float64
        Peak-to-valley range of the smoothed signal over the step, m/s².
    gravity : ndarray, shape (k,), float64
        The gravity estimate at the step, m/s².
    """

    t_ms: IntArray
    accel_range: FloatArray
    gravity: FloatArray

    def __len__(self) -> int:
        return int(self.t_ms.size)


_NO_STEPS = Steps(np.empty(0, np.int64), np.empty(0), np.empty(0))


# slots of DetectorState.machine
_MACHINE = (
    "phase",  # 0: waiting for a peak, 1: have a peak, 2: have a valley (mansour)
    "peak_t",
    "peak_v",
    "valley_t",
    "valley_v",
    "valley_g",
    "last_step_t",  # time of the last step (-inf before any)
    "run_min",  # cui: minimum of the signal since the last peak
)
_I = {name: i for i, name in enumerate(_MACHINE)}


@dataclass(frozen=True, kw_only=True)
class DetectorState:
    """Everything the detector carries from one batch to the next (small, fixed size
    apart from ``tail``, which holds at most ``2N + 2`` values)."""

    # [t_ms, x, y, z] of the last raw sample; t NaN before any
    last_raw: FloatArray = field(metadata=shape(4))
    next_grid_ms: float  # next grid time to produce; NaN before any sample
    # last low-passed magnitude (the gravity estimate)
    gravity_lp: FloatArray = field(metadata=shape(1))
    vertical_lp: FloatArray = field(metadata=shape(3))  # last low-passed acceleration vector
    initialized: bool
    tail_t: FloatArray  # grid times whose raw signal is kept for the moving average
    tail_v: FloatArray  # raw signal at tail_t
    tail_g: FloatArray  # gravity at tail_t
    # last two smoothed [t, value, gravity]; NaN rows when absent
    smooth: FloatArray = field(metadata=shape(2, 3))
    machine: FloatArray = field(metadata=shape(len(_MACHINE)))  # state machine, see _MACHINE


def initial_detector() -> DetectorState:
    machine = np.full(len(_MACHINE), np.nan)
    machine[_I["phase"]] = 0.0
    machine[_I["last_step_t"]] = -np.inf
    machine[_I["run_min"]] = np.inf
    return DetectorState(
        last_raw=np.full(4, np.nan),
        next_grid_ms=math.nan,
        gravity_lp=np.full(1, G),
        vertical_lp=np.array([0.0, 0.0, G]),
        initialized=False,
        tail_t=np.empty(0),
        tail_v=np.empty(0),
        tail_g=np.empty(0),
        smooth=np.full((2, 3), np.nan),
        machine=machine,
    )


def _low_pass(x: FloatArray, tau_s: float, grid_ms: int, y0: FloatArray) -> FloatArray:
    """First-order low-pass ``y_k = y_{k-1} + alpha (x_k - y_{k-1})`` along axis 0,
    continuing from the previous outputs ``y0`` (one per column)."""
    alpha = 1.0 - math.exp(-grid_ms / 1000.0 / tau_s)
    zi = (1.0 - alpha) * np.atleast_1d(y0)[None, :]
    y = lfilter([alpha], [1.0, alpha - 1.0], x.reshape(x.shape[0], -1), axis=0, zi=zi)[0]
    return np.asarray(y, dtype=np.float64).reshape(x.shape)


def _resample(
    state: DetectorState, accel: FloatArray, params: PdrParams
) -> tuple[FloatArray, FloatArray, float, FloatArray]:
    """Grid times and accelerations between the last grid time and the newest sample."""
    t = accel[:, 0]
    xyz = accel[:, 1:4]
    if not math.isnan(state.last_raw[0]):
        t = np.concatenate([[state.last_raw[0]], t])
        xyz = np.vstack([state.last_raw[1:], xyz])
    if math.isnan(state.next_grid_ms):
        start = math.ceil(t[0] / params.grid_ms) * params.grid_ms
    else:
        start = state.next_grid_ms
    grid = np.arange(start, t[-1] + 0.5, params.grid_ms, dtype=np.float64)
    grid = grid[grid <= t[-1]]
    values = np.column_stack([np.interp(grid, t, xyz[:, i]) for i in range(3)])
    next_grid = float(grid[-1] + params.grid_ms) if grid.size else start
    return grid, values, next_grid, np.concatenate([[t[-1]], xyz[-1]])


def _signal(
    state: DetectorState, values: FloatArray, params: PdrParams
) -> tuple[FloatArray, FloatArray, DetectorState]:
    """Detector signal and gravity per grid sample, with the filter memories advanced."""
    magnitude = np.linalg.norm(values, axis=1)
    # gravity starts at its nominal value (the first sample may be mid-stride); the
    # vertical starts along the first sample
    g0 = state.gravity_lp if state.initialized else np.array([G])
    v0 = state.vertical_lp if state.initialized else values[0]
    gravity = _low_pass(magnitude, params.gravity_tau_s, params.grid_ms, g0)
    if params.detector in ("cui", "wang"):
        signal = magnitude - gravity
        vertical_lp = v0
    else:
        down = _low_pass(values, params.vertical_tau_s, params.grid_ms, v0)
        vertical_lp = down[-1]
        up = down / np.maximum(np.linalg.norm(down, axis=1, keepdims=True), 1e-9)
        signal = np.einsum("ij,ij->i", values, up) - gravity
    new = replace(
        state, gravity_lp=gravity[-1:].copy(), vertical_lp=vertical_lp.copy(), initialized=True
    )
    return np.asarray(signal, dtype=np.float64), np.asarray(gravity, dtype=np.float64), new


def detect_steps(
    state: DetectorState, accel: FloatArray, params: PdrParams
) -> tuple[DetectorState, Steps]:
    """Find the steps completed by a new block of accelerometer samples.

    Parameters
    ----------
    state : DetectorState
        From the previous block (``initial_detector()`` at the start).
    accel : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` in m/s², gravity included, times strictly increasing and
        after the previous block's.
    params : PdrParams

    Returns
    -------
    state : DetectorState
    steps : Steps
        Steps whose completing extreme is now certain. A step near the end of the block
        may only come out with the next block.
    """
    if accel.shape[0] == 0:
        return state, _NO_STEPS
    gaps = np.flatnonzero(np.diff(accel[:, 0]) > params.max_gap_ms) + 1
    if gaps.size:  # a gap inside the block: each side on its own, the detector restarting
        found = []
        for part in np.split(accel, gaps):
            state, part_steps = detect_steps(state, part, params)
            found.append(part_steps)
        return state, _steps(
            [int(t) for f in found for t in f.t_ms],
            [float(r) for f in found for r in f.accel_range],
            [float(g) for f in found for g in f.gravity],
        )
    if not math.isnan(state.last_raw[0]) and accel[0, 0] - state.last_raw[0] > params.max_gap_ms:
        state = initial_detector()  # a long gap: nothing before it belongs to a step
    grid, values, next_grid, last_raw = _resample(state, accel, params)
    state = replace(state, next_grid_ms=next_grid, last_raw=last_raw)
    if grid.size == 0:
        return state, _NO_STEPS
    signal, gravity, state = _signal(state, values, params)

    # centred moving average (papers/002_* eq 7) over the carried tail plus the new values
    n = params.half_window
    t_all = np.concatenate([state.tail_t, grid])
    v_all = np.concatenate([state.tail_v, signal])
    g_all = np.concatenate([state.tail_g, gravity])
    width = 2 * n + 1
    if v_all.size >= width:
        window = np.convolve(v_all, np.ones(width) / width, mode="valid")
        centre_t = t_all[n : n + window.size]
        centre_g = g_all[n : n + window.size]
        keep = v_all.size - (width - 1)
        tail_t, tail_v, tail_g = t_all[keep:], v_all[keep:], g_all[keep:]
    else:
        window = centre_t = centre_g = np.empty(0)
        tail_t, tail_v, tail_g = t_all, v_all, g_all
    state = replace(state, tail_t=tail_t, tail_v=tail_v, tail_g=tail_g)

    # extrema need one smoothed value on each side: prepend the two carried ones
    carried = state.smooth[~np.isnan(state.smooth[:, 0])]
    smooth = np.vstack([carried, np.column_stack([centre_t, window, centre_g])])
    state = replace(state, smooth=np.vstack([np.full((2, 3), np.nan), smooth])[-2:])
    if smooth.shape[0] < 3:
        return state, _NO_STEPS
    s_v = smooth[:, 1]
    mid = s_v[1:-1]
    is_max = (mid > s_v[:-2]) & (mid >= s_v[2:])
    is_min = (mid < s_v[:-2]) & (mid <= s_v[2:])
    idx = np.flatnonzero(is_max | is_min) + 1
    machine, steps = _run_machine(
        state.machine.copy(),
        smooth[idx],
        is_max[idx - 1],
        float(smooth[-2, 0]),  # the newest time whose extremum status is known
        params,
    )
    state = replace(state, machine=machine)
    return state, steps


def _run_machine(
    m: FloatArray,
    extrema: FloatArray,
    maxima: NDArray[np.bool_],
    known_until: float,
    params: PdrParams,
) -> tuple[FloatArray, Steps]:
    """Feed the extrema (rows ``[t, value, gravity]``, in time order) to the detector's
    state machine."""
    times, values, gravity = extrema[:, 0], extrema[:, 1], extrema[:, 2]
    out_t: list[int] = []
    out_range: list[float] = []
    out_g: list[float] = []
    thr = params.threshold_ms2

    def emit(t: float, rng: float, g: float) -> None:
        out_t.append(round(t))
        out_range.append(rng)
        out_g.append(g)
        m[_I["last_step_t"]] = t

    if params.detector == "cui":
        for t, v, is_max, g in zip(times, values, maxima, gravity, strict=True):
            if not is_max:
                m[_I["run_min"]] = min(m[_I["run_min"]], v)
                continue
            if v > thr and t - m[_I["last_step_t"]] >= params.min_step_ms:
                low = m[_I["run_min"]]
                emit(t, v - low if math.isfinite(low) else 2.0 * v, g)
                m[_I["run_min"]] = math.inf
        return m, _steps(out_t, out_range, out_g)

    if params.detector == "wang":
        for t, v, is_max, g in zip(times, values, maxima, gravity, strict=True):
            if not is_max:  # minAc, minTS of Algorithm 2
                m[_I["run_min"]], m[_I["valley_t"]] = v, t
                continue
            low, since = m[_I["run_min"]], t - m[_I["valley_t"]]
            m[_I["run_min"]] = math.inf
            early = t - m[_I["last_step_t"]] < params.min_step_ms
            if not math.isfinite(low) or early or v <= params.threshold_ms2:
                continue
            rise = v - low
            if (
                params.min_peak_valley_ms <= since <= params.max_peak_valley_ms
                and params.wang_min_rise_ms2 <= rise <= params.wang_max_rise_ms2
            ):
                emit(t, rise, g)
        return m, _steps(out_t, out_range, out_g)

    for t, v, is_max, g in zip(times, values, maxima, gravity, strict=True):
        phase = m[_I["phase"]]
        if phase == 2 and t - m[_I["valley_t"]] > params.false_extreme_ms:
            _emit_valley(m, emit, params.min_step_ms)
            phase = 0
        if is_max and v > thr:
            if phase == 1 and t - m[_I["peak_t"]] <= params.false_extreme_ms:
                if v > m[_I["peak_v"]]:  # a false extreme: keep the larger peak
                    m[_I["peak_t"]], m[_I["peak_v"]] = t, v
            elif phase != 2:
                m[_I["phase"]], m[_I["peak_t"]], m[_I["peak_v"]] = 1, t, v
        elif not is_max and v < -thr:
            if phase == 2:
                if v < m[_I["valley_v"]]:  # a false extreme: keep the deeper valley
                    m[_I["valley_t"]], m[_I["valley_v"]], m[_I["valley_g"]] = t, v, g
            elif phase == 1:
                gap = t - m[_I["peak_t"]]
                if gap > params.max_peak_valley_ms:
                    m[_I["phase"]] = 0  # the peak was too long ago to pair with this valley
                elif gap >= params.min_peak_valley_ms:
                    m[_I["phase"]], m[_I["valley_t"]], m[_I["valley_v"]] = 2, t, v
                    m[_I["valley_g"]] = g
    if m[_I["phase"]] == 2 and known_until - m[_I["valley_t"]] > params.false_extreme_ms:
        _emit_valley(m, emit, params.min_step_ms)
    return m, _steps(out_t, out_range, out_g)


def _emit_valley(
    m: FloatArray, emit: Callable[[float, float, float], None], min_step_ms: float
) -> None:
    """Close a peak-valley pair as a step unless it follows the last step too soon."""
    t = m[_I["valley_t"]]
    if t - m[_I["last_step_t"]] >= min_step_ms:
        emit(t, m[_I["peak_v"]] - m[_I["valley_v"]], m[_I["valley_g"]])
    m[_I["phase"]] = 0


def _steps(t: list[int], rng: list[float], g: list[float]) -> Steps:
    if not t:
        return _NO_STEPS
    return Steps(np.array(t, dtype=np.int64), np.array(rng), np.array(g))


def step_lengths(steps: Steps, params: PdrParams, scale: float = 1.0) -> FloatArray:
    """Length of each step in metres (``papers/002_*`` eq 8 or ``papers/003_*`` eq 1).

    ``scale`` multiplies K or m: 1 for the paper's value, a per-session calibration
    otherwise (see ``calibrated_scale``).
    """
    rng = np.maximum(steps.accel_range, 0.0)
    if params.length_model == "weinberg":
        g = np.where(np.isfinite(steps.gravity), steps.gravity, G)
        return np.asarray(scale * params.weinberg_k * (rng / g) ** 0.25, dtype=np.float64)
    raw = scale * params.mansour_m * rng**0.25
    return np.asarray(
        np.clip(raw, params.min_step_m * scale, params.max_step_m * scale), dtype=np.float64
    )


def calibrated_step_m(distance_m: float, n_steps: int) -> float:
    """``papers/003_*`` eq 18: the straight distance between two known points over the
    number of steps taken between them.

    Raises
    ------
    ValueError
        When no step was taken or the distance is not positive and finite.
    """
    if n_steps < 1:
        raise ValueError(f"n_steps must be at least 1, got {n_steps}")
    if not (math.isfinite(distance_m) and distance_m > 0):
        raise ValueError(f"distance_m must be positive and finite, got {distance_m}")
    return distance_m / n_steps
