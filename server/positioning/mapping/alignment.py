"""Aligning dead-reckoned segments to anchors: similarity transform and smoothing.

Similarity transform (``papers/003_*`` section IV-C, eq 5-7; Umeyama 1991)
-------------------------------------------------------------------------
A closed segment has ``n`` anchors, each seen twice: where the dead-reckoned trace put
it, ``b_i`` (the *measured* points, ``B``), and where it really is, ``a_i`` (the
*reference* points, ``A``). The transform ``b' = t + s R b`` with scale ``s > 0``, a
rotation ``R`` (never a reflection) and a translation ``t`` that minimises::

    e^2 = sum_i w_i |a_i - (t + s R b_i)|^2 / sum_i w_i

is found in closed form. With the (normalised) weights ``w_i`` (all equal by default)::

    mu_A = sum w_i a_i,   mu_B = sum w_i b_i,   sigma_B^2 = sum w_i |b_i - mu_B|^2
    H = sum w_i (a_i - mu_A)(b_i - mu_B)^T = U D V^T                          (eq 5)
    S = diag(1, sgn(det U det V))                                            (eq 6)
    R = U S V^T,   s = tr(D S) / sigma_B^2,   t = mu_A - s R mu_B            (eq 7)

``S`` turns what would be a reflection (``det U det V = -1``) into the best proper
rotation. With two anchors ``H`` has rank one, ``S`` still makes ``det R = +1`` and the fit
is exact. ``allow_scale=False`` fixes ``s = 1`` (a rigid transform: ``R`` and ``t`` are
unchanged by that constraint).

The paper prints the scale as ``sigma_A^2 / tr(D S)``. That equals Umeyama's
``tr(D S) / sigma_B^2`` for noiseless points (then ``sigma_A^2 = s^2 sigma_B^2`` and
``tr(D S) = s sigma_B^2``), but with noise it is the reciprocal of the scale of the
*inverse* fit (A onto B), not the minimiser of ``e^2``; Umeyama's form is used here.

``rotation_rad`` is counter-clockwise in the building frame (x east, y north), the
mathematical sense, so a trace rotated by ``theta`` has headings (clockwise from north)
off by ``-theta``.

Forward-backward smoothing between two anchors (``papers/000_*`` section II-B, eq 8-9)
------------------------------------------------------------------------------------
A dead-reckoned segment of ``n`` steps ``s_0 .. s_{n-1}`` (displacements, metres) walks
from anchor ``A`` to anchor ``B``; its ``n + 1`` points are ``k = 0 .. n``. The forward
solution starts at ``A``, the backward one at ``B`` and runs the steps in reverse::

    x_{+,k} = A + sum_{j<k} s_j,          x_{-,k} = B - sum_{j>=k} s'_j

where ``s'`` are the steps of the backward dead reckoning (the same ``s`` unless a
separate backward run is given). Each solution's error grows with the way walked from
its anchor: with ``d_{+,k}`` (``d_{-,k}``) the distance walked from ``A`` to point ``k``
(from point ``k`` to ``B``), and ``m_{+,k} = k``, ``m_{-,k} = n - k`` steps::

    sigma_{+,k}^2 = sigma_A^2 + m_{+,k} q^2 + (epsilon d_{+,k})^2

(and likewise ``sigma_{-,k}`` with ``sigma_B``): the anchor's own error, a random walk
of ``q`` per step (step length and heading jitter) and a drift proportional to the
distance walked (heading bias, step-length scale error). ``sigma`` is the 2-D RMS
position error in metres (the paper's "accuracy, the RMS value").

The two solutions are combined with weights ``u = 1 / sigma^2`` (eq 8)::

    xi_k = u_{+,k} / (u_{+,k} + u_{-,k}) = sigma_{-,k}^2 / (sigma_{+,k}^2 + sigma_{-,k}^2)
    x_{sm,k} = xi_k x_{+,k} + (1 - xi_k) x_{-,k}

and the RP location uncertainty follows by error propagation (eq 9)::

    sigma_{sm,k} = sqrt(xi_k^2 sigma_{+,k}^2 + (1 - xi_k)^2 sigma_{-,k}^2)

which is zero at an exactly known anchor and largest in the middle of the segment. Eq 9
treats the forward and backward errors as independent, as the paper does; they come
from the same steps, so it is an approximation.

The paper leaves the weights ``u`` undefined; inverse variances are the minimum-variance
choice for independent errors. It gives no values for ``q`` and ``epsilon`` either (see
``DeadReckoningNoise``).

Endpoint test (``papers/000_*`` section II-B condition a, section IV-B): a segment is
kept only when the end of the forward solution lies within ``lambda_d`` of ``B`` and the
end of the backward solution within ``lambda_d`` of ``A``, ``lambda_d = 20 m`` in the
paper's tests. When the backward solution runs the same steps, the two mismatches are the
same length (``x_{+,n} - B = -(x_{-,0} - A)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

MAX_ENDPOINT_MISMATCH_M = 20.0  # lambda_d, papers/000_* section IV-B


# ------------------------------------------------------------------ similarity transform


@dataclass(frozen=True)
class Similarity:
    """``b' = t + s R(theta) b``: the transform taking measured points onto references.

    Attributes
    ----------
    scale : float
        ``s`` (1.0 for a rigid fit).
    rotation_rad : float
        ``theta`` in ``(-pi, pi]``, counter-clockwise.
    translation : ndarray, shape (2,)
        ``t`` in metres.
    rms_m : float
        Weighted RMS distance between the transformed points and their references (m),
        ``e`` of the module docstring.
    """

    scale: float
    rotation_rad: float
    translation: FloatArray
    rms_m: float

    @property
    def matrix(self) -> FloatArray:
        """``s R``, shape (2, 2)."""
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return self.scale * np.array([[c, -s], [s, c]])

    def apply(self, xy: ArrayLike) -> FloatArray:
        """Transform points.

        Parameters
        ----------
        xy : array_like, shape (..., 2)
            Points in the measured frame (m).

        Returns
        -------
        ndarray, shape (..., 2)
            The points in the reference frame (m).
        """
        pts = np.asarray(xy, dtype=np.float64)
        if pts.ndim == 0 or pts.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got {pts.shape}")
        return np.asarray(pts @ self.matrix.T + self.translation, dtype=np.float64)


def similarity_transform(
    src: ArrayLike,
    dst: ArrayLike,
    weights: ArrayLike | None = None,
    *,
    allow_scale: bool = True,
) -> Similarity:
    """Least-squares similarity (or rigid) transform taking ``src`` onto ``dst``.

    ``papers/003_*`` eq 5-7 with Umeyama's scale (see the module docstring).

    Parameters
    ----------
    src : array_like, shape (n, 2)
        Measured points ``b_i`` (m), e.g. where dead reckoning put the anchors.
    dst : array_like, shape (n, 2)
        Reference points ``a_i`` (m), the anchors' known positions.
    weights : array_like, shape (n,), optional
        Non-negative weights ``w_i`` (e.g. inverse anchor variances); equal by default.
    allow_scale : bool
        False fits a rigid transform (``scale = 1``).

    Returns
    -------
    Similarity
        Never a reflection. Exact (``rms_m`` ~ 0) for two points with a scale, or for
        noiseless points.

    Raises
    ------
    ValueError
        Fewer than two points, shapes that differ, non-finite values, negative weights,
        or ``src`` points (of positive weight) that all coincide.
    """
    b = np.asarray(src, dtype=np.float64)
    a = np.asarray(dst, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 2:
        raise ValueError(f"src must have shape (n, 2), got {b.shape}")
    if a.shape != b.shape:
        raise ValueError(f"dst must have the shape of src {b.shape}, got {a.shape}")
    n = b.shape[0]
    if n < 2:
        raise ValueError(f"src and dst need at least 2 point pairs, got {n}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("src and dst must be finite")
    if weights is None:
        w = np.full(n, 1.0 / n)
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (n,):
            raise ValueError(f"weights must have shape ({n},), got {w.shape}")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0.0)):
            raise ValueError("weights must be finite and non-negative")
        total = float(w.sum())
        if not total > 0:
            raise ValueError("weights must not all be zero")
        w = w / total

    mu_a = w @ a
    mu_b = w @ b
    a_c = a - mu_a
    b_c = b - mu_b
    var_b = float(w @ np.einsum("ij,ij->i", b_c, b_c))
    if not var_b > 1e-12 * (1.0 + float(np.max(np.abs(b))) ** 2):
        raise ValueError("src points (of positive weight) must not all coincide")
    H = (a_c * w[:, None]).T @ b_c  # eq 5
    U, D, Vt = np.linalg.svd(H)
    S = np.array([1.0, 1.0 if np.linalg.det(U) * np.linalg.det(Vt) >= 0 else -1.0])  # eq 6
    R = U @ np.diag(S) @ Vt  # eq 7
    scale = float(D @ S) / var_b if allow_scale else 1.0
    t = mu_a - scale * R @ mu_b
    resid = a - (b @ (scale * R).T + t)
    rms = math.sqrt(max(float(w @ np.einsum("ij,ij->i", resid, resid)), 0.0))
    t.setflags(write=False)
    return Similarity(
        scale=scale,
        rotation_rad=math.atan2(float(R[1, 0]), float(R[0, 0])),
        translation=t,
        rms_m=rms,
    )


# ------------------------------------------------------- forward-backward smoothing


@dataclass(frozen=True)
class DeadReckoningNoise:
    """How the error of a dead-reckoned solution grows away from its anchor.

    ``papers/000_*`` gives no values (its DR error model is the INS/PDR EKF's); these
    are ours, typical of hand-held step-and-heading PDR.
    """

    step_std_m: float = 0.1  # q: 2-D RMS random error added per step (m)
    drift_per_m: float = 0.03  # epsilon: systematic drift, 3 % of the distance walked

    def __post_init__(self) -> None:
        if not (math.isfinite(self.step_std_m) and self.step_std_m >= 0):
            raise ValueError(f"step_std_m must be finite and >= 0, got {self.step_std_m}")
        if not (math.isfinite(self.drift_per_m) and self.drift_per_m >= 0):
            raise ValueError(f"drift_per_m must be finite and >= 0, got {self.drift_per_m}")


@dataclass(frozen=True)
class SmoothedTrack:
    """A segment smoothed between its anchors (``papers/000_*`` eq 8-9).

    Attributes
    ----------
    xy : ndarray, shape (n + 1, 2)
        Smoothed positions ``x_sm`` (m); row 0 at the start anchor, row n at the end.
    std_m : ndarray, shape (n + 1,)
        ``sigma_sm``, the 2-D RMS uncertainty of each position (m): the RP location
        uncertainty.
    forward_xy, backward_xy : ndarray, shape (n + 1, 2)
        ``x_+`` and ``x_-`` (m).
    forward_std_m, backward_std_m : ndarray, shape (n + 1,)
        ``sigma_+`` and ``sigma_-`` (m).
    xi : ndarray, shape (n + 1,)
        Weight of the forward solution, ``xi`` of eq 8.
    """

    xy: FloatArray
    std_m: FloatArray
    forward_xy: FloatArray
    backward_xy: FloatArray
    forward_std_m: FloatArray
    backward_std_m: FloatArray
    xi: FloatArray


def _segment(
    steps_xy: ArrayLike,
    start_xy: ArrayLike,
    end_xy: ArrayLike,
    backward_steps_xy: ArrayLike | None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Validated ``(steps, backward steps, A, B)``."""
    steps = np.asarray(steps_xy, dtype=np.float64)
    if steps.ndim != 2 or steps.shape[1] != 2:
        raise ValueError(f"steps_xy must have shape (n, 2), got {steps.shape}")
    if not np.all(np.isfinite(steps)):
        raise ValueError("steps_xy must be finite")
    if backward_steps_xy is None:
        back = steps
    else:
        back = np.asarray(backward_steps_xy, dtype=np.float64)
        if back.shape != steps.shape:
            raise ValueError(
                f"backward_steps_xy must have the shape of steps_xy {steps.shape}, got {back.shape}"
            )
        if not np.all(np.isfinite(back)):
            raise ValueError("backward_steps_xy must be finite")
    ends = []
    for name, value in (("start_xy", start_xy), ("end_xy", end_xy)):
        p = np.asarray(value, dtype=np.float64)
        if p.shape != (2,) or not np.all(np.isfinite(p)):
            raise ValueError(f"{name} must be a finite point of shape (2,), got {p.shape}")
        ends.append(p)
    return steps, back, ends[0], ends[1]


def _solutions(
    steps: FloatArray, back: FloatArray, A: FloatArray, B: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Forward and backward solutions ``x_+``, ``x_-``, each shape (n + 1, 2)."""
    zero = np.zeros((1, 2))
    forward = A + np.concatenate([zero, np.cumsum(steps, axis=0)])
    # sum_{j>=k} s'_j for k = 0 .. n
    to_end = np.concatenate([np.cumsum(back[::-1], axis=0)[::-1], zero])
    return forward, B - to_end


def endpoint_mismatch_m(
    steps_xy: ArrayLike,
    start_xy: ArrayLike,
    end_xy: ArrayLike,
    *,
    backward_steps_xy: ArrayLike | None = None,
) -> tuple[float, float]:
    """How far the dead-reckoned solutions end from the anchors (``papers/000_*`` II-B).

    Parameters
    ----------
    steps_xy : array_like, shape (n, 2)
        Step displacements (m), in walking order. For a track of positions ``p`` of shape
        ``(n + 1, 2)`` pass ``np.diff(p, axis=0)``.
    start_xy, end_xy : array_like, shape (2,)
        Anchors ``A`` and ``B`` (m).
    backward_steps_xy : array_like, shape (n, 2), optional
        Steps of a separate backward dead reckoning, in walking order; ``steps_xy`` by
        default.

    Returns
    -------
    forward_m : float
        ``|x_{+,n} - B|``: the forward solution's end against the end anchor (m).
    backward_m : float
        ``|x_{-,0} - A|``: the backward solution's end against the start anchor (m).
        Equal to ``forward_m`` when both run the same steps.
    """
    steps, back, A, B = _segment(steps_xy, start_xy, end_xy, backward_steps_xy)
    forward_end = A + steps.sum(axis=0)
    backward_end = B - back.sum(axis=0)
    return float(np.hypot(*(forward_end - B))), float(np.hypot(*(backward_end - A)))


def passes_endpoint_test(
    steps_xy: ArrayLike,
    start_xy: ArrayLike,
    end_xy: ArrayLike,
    *,
    backward_steps_xy: ArrayLike | None = None,
    max_mismatch_m: float = MAX_ENDPOINT_MISMATCH_M,
) -> bool:
    """Whether a segment is reliable enough to build the map from.

    ``papers/000_*`` section II-B condition a): both the forward and the backward
    solution end within ``lambda_d = max_mismatch_m`` (20 m, section IV-B) of the anchor
    they run towards. Arguments as in ``endpoint_mismatch_m``.
    """
    if not max_mismatch_m >= 0:
        raise ValueError(f"max_mismatch_m must be non-negative, got {max_mismatch_m}")
    forward_m, backward_m = endpoint_mismatch_m(
        steps_xy, start_xy, end_xy, backward_steps_xy=backward_steps_xy
    )
    return forward_m <= max_mismatch_m and backward_m <= max_mismatch_m


def smooth_between_anchors(
    steps_xy: ArrayLike,
    start_xy: ArrayLike,
    end_xy: ArrayLike,
    *,
    start_std_m: float = 0.0,
    end_std_m: float = 0.0,
    noise: DeadReckoningNoise | None = None,
    backward_steps_xy: ArrayLike | None = None,
) -> SmoothedTrack:
    """Forward-backward smoothed segment and its RP location uncertainty.

    ``papers/000_*`` eq 8-9 (see the module docstring). The endpoint test is separate
    (``passes_endpoint_test``); run it first, the smoothing accepts any segment.

    Parameters
    ----------
    steps_xy : array_like, shape (n, 2)
        Step displacements (m), in walking order (``np.diff`` of a track of positions).
    start_xy, end_xy : array_like, shape (2,)
        Anchors ``A`` and ``B`` (m).
    start_std_m, end_std_m : float
        ``sigma_A``, ``sigma_B``: 2-D RMS error of the anchors (m); 0 for exactly known
        points (e.g. an elevator beacon), a GNSS fix's accuracy otherwise.
    noise : DeadReckoningNoise, optional
        Error growth of the dead reckoning; ``DeadReckoningNoise()`` by default.
    backward_steps_xy : array_like, shape (n, 2), optional
        Steps of a separate backward dead reckoning, in walking order.

    Returns
    -------
    SmoothedTrack
        With read-only arrays of ``n + 1`` points.
    """
    steps, back, A, B = _segment(steps_xy, start_xy, end_xy, backward_steps_xy)
    for name, value in (("start_std_m", start_std_m), ("end_std_m", end_std_m)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and non-negative, got {value}")
    noise = DeadReckoningNoise() if noise is None else noise
    n = steps.shape[0]
    forward, backward = _solutions(steps, back, A, B)

    zero = np.zeros(1)
    walked_from_a = np.concatenate([zero, np.cumsum(np.hypot(steps[:, 0], steps[:, 1]))])
    walked_to_b = np.concatenate([np.cumsum(np.hypot(back[::-1, 0], back[::-1, 1]))[::-1], zero])
    k = np.arange(n + 1, dtype=np.float64)
    q2 = noise.step_std_m**2
    eps = noise.drift_per_m
    var_fwd = start_std_m**2 + k * q2 + (eps * walked_from_a) ** 2
    var_bwd = end_std_m**2 + (n - k) * q2 + (eps * walked_to_b) ** 2

    total = var_fwd + var_bwd
    # both zero only for a point that both anchors pin exactly: split evenly
    xi = np.divide(var_bwd, total, out=np.full(n + 1, 0.5), where=total > 0)  # eq 8
    smoothed = xi[:, None] * forward + (1.0 - xi[:, None]) * backward
    std = np.sqrt(xi**2 * var_fwd + (1.0 - xi) ** 2 * var_bwd)  # eq 9

    arrays = (smoothed, std, forward, backward, np.sqrt(var_fwd), np.sqrt(var_bwd), xi)
    for arr in arrays:
        arr.setflags(write=False)
    return SmoothedTrack(*arrays)
