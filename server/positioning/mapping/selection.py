"""Inertial data selection (``papers/003_*`` section IV-A); ``mapping.segments`` cuts what it
keeps at anchors (IV-C).

Which parts of a crowdsourced trace are good enough to build maps from
-----------------------------------------------------------------------
Mansour et al. found (section IV-A, Fig. 5) that traces keep their shape after PDR
(geometric similarity above 90 %) when the phone is carried steadily, and they select a
portion of a trace when three criteria hold (IV-A 2b, last paragraph):

1. the differences between successive step peaks and between successive step valleys
   of the filtered vertical acceleration are below 3.0 m/s²;
2. the variances of the filtered linear acceleration in sliding windows, in x, y, z and
   of the magnitude, are below 7 m²/s⁴;
3. the variances of the filtered angular velocity in sliding windows, in x, y, z and of
   the magnitude, are below 0.25 (see *Units* below).

Here, with ``a`` the accelerometer and ``ω`` the gyroscope, both put on the uniform grid of
``PdrParams.grid_ms`` (20 ms, the 50 Hz of section VI-A) by linear interpolation:

* gravity ``g_k = g_{k-1} + α (a_k - g_{k-1})``, ``α = 1 - exp(-Δt / τ)`` with
  ``τ = PdrParams.vertical_tau_s``, started at ``g_0 = a_0`` (the same first-order low-pass
  as ``pdr.py``); linear acceleration ``l_k = a_k - g_k`` ("the gravity effect was first
  subtracted", section III);
* low-pass: the centred moving average of ``2N + 1`` samples of ``pdr.py``
  (``PdrParams.half_window``), applied to ``l`` and ``ω`` ("filtered using a low-pass
  filter", IV-A 2b);
* windows of ``W = 130`` grid samples (2.6 s) with 50 % overlap (hop 65), the
  accelerometer window of section VI-D; the last window is moved back to end on the last
  sample so every sample is covered. The gyroscope is judged over the same windows: the
  paper's 265 samples at 100 Hz are 2.65 s, 2 % longer; one set of windows gives one
  usable/unusable mark per window;
* criterion 1: steps come from ``pdr.detect_steps``; for step ``k`` (at its valley
  time ``t_k``) the peak ``p_k`` and valley ``v_k`` are the maximum and minimum of the
  filtered vertical linear acceleration ``l·g/|g|`` over
  ``max(t_{k-1}, t_k - PdrParams.max_peak_valley_ms) < t <= t_k``, and::

      Δ_k = max(|p_k - p_{k-1}|, |v_k - v_{k-1}|)      (Table IV: Δ_Peak, Δ_Valley)

  is charged to the window(s) holding ``t_k``; a window fails when ``max Δ_k >= 3.0``;
* criteria 2 and 3: population variance over the window of each of the four channels
  (x, y, z, magnitude); a window fails when the largest is ``>= 7`` resp. ``>= 0.25``;
* ours, not the paper's: a window also fails when either sensor has a hole of more
  than ``max_gap_ms`` between raw samples inside it (interpolating across it would invent
  data), or no data at all there.

A window is usable when no criterion fails. The samples kept are those covered by a
usable window and by no failing window (a sample in the overlap of a good and a bad
window goes with the bad one). Kept and rejected time spans are half-open
``[start_ms, end_ms)`` on the grid and tile the trace; each rejected span lists, per
failed criterion, the worst value among its windows, so an upload report can say why.

Units
~~~~~
The paper prints the angular-velocity threshold as 0.25 deg²/s². Read literally that is
a standard deviation of 0.5 °/s, below what a hand-held phone shows even when the walker
stands still, and Table IV's qualified portions have mean variances of 0.04-0.06 in the
same unit (s.d. 0.2 °/s) while 27-69 % of all walking data qualified (Table V). In
rad²/s² the same numbers are a s.d. of 0.2 rad/s (11 °/s) for steady hand-held walking
and 0.5 rad/s (29 °/s) at the threshold, which matches walking, so the threshold is
applied in rad²/s² to gyroscope data in rad/s. (Table IV's largest qualified σ_ωx, 0.28,
is above 0.25 either way.) Table IV's accelerometer numbers (σ_az mean 2.70 m²/s⁴, max
6.88 < 7) confirm that its "σ" columns are variances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from server.positioning.motion.pdr import PdrParams, detect_steps, initial_detector

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

Criterion = Literal[
    "step_extremes", "accel_variance", "gyro_variance", "accel_gap", "gyro_gap", "too_short"
]
CRITERIA: tuple[Criterion, ...] = (
    "step_extremes",
    "accel_variance",
    "gyro_variance",
    "accel_gap",
    "gyro_gap",
)
_CHANNELS = ("x", "y", "z", "magnitude")


@dataclass(frozen=True)
class SelectionParams:
    """Thresholds of ``papers/003_*`` IV-A and the windows of VI-D."""

    max_step_change_ms2: float = 3.0  # IV-A criterion 1, m/s²
    max_accel_var_m2s4: float = 7.0  # IV-A criterion 2, m²/s⁴
    max_gyro_var_rad2s2: float = 0.25  # IV-A criterion 3 (printed deg²/s², see docstring)
    window_samples: int = 130  # VI-D: 130 samples at 50 Hz = 2.6 s
    hop_samples: int = 65  # VI-D: 50 % overlap
    max_gap_ms: int = 500  # ours: a longer hole between raw samples fails the window
    pdr: PdrParams = field(default_factory=PdrParams)  # grid, filters, step detection

    def __post_init__(self) -> None:
        if self.window_samples < 2:
            raise ValueError(f"window_samples must be at least 2, got {self.window_samples}")
        if not 1 <= self.hop_samples <= self.window_samples:
            raise ValueError(f"hop_samples must be in [1, window_samples], got {self.hop_samples}")
        for name in ("max_step_change_ms2", "max_accel_var_m2s4", "max_gyro_var_rad2s2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        if self.max_gap_ms <= 0:
            raise ValueError(f"max_gap_ms must be positive, got {self.max_gap_ms}")


@dataclass(frozen=True)
class RejectedSpan:
    """A time span left out of map building, and why.

    ``criteria``, ``values`` and ``reasons`` are aligned: per failed criterion, the worst
    value among the span's windows (``inf`` for a gap means no data) and a sentence such
    as ``"acceleration variance 9.1 m²/s⁴ (z) >= 7 m²/s⁴"``.
    """

    start_ms: int
    end_ms: int  # exclusive
    criteria: tuple[Criterion, ...]
    values: tuple[float, ...]
    reasons: tuple[str, ...]


@dataclass(frozen=True)
class InertialSelection:
    """Per-window marks and the kept / rejected time spans of one trace.

    Attributes
    ----------
    window_start_ms, window_end_ms : ndarray, shape (n_win,), int64
        Window bounds, ``[start, end)``.
    usable : ndarray, shape (n_win,), bool
        True when the window meets every criterion.
    step_change_ms2 : ndarray, shape (n_win,), float64
        Largest ``Δ_k`` charged to the window, m/s²; NaN when it holds no step pair.
    accel_var_m2s4 : ndarray, shape (n_win,), float64
        Largest variance over x, y, z, magnitude of the filtered linear acceleration.
    gyro_var_rad2s2 : ndarray, shape (n_win,), float64
        Largest variance over x, y, z, magnitude of the filtered angular velocity.
    kept_spans_ms : ndarray, shape (n_kept, 2), int64
        ``[start, end)`` of each kept span, in time order.
    rejected : tuple of RejectedSpan
        The complementary spans, in time order.
    """

    window_start_ms: IntArray
    window_end_ms: IntArray
    usable: BoolArray
    step_change_ms2: FloatArray
    accel_var_m2s4: FloatArray
    gyro_var_rad2s2: FloatArray
    kept_spans_ms: IntArray
    rejected: tuple[RejectedSpan, ...]

    @property
    def kept_ms(self) -> int:
        """Total kept time."""
        return int(np.sum(self.kept_spans_ms[:, 1] - self.kept_spans_ms[:, 0]))

    @property
    def rejected_ms(self) -> int:
        """Total rejected time."""
        return sum(r.end_ms - r.start_ms for r in self.rejected)


def _samples(name: str, value: ArrayLike) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"{name} must have shape (n, 4), got {arr.shape}")
    if arr.shape[0] < 2:
        raise ValueError(f"{name} needs at least 2 samples, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    if np.any(np.diff(arr[:, 0]) <= 0):
        raise ValueError(f"{name} times must be strictly increasing")
    return arr


def _on_grid(samples: FloatArray, grid: FloatArray) -> FloatArray:
    t = samples[:, 0]
    return np.column_stack([np.interp(grid, t, samples[:, i]) for i in (1, 2, 3)])


def _gap_at(t_raw: FloatArray, grid: FloatArray) -> FloatArray:
    """Length of the raw sampling interval around each grid time; inf outside the data."""
    i = np.clip(np.searchsorted(t_raw, grid, side="right"), 1, t_raw.size - 1)
    gap = t_raw[i] - t_raw[i - 1]
    return np.where((grid >= t_raw[0]) & (grid <= t_raw[-1]), gap, np.inf)


def _low_pass(x: FloatArray, tau_s: float, grid_ms: int) -> FloatArray:
    """First-order low-pass along axis 0 started at the first sample (as in ``pdr.py``)."""
    alpha = 1.0 - math.exp(-grid_ms / 1000.0 / tau_s)
    zi = (1.0 - alpha) * x[:1]
    y = lfilter([alpha], [1.0, alpha - 1.0], x, axis=0, zi=zi)[0]
    return np.asarray(y, dtype=np.float64)


def _moving_average(x: FloatArray, half_window: int) -> FloatArray:
    y = uniform_filter1d(x, size=2 * half_window + 1, axis=0, mode="nearest")
    return np.asarray(y, dtype=np.float64)


def _window_var(x: FloatArray, starts: IntArray, w: int) -> tuple[FloatArray, IntArray]:
    """Largest variance over the channels (x, y, z, magnitude) per window, and which."""
    channels = np.column_stack([x, np.linalg.norm(x, axis=1)])
    var = sliding_window_view(channels, w, axis=0)[starts].var(axis=-1)  # (n_win, 4)
    worst = np.argmax(var, axis=1)
    return var[np.arange(starts.size), worst], worst.astype(np.int64)


def _window_max(x: FloatArray, starts: IntArray, w: int) -> FloatArray:
    return np.asarray(sliding_window_view(x, w)[starts].max(axis=1), dtype=np.float64)


def _runs(mask: BoolArray) -> IntArray:
    """``[i0, i1)`` index pairs of the runs of True, shape (n_runs, 2)."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.column_stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)]).astype(
        np.int64
    )


def _coverage(starts: IntArray, w: int, n: int) -> BoolArray:
    d = np.zeros(n + 1, dtype=np.int64)
    np.add.at(d, starts, 1)
    np.add.at(d, starts + w, -1)
    return np.asarray(np.cumsum(d)[:n] > 0)


def _step_changes(
    accel: FloatArray, grid: FloatArray, vertical: FloatArray, pdr: PdrParams
) -> FloatArray:
    """``Δ_k`` placed at the grid index of step ``k`` (``-inf`` where no step ends)."""
    out = np.full(grid.size, -np.inf)
    _, steps = detect_steps(initial_detector(), accel, pdr)
    t = steps.t_ms.astype(np.float64)
    if t.size < 2:
        return out
    prev = np.concatenate([[-np.inf], t[:-1]])
    lo = np.searchsorted(grid, np.maximum(prev + pdr.grid_ms, t - pdr.max_peak_valley_ms))
    hi = np.searchsorted(grid, t, side="right")
    padded = np.append(vertical, vertical[-1])  # so that hi == grid.size is a valid index
    bounds = np.column_stack([lo, hi]).ravel()
    peak = np.maximum.reduceat(padded, bounds)[::2]
    valley = np.minimum.reduceat(padded, bounds)[::2]
    change = np.maximum(np.abs(np.diff(peak)), np.abs(np.diff(valley)))
    np.maximum.at(out, hi[1:] - 1, change)
    return out


def _reason(criterion: Criterion, value: float, params: SelectionParams, channel: int) -> str:
    axis = _CHANNELS[channel]
    if criterion == "step_extremes":
        thr = params.max_step_change_ms2
        return f"step peak/valley change {value:.3g} m/s² >= {thr:g} m/s²"
    if criterion == "accel_variance":
        thr = params.max_accel_var_m2s4
        return f"acceleration variance {value:.3g} m²/s⁴ ({axis}) >= {thr:g} m²/s⁴"
    if criterion == "gyro_variance":
        thr = params.max_gyro_var_rad2s2
        return f"angular-velocity variance {value:.3g} rad²/s² ({axis}) >= {thr:g} rad²/s²"
    sensor = "accelerometer" if criterion == "accel_gap" else "gyroscope"
    if math.isinf(value):
        return f"no {sensor} data"
    return f"{sensor} gap {value / 1000:.3g} s > {params.max_gap_ms / 1000:g} s"


def select_inertial(
    accel: ArrayLike, gyro: ArrayLike, params: SelectionParams | None = None
) -> InertialSelection:
    """Mark the sliding windows of a trace usable or not (see the module docstring).

    Parameters
    ----------
    accel : array_like, shape (n, 4)
        Accelerometer rows ``[t_ms, x, y, z]``, m/s², gravity included; times strictly
        increasing.
    gyro : array_like, shape (m, 4)
        Gyroscope rows ``[t_ms, x, y, z]``, rad/s; times strictly increasing.
    params : SelectionParams, optional

    Returns
    -------
    InertialSelection
        Per-window marks and values; kept and rejected spans covering the trace from the
        first grid time to one grid step after the last.

    Raises
    ------
    ValueError
        When ``accel`` or ``gyro`` is malformed (naming the argument).
    """
    params = params or SelectionParams()
    acc = _samples("accel", accel)
    gyr = _samples("gyro", gyro)
    step = params.pdr.grid_ms
    w, hop = params.window_samples, params.hop_samples
    t_lo = min(acc[0, 0], gyr[0, 0])
    t_hi = max(acc[-1, 0], gyr[-1, 0])
    start = math.ceil(t_lo / step) * step  # the lattice of pdr.py, so step times fall on it
    grid = np.arange(start, t_hi + 0.5, step, dtype=np.float64)
    grid = grid[grid <= t_hi]
    n = grid.size

    if n < w:
        end = int(grid[-1]) + step if n else int(t_hi)
        duration_s = (t_hi - t_lo) / 1000.0
        text = f"trace of {duration_s:.3g} s is shorter than one {w * step / 1000:g} s window"
        empty_i = np.empty(0, dtype=np.int64)
        empty_f = np.empty(0, dtype=np.float64)
        return InertialSelection(
            window_start_ms=empty_i,
            window_end_ms=empty_i,
            usable=np.empty(0, dtype=np.bool_),
            step_change_ms2=empty_f,
            accel_var_m2s4=empty_f,
            gyro_var_rad2s2=empty_f,
            kept_spans_ms=np.empty((0, 2), dtype=np.int64),
            rejected=(
                RejectedSpan(
                    int(start if n else t_lo), end, ("too_short",), (duration_s,), (text,)
                ),
            ),
        )

    a = _on_grid(acc, grid)
    gravity = _low_pass(a, params.pdr.vertical_tau_s, step)
    linear = _moving_average(a - gravity, params.pdr.half_window)
    omega = _moving_average(_on_grid(gyr, grid), params.pdr.half_window)
    up = gravity / np.maximum(np.linalg.norm(gravity, axis=1, keepdims=True), 1e-9)
    vertical = np.einsum("ij,ij->i", linear, up)

    starts = np.arange(0, n - w + 1, hop, dtype=np.int64)
    if starts[-1] != n - w:
        starts = np.append(starts, n - w)

    change = _window_max(_step_changes(acc, grid, vertical, params.pdr), starts, w)
    change = np.where(np.isfinite(change), change, np.nan)
    acc_var, acc_channel = _window_var(linear, starts, w)
    gyr_var, gyr_channel = _window_var(omega, starts, w)
    acc_gap = _window_max(_gap_at(acc[:, 0], grid), starts, w)
    gyr_gap = _window_max(_gap_at(gyr[:, 0], grid), starts, w)

    values = np.column_stack([change, acc_var, gyr_var, acc_gap, gyr_gap])  # (n_win, 5)
    channel = np.zeros(values.shape, dtype=np.int64)  # which of x, y, z, magnitude
    channel[:, 1], channel[:, 2] = acc_channel, gyr_channel
    fails = np.column_stack(  # NaN (no step pair) compares False: no failure
        [
            change >= params.max_step_change_ms2,
            acc_var >= params.max_accel_var_m2s4,
            gyr_var >= params.max_gyro_var_rad2s2,
            acc_gap > params.max_gap_ms,
            gyr_gap > params.max_gap_ms,
        ]
    )
    usable = np.asarray(~fails.any(axis=1))

    bad = _coverage(starts[~usable], w, n)
    kept = _coverage(starts[usable], w, n) & ~bad
    kept_runs = _runs(kept)
    bad_runs = _runs(bad)

    def span(i0: int, i1: int) -> tuple[int, int]:
        return int(grid[i0]), int(grid[i1 - 1]) + step

    kept_spans = np.array([span(i0, i1) for i0, i1 in kept_runs], dtype=np.int64).reshape(-1, 2)

    # every failing window lies inside one bad run: group the failing windows by run
    failing = np.flatnonzero(~usable)
    run_of = np.searchsorted(bad_runs[:, 0], starts[failing], side="right") - 1
    groups = np.split(failing, np.flatnonzero(np.diff(run_of)) + 1) if failing.size else []
    rejected: list[RejectedSpan] = []
    for (i0, i1), windows in zip(bad_runs, groups, strict=True):
        crit: list[Criterion] = []
        worst: list[float] = []
        texts: list[str] = []
        for c, name in enumerate(CRITERIA):
            hit = windows[fails[windows, c]]
            if hit.size == 0:
                continue
            j = hit[np.argmax(values[hit, c])]
            crit.append(name)
            worst.append(float(values[j, c]))
            texts.append(_reason(name, float(values[j, c]), params, int(channel[j, c])))
        s0, s1 = span(int(i0), int(i1))
        rejected.append(RejectedSpan(s0, s1, tuple(crit), tuple(worst), tuple(texts)))

    return InertialSelection(
        window_start_ms=grid[starts].astype(np.int64),
        window_end_ms=(grid[starts + w - 1] + step).astype(np.int64),
        usable=usable,
        step_change_ms2=change,
        accel_var_m2s4=acc_var,
        gyro_var_rad2s2=gyr_var,
        kept_spans_ms=kept_spans,
        rejected=tuple(rejected),
    )
