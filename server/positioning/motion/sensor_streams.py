"""Sensor sample streams: their array shapes, their alignment, and batches.

Samples are ``(n, 4)`` arrays ``[t_ms, x, y, z]`` (package docstring). The filters of
this package run at the gyro sample times; the other streams are aligned to them.

Alignment. The accelerometer and magnetometer are held (zero-order hold: the latest sample
at or before the gyro sample time, ``held_index``) rather than interpolated, because
interpolation needs the next sample and so could not give the same output for one batch
and for two. A measurement updates a filter once, at the first gyro sample at or after it
(``fresh``). The last sample of each stream is carried in the filter state
(``with_carried``), so that splitting all streams at a common time gives the same output
as one batch.

Low-pass (``lowpass``). First order, ``y += (1 - exp(-dt / tau)) (x - y)`` at the sample
times, so irregular sample times are handled; it continues from a carried output.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

MAX_GAP_S = 1.0  # a longer gap between gyro samples is not integrated across


def samples(x: FloatArray, width: int = 4) -> FloatArray:
    """``x`` as float64 rows of ``width`` columns, shape ``(n, width)`` (``n`` may be 0)."""
    return np.asarray(x, dtype=np.float64).reshape(-1, width)


def vectors(x: FloatArray) -> FloatArray:
    """The last three columns: ``(n, 3)`` vectors from ``(n, 4)`` samples or ``(n, 3)``."""
    a = np.asarray(x, dtype=np.float64)
    return a.reshape(-1, a.shape[-1] if a.ndim > 1 else 3)[:, -3:]


def held_index(sample_t_ms: FloatArray, t_ms: FloatArray) -> NDArray[np.intp]:
    """Index of the latest sample at or before each time, -1 when there is none."""
    return np.searchsorted(sample_t_ms, t_ms, side="right") - 1


def fresh(
    sample_t_ms: FloatArray, index: NDArray[np.intp], t_ms: FloatArray, last_t_ms: float
) -> NDArray[np.bool_]:
    """Whether the held sample is new at each time: later than the previous time.

    ``index`` is ``held_index(sample_t_ms, t_ms)``; ``last_t_ms`` is the time before the
    first of ``t_ms`` (NaN before any).
    """
    start = last_t_ms if math.isfinite(last_t_ms) else -np.inf
    previous = np.concatenate([[start], t_ms])[:-1]
    held_t = sample_t_ms[np.maximum(index, 0)] if len(sample_t_ms) else np.zeros(len(t_ms))
    return np.asarray((index >= 0) & (held_t > previous), dtype=np.bool_)


def with_carried(carried: FloatArray, batch: FloatArray) -> FloatArray:
    """Prepend the carried last sample of the previous batch when there is one (its time
    is not NaN)."""
    return np.vstack([carried[None, :], batch]) if math.isfinite(carried[0]) else batch


def lowpass(
    accel: FloatArray, tau_s: float, y0: FloatArray, t0_ms: float
) -> tuple[FloatArray, FloatArray]:
    """First-order low-pass ``y += (1 - exp(-dt / tau)) (x - y)`` at the sample times.

    Parameters
    ----------
    accel : ndarray, shape (n, 4)
        ``[t_ms, x, y, z]`` samples.
    tau_s : float
        Time constant, s.
    y0 : ndarray, shape (3,)
        Output at ``t0_ms``.
    t0_ms : float
        Time of ``y0``; NaN starts the filter at the first sample.

    Returns
    -------
    filtered : ndarray, shape (n, 3)
        The output at each sample time.
    last : ndarray, shape (3,)
        The last output (``y0`` when ``n`` is 0).
    """
    out = np.empty((len(accel), 3))
    y = [float(v) for v in y0]
    t_prev = t0_ms
    for i, (t, ax, ay, az) in enumerate(accel.tolist()):
        if math.isfinite(t_prev):
            a = 1.0 - math.exp(-(t - t_prev) / (1000.0 * tau_s))
            y = [y[0] + a * (ax - y[0]), y[1] + a * (ay - y[1]), y[2] + a * (az - y[2])]
        else:
            y = [ax, ay, az]
        out[i] = y
        t_prev = t
    return out, np.array(y, dtype=np.float64)
