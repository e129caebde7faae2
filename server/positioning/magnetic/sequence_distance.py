"""Distances between magnetic sequences: a walk's observed magnitudes against the map's.

Both compare windows of ``w`` magnitudes (the last ``W + 1`` per-step magnitudes for a
window of ``W`` steps; ``W = 3`` in ``papers/001_*``); the map's come from sampling a
``magnetic.MagneticGrid`` along each particle's last positions.

* ``mmse``: the mean magnetic strength error of ``papers/001_*`` eq (b), the building
  block of the mass-centered weight update eq (c)::

      MMSE_i = 1/W sum_{j=0}^{W-1} | |s_i[t-j] - s_i[t-j-1]| - |s_obs[t-j] - s_obs[t-j-1]| |

  It compares the absolute step-to-step changes of the field, so a constant offset of
  the phone's magnetometer calibration (section II, Figure 1) cancels.
* ``dtw_distance``: the dynamic time warping distance of the Magicol-style baseline
  (section IV-B, reference [11]); classic DTW with cost ``|a_k - b_l|``, no band::

      D[k, l] = |a_k - b_l| + min(D[k-1, l], D[k, l-1], D[k-1, l-1]),   D[0, 0] = |a_0 - b_0|

  and the distance ``D[w-1, m-1]``.

Both are vectorised over the candidates (one per particle); a candidate with a NaN (a
particle over an unknown cell) gets ``inf``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def mmse(observed: ArrayLike, candidates: ArrayLike) -> FloatArray:
    """Mean magnetic strength error ``papers/001_*`` eq (b) of each candidate sequence.

    Parameters
    ----------
    observed : array_like, shape (w,)
        Observed magnitudes, oldest first, ``w = W + 1 >= 2``, finite.
    candidates : array_like, shape (n, w)
        Map magnitudes along each particle's last ``w`` positions.

    Returns
    -------
    ndarray, shape (n,), float64
        ``1/W sum | |Δ candidate| - |Δ observed| |`` over the ``W`` steps; ``inf`` for a
        row with a NaN.
    """
    obs, cand = _sequences(observed, candidates)
    if obs.shape[0] != cand.shape[0]:
        raise ValueError(f"candidates must have shape (n, {obs.shape[0]}), got {cand.T.shape}")
    if obs.shape[0] < 2:
        raise ValueError("mmse needs at least two magnitudes (one step)")
    # candidates come transposed to (w, n): each step below runs over contiguous rows
    # (a reduction over a short inner axis of (n, w) is ~10x slower)
    d = np.diff(cand, axis=0)
    np.abs(d, out=d)
    d -= np.abs(np.diff(obs))[:, None]
    np.abs(d, out=d)
    out: FloatArray = d.sum(axis=0)
    out /= d.shape[0]
    out[np.isnan(out)] = np.inf
    return out


def dtw_distance(observed: ArrayLike, candidates: ArrayLike) -> FloatArray:
    """Classic DTW distance between the observed sequence and each candidate.

    Absolute-difference cost, full window, no band (module docstring). Loops over the
    ``w x m`` cells and is vectorised over the candidates.

    Parameters
    ----------
    observed : array_like, shape (w,)
        Observed magnitudes, finite.
    candidates : array_like, shape (n, m)
        Candidate sequences (usually ``m = w``).

    Returns
    -------
    ndarray, shape (n,), float64
        ``D[w-1, m-1]``; ``inf`` for a row with a NaN.
    """
    obs, cand = _sequences(observed, candidates)
    w, m = obs.shape[0], cand.shape[0]
    if w == 0 or m == 0:
        raise ValueError("dtw_distance needs non-empty sequences")
    # D[k, l] starts as the cost |a_k - b_l| and is accumulated in place, row by row
    D = np.empty((w, m, cand.shape[1]))
    for k in range(w):
        np.subtract(cand, obs[k], out=D[k])
    np.abs(D, out=D)
    # first row and column: one predecessor each (explicit adds: np.cumsum over the outer
    # axis is ~7x slower here)
    for ell in range(1, m):
        D[0, ell] += D[0, ell - 1]
    for k in range(1, w):
        D[k, 0] += D[k - 1, 0]
    best = np.empty(cand.shape[1])
    for k in range(1, w):
        for ell in range(1, m):
            np.minimum(D[k - 1, ell], D[k, ell - 1], out=best)
            np.minimum(best, D[k - 1, ell - 1], out=best)
            D[k, ell] += best
    out: FloatArray = D[w - 1, m - 1].copy()
    out[np.isnan(out)] = np.inf
    return out


def densified(sequences: ArrayLike, per_step: int) -> FloatArray:
    """Windows of per-step magnitudes as sampled sequences: ``per_step`` samples per step,
    linear between the step magnitudes (the last magnitude ends the sequence).

    Parameters
    ----------
    sequences : array_like, shape (..., c)
        Magnitudes at ``c >= 1`` consecutive steps.
    per_step : int
        Samples per step, ``>= 1`` (1 returns the magnitudes themselves).

    Returns
    -------
    ndarray, shape (..., (c - 1) * per_step + 1), float64
    """
    seq = np.asarray(sequences, dtype=np.float64)
    if per_step < 1:
        raise ValueError(f"per_step must be at least 1, got {per_step}")
    if per_step == 1 or seq.shape[-1] < 2:
        return seq
    f = np.arange(per_step) / per_step  # fractions of a step
    start, end = seq[..., :-1, None], seq[..., 1:, None]
    dense = (start + f * (end - start)).reshape(*seq.shape[:-1], -1)
    return np.concatenate([dense, seq[..., -1:]], axis=-1)


def _sequences(observed: ArrayLike, candidates: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Validate a window; return it and the candidates transposed to ``(m, n)``, C order."""
    obs = np.asarray(observed, dtype=np.float64)
    cand = np.asarray(candidates)
    if obs.ndim != 1:
        raise ValueError(f"observed must have shape (w,), got {obs.shape}")
    if not np.all(np.isfinite(obs)):
        raise ValueError("observed must be finite")
    if cand.ndim != 2:
        raise ValueError(f"candidates must have shape (n, m), got {cand.shape}")
    return obs, np.ascontiguousarray(cand.T, dtype=np.float64)  # one copy
