"""Kalman steps: hand-computed cases, the textbook form, and covariance invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from server.positioning.filters.kalman import (
    predict,
    predict_ekf,
    update,
    wrap_angle,
    wrap_angle_float,
)


def test_scalar_predict_update_by_hand() -> None:
    x, P = predict([1.0], [[2.0]], [[1.0]], [[0.5]])
    assert x.tolist() == [1.0]
    assert P.tolist() == [[2.5]]
    u = update(x, P, z=[3.0], H=[[1.0]], R=[[2.5]])
    # S = 5, K = 0.5, y = 2 -> x = 2, P = (1 - K)^2 P + K^2 R = 1.25, d2 = 4 / 5
    assert u.y.tolist() == [2.0]
    assert u.S.tolist() == [[5.0]]
    assert u.x.tolist() == pytest.approx([2.0])
    assert u.P.tolist() == [[pytest.approx(1.25)]]
    assert u.mahalanobis2 == pytest.approx(0.8)


def test_constant_velocity_by_hand() -> None:
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    x, P = predict([0.0, 1.0], np.eye(2), F, np.diag([0.0, 0.1]))
    np.testing.assert_allclose(x, [1.0, 1.0])
    np.testing.assert_allclose(P, [[2.0, 1.0], [1.0, 1.1]])
    u = update(x, P, z=[2.0], H=[[1.0, 0.0]], R=[[1.0]])
    # S = 3, K = [2/3, 1/3], y = 1
    np.testing.assert_allclose(u.x, [1.0 + 2.0 / 3.0, 1.0 + 1.0 / 3.0])
    np.testing.assert_allclose(u.P, [[2.0 / 3.0, 1.0 / 3.0], [1.0 / 3.0, 1.1 - 1.0 / 3.0]])
    assert u.mahalanobis2 == pytest.approx(1.0 / 3.0)


def test_predict_is_predict_ekf_of_the_linear_mean() -> None:
    rng = np.random.default_rng(1)
    F = rng.normal(size=(3, 3))
    A = rng.normal(size=(3, 3))
    P = A @ A.T + np.eye(3)
    Q = np.diag([0.1, 0.2, 0.3])
    x = rng.normal(size=3)
    x1, P1 = predict(x, P, F, Q)
    x2, P2 = predict_ekf(F @ x, P, F, Q)
    np.testing.assert_array_equal(x1, x2)
    np.testing.assert_array_equal(P1, P2)


def test_update_matches_textbook_gain() -> None:
    rng = np.random.default_rng(7)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + 0.5 * np.eye(4)
    H = rng.normal(size=(2, 4))
    R = np.diag([0.3, 0.7])
    x = rng.normal(size=4)
    z = rng.normal(size=2)
    u = update(x, P, z, H, R)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    y = z - H @ x
    np.testing.assert_allclose(u.x, x + K @ y, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(u.P, (np.eye(4) - K @ H) @ P, rtol=1e-9, atol=1e-12)
    assert u.mahalanobis2 == pytest.approx(float(y @ np.linalg.solve(S, y)))


def test_residual_wraps_angles() -> None:
    def angle_residual(z: NDArray[np.float64], z_pred: NDArray[np.float64]) -> NDArray[np.float64]:
        return wrap_angle(z - z_pred)

    u = update([math.pi - 0.05], [[1.0]], [-math.pi + 0.05], [[1.0]], [[1.0]], angle_residual)
    assert u.y[0] == pytest.approx(0.1)
    assert u.x[0] == pytest.approx(math.pi - 0.05 + 0.05)


def test_update_refuses_a_covariance_that_is_not_positive_definite() -> None:
    with pytest.raises(np.linalg.LinAlgError):
        update([0.0], [[1.0]], [1.0], [[1.0]], [[-2.0]])


@pytest.mark.parametrize(
    ("angle", "wrapped"),
    [
        (0.0, 0.0),
        (math.pi, math.pi),
        (-math.pi, math.pi),
        (3 * math.pi, math.pi),
        (1.5 * math.pi, -0.5 * math.pi),
        (-1.5 * math.pi, 0.5 * math.pi),
        (7.0, 7.0 - 2 * math.pi),
    ],
)
def test_wrap_angle(angle: float, wrapped: float) -> None:
    assert float(wrap_angle(angle)) == pytest.approx(wrapped)


@given(st.floats(-100.0, 100.0, allow_nan=False))
def test_wrap_angle_range(angle: float) -> None:
    w = float(wrap_angle(angle))
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(angle), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(angle), abs_tol=1e-9)


def _matrix(n: int, m: int) -> st.SearchStrategy[NDArray[np.float64]]:
    return arrays(np.float64, (n, m), elements=st.floats(-3.0, 3.0, allow_subnormal=False))


def _is_pd(M: NDArray[np.float64]) -> bool:
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return True


@settings(max_examples=200, deadline=None)
@given(
    A=_matrix(4, 4),
    F=_matrix(4, 4),
    B=_matrix(4, 4),
    H=_matrix(2, 4),
    C=_matrix(2, 2),
    x=arrays(np.float64, 4, elements=st.floats(-10.0, 10.0)),
    z=arrays(np.float64, 2, elements=st.floats(-10.0, 10.0)),
)
def test_covariance_stays_symmetric_positive_definite(
    A: NDArray[np.float64],
    F: NDArray[np.float64],
    B: NDArray[np.float64],
    H: NDArray[np.float64],
    C: NDArray[np.float64],
    x: NDArray[np.float64],
    z: NDArray[np.float64],
) -> None:
    P = A @ A.T + 0.01 * np.eye(4)
    Q = B @ B.T + 1e-3 * np.eye(4)
    R = C @ C.T + 1e-2 * np.eye(2)
    xp, Pp = predict(x, P, F, Q)
    assert np.array_equal(Pp, Pp.T)
    assert _is_pd(Pp)
    u = update(xp, Pp, z, H, R)
    assert np.array_equal(u.P, u.P.T)
    assert _is_pd(u.P)
    assert u.mahalanobis2 >= 0.0
    # a measurement never adds uncertainty
    assert np.trace(u.P) <= np.trace(Pp) * (1 + 1e-9)


@given(
    st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from([0.0, -0.0, math.pi, -math.pi, 3 * math.pi, -2 * math.pi, 1e-300])
    | st.integers(-1000, 1000).map(lambda k: k * math.pi)
)
def test_wrap_angle_float_is_wrap_angle_to_the_bit(angle: float) -> None:
    with np.errstate(invalid="ignore"):  # wrap_angle of an infinity is NaN
        expected = float(wrap_angle(angle))
        got = wrap_angle_float(angle)
    assert np.float64(got).tobytes() == np.float64(expected).tobytes() or (
        math.isnan(got) and math.isnan(expected)
    )
