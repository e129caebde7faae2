"""Magnetic sequence distances: DTW against a reference, MMSE by hand, ranking."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.magnetic.sequence_distance import densified, dtw_distance, mmse

NAN = float("nan")


def _reference_dtw(a: list[float], b: list[float]) -> float:
    D = [[math.inf] * (len(b) + 1) for _ in range(len(a) + 1)]
    D[0][0] = 0.0
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            D[i][j] = abs(a[i - 1] - b[j - 1]) + min(D[i - 1][j], D[i][j - 1], D[i - 1][j - 1])
    return D[len(a)][len(b)]


values_ut = st.floats(20.0, 70.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    observed=st.lists(values_ut, min_size=1, max_size=7),
    m=st.integers(1, 7),
    n=st.integers(1, 5),
    data=st.data(),
)
def test_dtw_equals_the_reference(
    observed: list[float], m: int, n: int, data: st.DataObject
) -> None:
    rows = [data.draw(st.lists(values_ut, min_size=m, max_size=m)) for _ in range(n)]
    got = dtw_distance(observed, rows)
    assert got.shape == (n,)
    np.testing.assert_allclose(got, [_reference_dtw(observed, r) for r in rows], rtol=1e-12)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), w=st.integers(1, 8))
def test_dtw_is_zero_on_itself_and_at_most_l1(seed: int, w: int) -> None:
    rng = np.random.default_rng(seed)
    observed = rng.normal(45.0, 5.0, w)
    candidates = np.vstack([observed, rng.normal(45.0, 5.0, (20, w))])
    d = dtw_distance(observed, candidates)
    assert d[0] == 0.0
    l1 = np.abs(candidates - observed).sum(axis=1)
    assert np.all(d <= l1 + 1e-9)


def test_dtw_handles_a_time_shift_better_than_l1() -> None:
    observed = np.array([40.0, 40.0, 44.0, 48.0, 52.0, 52.0])
    shifted = np.array([40.0, 44.0, 48.0, 52.0, 52.0, 52.0])  # one sample earlier
    l1 = np.abs(shifted - observed).sum()
    assert l1 == 12.0
    assert dtw_distance(observed, shifted[None, :])[0] == 0.0


def test_nan_rows_give_inf() -> None:
    observed = [40.0, 42.0, 41.0, 45.0]
    candidates = np.array([[40.0, 42.0, 41.0, 45.0], [40.0, NAN, 41.0, 45.0], [NAN] * 4])
    np.testing.assert_array_equal(dtw_distance(observed, candidates), [0.0, np.inf, np.inf])
    np.testing.assert_array_equal(mmse(observed, candidates), [0.0, np.inf, np.inf])
    with pytest.raises(ValueError, match="observed must be finite"):
        dtw_distance([40.0, NAN], candidates[:, :2])


def test_mmse_by_hand() -> None:
    observed = [40.0, 42.0, 41.0, 45.0]  # |Δ| = 2, 1, 4
    candidates = [
        [50.0, 52.0, 51.0, 55.0],  # offset by 10 µT: same changes, error 0
        [40.0, 40.0, 40.0, 40.0],  # |Δ| = 0, 0, 0 -> (2 + 1 + 4) / 3
        [45.0, 42.0, 40.0, 40.0],  # |Δ| = 3, 2, 0 -> (1 + 1 + 4) / 3
        [40.0, 38.0, 39.0, 35.0],  # mirrored changes have the same |Δ|
    ]
    np.testing.assert_allclose(mmse(observed, candidates), [0.0, 7.0 / 3.0, 2.0, 0.0])
    with pytest.raises(ValueError, match="candidates must have shape"):
        mmse(observed, [[40.0, 41.0, 42.0]])
    with pytest.raises(ValueError, match="at least two"):
        mmse([40.0], [[40.0]])


def _paper_window(rng: np.random.Generator, n: int) -> tuple[NDArray[np.float64], ...]:
    return rng.normal(45.0, 5.0, 4), rng.normal(45.0, 5.0, (n, 4))


def test_distances_rank_the_true_sequence_first() -> None:
    rng = np.random.default_rng(5)
    observed, candidates = _paper_window(rng, 3000)
    candidates[1234] = observed + 3.0  # a calibration offset: DTW sees it, eq (b) does not
    assert int(np.argmin(mmse(observed, candidates))) == 1234
    candidates[1234] = observed
    assert int(np.argmin(dtw_distance(observed, candidates))) == 1234


def test_densified_samples_each_step_linearly_and_keeps_the_magnitudes() -> None:
    seq = np.array([[40.0, 44.0, 42.0], [30.0, 30.0, np.nan]])
    dense = densified(seq, 4)
    np.testing.assert_allclose(dense[0], [40, 41, 42, 43, 44, 43.5, 43, 42.5, 42])
    assert dense[0, ::4].tolist() == [40.0, 44.0, 42.0]  # every step's own magnitude
    assert np.isnan(dense[1, -1])
    assert not np.isnan(dense[1, :4]).any()
    np.testing.assert_array_equal(densified(seq, 1), seq)
