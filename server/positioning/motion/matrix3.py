"""3×3 matrices as tuples of nine floats (row-major): the algebra of ``attitude_ekf``.

The attitude filter runs one predict and one update per gyro sample, in a Python loop
(each step depends on the previous one). At this size numpy's per-call cost dominates:
over a real trace the same filter built on ``server.positioning.filters.kalman`` (``predict_ekf``
and ``update``) takes 6-8x as long as with these functions (the figures and the command
that measures them: ``attitude_ekf``), so the products, the transpose and the inverse are
written out here.
"""

from __future__ import annotations

from collections.abc import Sequence

Matrix3 = tuple[float, float, float, float, float, float, float, float, float]


def matrix3(values: Sequence[float]) -> Matrix3:
    """The first nine values, row-major."""
    v = values
    return (v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])


def diagonal(d: Sequence[float]) -> Matrix3:
    """``diag(d[0], d[1], d[2])``."""
    return (d[0], 0.0, 0.0, 0.0, d[1], 0.0, 0.0, 0.0, d[2])


def mul(A: Matrix3, B: Matrix3) -> Matrix3:
    """``A B``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = A
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = B
    return (
        a0 * b0 + a1 * b3 + a2 * b6,
        a0 * b1 + a1 * b4 + a2 * b7,
        a0 * b2 + a1 * b5 + a2 * b8,
        a3 * b0 + a4 * b3 + a5 * b6,
        a3 * b1 + a4 * b4 + a5 * b7,
        a3 * b2 + a4 * b5 + a5 * b8,
        a6 * b0 + a7 * b3 + a8 * b6,
        a6 * b1 + a7 * b4 + a8 * b7,
        a6 * b2 + a7 * b5 + a8 * b8,
    )


def add(A: Matrix3, B: Matrix3) -> Matrix3:
    """``A + B``."""
    return matrix3([a + b for a, b in zip(A, B, strict=True)])


def transpose(A: Matrix3) -> Matrix3:
    """``A^T``."""
    return (A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8])


def symmetric(A: Matrix3) -> Matrix3:
    """``(A + A^T) / 2``."""
    a1, a2, a5 = 0.5 * (A[1] + A[3]), 0.5 * (A[2] + A[6]), 0.5 * (A[5] + A[7])
    return (A[0], a1, a2, a1, A[4], a5, a2, a5, A[8])


def inverse(A: Matrix3) -> Matrix3:
    """``A^-1`` by cofactors.

    Raises
    ------
    ZeroDivisionError
        When ``A`` is singular (its determinant is exactly 0).
    """
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = A
    c0, c3, c6 = a4 * a8 - a5 * a7, a5 * a6 - a3 * a8, a3 * a7 - a4 * a6
    det = a0 * c0 + a1 * c3 + a2 * c6
    return (
        c0 / det,
        (a2 * a7 - a1 * a8) / det,
        (a1 * a5 - a2 * a4) / det,
        c3 / det,
        (a0 * a8 - a2 * a6) / det,
        (a2 * a3 - a0 * a5) / det,
        c6 / det,
        (a1 * a6 - a0 * a7) / det,
        (a0 * a4 - a1 * a3) / det,
    )
