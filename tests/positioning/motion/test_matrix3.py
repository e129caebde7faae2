"""The attitude filter's 3×3 algebra equals numpy's."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.motion import matrix3 as m3

entries = st.lists(st.floats(-10.0, 10.0), min_size=9, max_size=9)


def as_array(A: m3.Matrix3) -> np.ndarray:
    return np.array(A).reshape(3, 3)


@given(a=entries, b=entries)
def test_products_sums_and_transposes_are_numpys(a: list[float], b: list[float]) -> None:
    A, B = m3.matrix3(a), m3.matrix3(b)
    np.testing.assert_allclose(as_array(m3.mul(A, B)), as_array(A) @ as_array(B), atol=1e-12)
    np.testing.assert_array_equal(as_array(m3.add(A, B)), as_array(A) + as_array(B))
    np.testing.assert_array_equal(as_array(m3.transpose(A)), as_array(A).T)
    np.testing.assert_array_equal(as_array(m3.symmetric(A)), 0.5 * (as_array(A) + as_array(A).T))
    np.testing.assert_array_equal(as_array(m3.diagonal(a[:3])), np.diag(a[:3]))


@given(d=st.lists(st.floats(0.1, 10.0), min_size=3, max_size=3), a=entries)
def test_inverse_of_a_positive_definite_matrix(d: list[float], a: list[float]) -> None:
    L = np.array(a).reshape(3, 3)
    S = L @ L.T + np.diag(d)  # like H P H^T + R
    inverse = as_array(m3.inverse(m3.matrix3(S.ravel().tolist())))
    np.testing.assert_allclose(inverse @ S, np.eye(3), atol=1e-9)
