"""Similarity transform (Umeyama) and forward-backward smoothing between anchors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.optimize import minimize

from server.positioning.mapping.alignment import (
    MAX_ENDPOINT_MISMATCH_M,
    DeadReckoningNoise,
    endpoint_mismatch_m,
    passes_endpoint_test,
    similarity_transform,
    smooth_between_anchors,
)

FloatArray = NDArray[np.float64]


def _rot(theta: float) -> FloatArray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


# ------------------------------------------------------------------ similarity transform


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 20),
    scale=st.floats(0.2, 5.0),
    theta=st.floats(-math.pi, math.pi),
    tx=st.floats(-100.0, 100.0),
    ty=st.floats(-100.0, 100.0),
)
def test_recovers_a_known_similarity_from_noiseless_points(
    seed: int, n: int, scale: float, theta: float, tx: float, ty: float
) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-50.0, 50.0, (n, 2))
    dst = scale * src @ _rot(theta).T + [tx, ty]
    fit = similarity_transform(src, dst)
    assert fit.scale == pytest.approx(scale, rel=1e-9)
    assert _angle_diff(fit.rotation_rad, theta) < 1e-9
    np.testing.assert_allclose(fit.translation, [tx, ty], atol=1e-7)
    assert fit.rms_m < 1e-7
    np.testing.assert_allclose(fit.apply(src), dst, atol=1e-7)


def _best_proper_rms(src: FloatArray, dst: FloatArray) -> float:
    """Smallest RMS over proper similarities, by a general-purpose optimiser."""

    def cost(p: FloatArray) -> float:
        moved = math.exp(p[1]) * src @ _rot(p[0]).T + p[2:]
        return float(np.mean(np.sum((dst - moved) ** 2, axis=1)))

    starts = [np.array([th, 0.0, 0.0, 0.0]) for th in np.linspace(-math.pi, math.pi, 8)]
    best = min(minimize(cost, x0, method="BFGS").fun for x0 in starts)
    return math.sqrt(best)


@pytest.mark.parametrize("seed", range(5))
def test_mirrored_points_give_the_best_rotation_never_a_reflection(seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-10.0, 10.0, (8, 2))
    dst = src * [-1.0, 1.0] + [3.0, -2.0]  # a mirror image: no proper transform fits
    fit = similarity_transform(src, dst)
    assert np.linalg.det(fit.matrix) > 0
    assert fit.rms_m > 0.1
    assert fit.rms_m <= _best_proper_rms(src, dst) + 1e-6
    moved = fit.apply(src)
    np.testing.assert_allclose(math.sqrt(np.mean(np.sum((dst - moved) ** 2, axis=1))), fit.rms_m)


@pytest.mark.parametrize("seed", range(5))
def test_noisy_fit_is_the_least_squares_optimum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-20.0, 20.0, (6, 2))
    dst = 1.3 * src @ _rot(0.7).T + [5.0, 1.0] + rng.normal(0.0, 1.0, src.shape)
    fit = similarity_transform(src, dst)
    assert fit.rms_m == pytest.approx(_best_proper_rms(src, dst), abs=1e-6)


def test_two_points_fit_exactly() -> None:
    src = [(0.0, 0.0), (10.0, 0.0)]
    dst = [(5.0, 5.0), (5.0, 17.0)]  # turned +90°, stretched by 1.2
    fit = similarity_transform(src, dst)
    assert fit.scale == pytest.approx(1.2)
    assert fit.rotation_rad == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(fit.translation, [5.0, 5.0], atol=1e-12)
    assert fit.rms_m == pytest.approx(0.0, abs=1e-12)


def test_rigid_mode_keeps_scale_one() -> None:
    src = np.array([(0.0, 0.0), (10.0, 0.0)])
    dst = np.array([(5.0, 5.0), (5.0, 17.0)])
    fit = similarity_transform(src, dst, allow_scale=False)
    assert fit.scale == 1.0
    assert fit.rotation_rad == pytest.approx(math.pi / 2)
    # the 10 m segment is centred on the 12 m one: each end 1 m short
    np.testing.assert_allclose(fit.apply(src), [(5.0, 6.0), (5.0, 16.0)], atol=1e-12)
    assert fit.rms_m == pytest.approx(1.0)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), theta=st.floats(-math.pi, math.pi))
def test_rigid_mode_recovers_a_rigid_transform(seed: int, theta: float) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-30.0, 30.0, (5, 2))
    dst = src @ _rot(theta).T + [7.0, -3.0]
    fit = similarity_transform(src, dst, allow_scale=False)
    assert fit.scale == 1.0
    assert _angle_diff(fit.rotation_rad, theta) < 1e-9
    assert fit.rms_m < 1e-8


def test_weights_pull_the_fit_towards_heavy_points() -> None:
    rng = np.random.default_rng(3)
    src = rng.uniform(-20.0, 20.0, (6, 2))
    dst = 0.9 * src @ _rot(-0.4).T + [2.0, 2.0]
    dst[0] += [6.0, -4.0]  # one anchor badly off
    # a zero weight drops it: the others are fitted exactly
    w = np.ones(6)
    w[0] = 0.0
    exact = similarity_transform(src, dst, w)
    assert exact.scale == pytest.approx(0.9)
    assert exact.rotation_rad == pytest.approx(-0.4)
    assert exact.rms_m == pytest.approx(0.0, abs=1e-9)

    def residual_of_first(weight: float) -> float:
        w = np.ones(6)
        w[0] = weight
        fit = similarity_transform(src, dst, w)
        return float(np.hypot(*(fit.apply(src[0]) - dst[0])))

    residuals = [residual_of_first(x) for x in (0.0, 0.5, 1.0, 5.0, 50.0)]
    assert all(np.diff(residuals) < 0)
    # only the weights' ratios matter
    a = similarity_transform(src, dst, np.arange(1.0, 7.0))
    b = similarity_transform(src, dst, 10.0 * np.arange(1.0, 7.0))
    assert a.scale == pytest.approx(b.scale)
    assert a.rotation_rad == pytest.approx(b.rotation_rad)
    np.testing.assert_allclose(a.translation, b.translation)


def test_apply_keeps_leading_shape() -> None:
    fit = similarity_transform([(0.0, 0.0), (1.0, 0.0)], [(1.0, 1.0), (1.0, 3.0)])
    out = fit.apply(np.zeros((3, 4, 2)))
    assert out.shape == (3, 4, 2)
    np.testing.assert_allclose(out, np.broadcast_to([1.0, 1.0], (3, 4, 2)), atol=1e-12)
    with pytest.raises(ValueError, match="xy"):
        fit.apply([1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("src", "dst", "weights", "match"),
    [
        ([(0.0, 0.0)], [(1.0, 1.0)], None, "at least 2"),
        ([(0.0, 0.0), (1.0, 0.0)], [(1.0, 1.0)], None, "dst"),
        ([0.0, 1.0], [1.0, 1.0], None, "src"),
        ([(1.0, 1.0), (1.0, 1.0)], [(0.0, 0.0), (1.0, 0.0)], None, "coincide"),
        ([(0.0, 0.0), (1.0, 0.0)], [(0.0, float("nan")), (1.0, 0.0)], None, "finite"),
        ([(0.0, 0.0), (1.0, 0.0)], [(0.0, 0.0), (1.0, 0.0)], [1.0, -1.0], "weights"),
        ([(0.0, 0.0), (1.0, 0.0)], [(0.0, 0.0), (1.0, 0.0)], [0.0, 0.0], "weights"),
        ([(0.0, 0.0), (1.0, 0.0)], [(0.0, 0.0), (1.0, 0.0)], [1.0], "weights"),
        ([(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)], [(0.0, 0.0)] * 3, [1.0, 0.0, 0.0], "coincide"),
    ],
)
def test_bad_input_is_refused(src: object, dst: object, weights: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        similarity_transform(src, dst, weights)  # type: ignore[arg-type]


# ------------------------------------------------------- forward-backward smoothing


def _walk(legs: list[tuple[float, float]], step_m: float = 0.7) -> FloatArray:
    """Positions of a walk of straight legs ``(heading_deg clockwise from north, length_m)``."""
    points = [np.zeros(2)]
    for heading_deg, length in legs:
        n = round(length / step_m)
        h = math.radians(heading_deg)
        d = np.array([math.sin(h), math.cos(h)]) * length / n
        start = points[-1]
        points.extend(start + d * (i + 1) for i in range(n))
    return np.array(points)


def _drifting_pdr(true_xy: FloatArray, bias_deg: float, scale: float, seed: int = 1) -> FloatArray:
    """Steps of the walk as a PDR with a heading bias (clockwise), a step-length scale
    error and a little jitter would measure them."""
    b = math.radians(bias_deg)
    clockwise = np.array([[math.cos(b), math.sin(b)], [-math.sin(b), math.cos(b)]])
    steps = np.diff(true_xy, axis=0)
    rng = np.random.default_rng(seed)
    return np.asarray(scale * steps @ clockwise.T + rng.normal(0.0, 0.03, steps.shape))


TRUE_WALK = _walk([(90.0, 40.0), (0.0, 20.0), (90.0, 30.0)]) + np.array([5.0, 5.0])


@pytest.mark.parametrize(("bias_deg", "seed"), [(4.0, 1), (-6.0, 2), (8.0, 3)])
def test_smoothing_beats_forward_dead_reckoning_between_the_anchors(
    bias_deg: float, seed: int
) -> None:
    steps = _drifting_pdr(TRUE_WALK, bias_deg, 1.03, seed)
    track = smooth_between_anchors(steps, TRUE_WALK[0], TRUE_WALK[-1])
    forward_err = np.hypot(*(track.forward_xy - TRUE_WALK).T)
    smoothed_err = np.hypot(*(track.xy - TRUE_WALK).T)
    assert forward_err[-1] > 4.0  # the drift is real
    inner = slice(1, -1)
    assert np.all(smoothed_err[inner] < forward_err[inner])
    assert smoothed_err.max() < 0.4 * forward_err.max()
    np.testing.assert_allclose(track.xy[0], TRUE_WALK[0])
    np.testing.assert_allclose(track.xy[-1], TRUE_WALK[-1])


def test_uncertainty_is_zero_at_exact_anchors_and_peaks_in_the_middle() -> None:
    steps = _drifting_pdr(TRUE_WALK, 4.0, 1.0)
    track = smooth_between_anchors(steps, TRUE_WALK[0], TRUE_WALK[-1])
    std = track.std_m
    n = std.size - 1
    assert std[0] == 0.0
    assert std[-1] == 0.0
    peak = int(np.argmax(std))
    assert abs(peak - n / 2) <= 0.1 * n
    assert np.all(np.diff(std[: peak + 1]) > 0)
    assert np.all(np.diff(std[peak:]) < 0)
    # the combination is never less certain than either solution alone
    assert np.all(std <= np.minimum(track.forward_std_m, track.backward_std_m) + 1e-12)


def test_random_walk_errors_give_a_linear_correction_and_a_brownian_bridge() -> None:
    # no drift: xi_k = (n - k) / n, the closure error spread linearly over the steps,
    # and sigma_sm^2 = q^2 k (n - k) / n
    rng = np.random.default_rng(0)
    steps = rng.normal(0.0, 0.7, (40, 2))
    a, b = np.array([0.0, 0.0]), np.array([3.0, -1.0])
    q = 0.2
    track = smooth_between_anchors(steps, a, b, noise=DeadReckoningNoise(q, 0.0))
    n = steps.shape[0]
    k = np.arange(n + 1)
    closure = a + steps.sum(axis=0) - b
    np.testing.assert_allclose(track.xi, (n - k) / n)
    np.testing.assert_allclose(track.xy, track.forward_xy - np.outer(k / n, closure), atol=1e-12)
    np.testing.assert_allclose(track.std_m**2, q**2 * k * (n - k) / n, atol=1e-12)


def test_uncertain_anchors_and_a_separate_backward_run() -> None:
    steps = np.tile([0.7, 0.0], (20, 1))
    back = np.tile([0.7, 0.1], (20, 1))
    track = smooth_between_anchors(
        steps, [0.0, 0.0], [14.0, 1.0], start_std_m=3.0, end_std_m=1.0, backward_steps_xy=back
    )
    np.testing.assert_allclose(track.backward_xy[-1], [14.0, 1.0])
    np.testing.assert_allclose(track.backward_xy[0], [0.0, -1.0], atol=1e-12)
    assert track.forward_std_m[0] == pytest.approx(3.0)
    assert track.backward_std_m[-1] == pytest.approx(1.0)
    # the end anchor is the better one, so the start is pulled a little towards it
    assert 0.0 < track.xi[0] < 1.0
    assert 0.0 < track.std_m[0] < 3.0
    assert not track.xy.flags.writeable


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 60),
    start_std=st.floats(0.0, 10.0),
    end_std=st.floats(0.0, 10.0),
    q=st.floats(0.0, 1.0),
    eps=st.floats(0.0, 0.2),
)
def test_smoothing_invariants(
    seed: int, n: int, start_std: float, end_std: float, q: float, eps: float
) -> None:
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.7, (n, 2))
    a, b = rng.uniform(-50.0, 50.0, (2, 2))
    track = smooth_between_anchors(
        steps, a, b, start_std_m=start_std, end_std_m=end_std, noise=DeadReckoningNoise(q, eps)
    )
    assert track.xy.shape == (n + 1, 2)
    assert track.std_m.shape == (n + 1,)
    assert np.all((track.xi >= 0.0) & (track.xi <= 1.0))
    assert np.all(np.isfinite(track.xy))
    assert np.all(track.std_m <= np.minimum(track.forward_std_m, track.backward_std_m) + 1e-9)
    # every smoothed point lies between its forward and backward solutions
    gap = np.hypot(*(track.forward_xy - track.backward_xy).T)
    to_fwd = np.hypot(*(track.xy - track.forward_xy).T)
    to_bwd = np.hypot(*(track.xy - track.backward_xy).T)
    np.testing.assert_allclose(to_fwd + to_bwd, gap, atol=1e-9)


# ------------------------------------------------------------------- endpoint test


def test_endpoint_threshold_is_the_papers_20_m() -> None:
    assert MAX_ENDPOINT_MISMATCH_M == 20.0


def test_endpoint_test_rejects_a_drifted_segment_and_keeps_a_close_one() -> None:
    a, b = TRUE_WALK[0], TRUE_WALK[-1]
    close = _drifting_pdr(TRUE_WALK, 4.0, 1.03)
    far = _drifting_pdr(TRUE_WALK, 20.0, 1.0)
    close_m, close_back_m = endpoint_mismatch_m(close, a, b)
    far_m, far_back_m = endpoint_mismatch_m(far, a, b)
    assert 4.0 < close_m < 10.0
    assert far_m > 25.0
    # the same steps run backwards miss the start by as much
    assert close_back_m == pytest.approx(close_m)
    assert far_back_m == pytest.approx(far_m)
    assert passes_endpoint_test(close, a, b)
    assert not passes_endpoint_test(far, a, b)


def test_endpoint_test_boundary_and_backward_run() -> None:
    steps = np.tile([1.0, 0.0], (10, 1))
    assert endpoint_mismatch_m(steps, [0.0, 0.0], [10.0, 20.0]) == (20.0, 20.0)
    assert passes_endpoint_test(steps, [0.0, 0.0], [10.0, 20.0])
    assert not passes_endpoint_test(steps, [0.0, 0.0], [10.0, 20.5])
    # forward lands on B, but a backward run that drifted misses A by 30 m
    back = np.tile([1.0, -3.0], (10, 1))
    assert endpoint_mismatch_m(steps, [0.0, 0.0], [10.0, 0.0], backward_steps_xy=back) == (
        0.0,
        30.0,
    )
    assert not passes_endpoint_test(steps, [0.0, 0.0], [10.0, 0.0], backward_steps_xy=back)
    assert passes_endpoint_test(steps, [0.0, 0.0], [10.0, 0.0], max_mismatch_m=0.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"steps_xy": [1.0, 2.0]}, "steps_xy"),
        ({"steps_xy": [[1.0, float("inf")]]}, "steps_xy"),
        ({"start_xy": [0.0, 0.0, 0.0]}, "start_xy"),
        ({"end_xy": [float("nan"), 0.0]}, "end_xy"),
        ({"backward_steps_xy": [[1.0, 0.0], [1.0, 0.0]]}, "backward_steps_xy"),
        ({"start_std_m": -1.0}, "start_std_m"),
        ({"end_std_m": float("nan")}, "end_std_m"),
    ],
)
def test_smoothing_refuses_bad_input(kwargs: dict[str, object], match: str) -> None:
    args: dict[str, object] = {
        "steps_xy": [[1.0, 0.0]],
        "start_xy": [0.0, 0.0],
        "end_xy": [1.0, 0.0],
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        smooth_between_anchors(**args)  # type: ignore[arg-type]


def test_noise_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="step_std_m"):
        DeadReckoningNoise(step_std_m=-0.1)
    with pytest.raises(ValueError, match="drift_per_m"):
        DeadReckoningNoise(drift_per_m=float("inf"))
    with pytest.raises(ValueError, match="max_mismatch_m"):
        passes_endpoint_test([[1.0, 0.0]], [0.0, 0.0], [1.0, 0.0], max_mismatch_m=-1.0)
