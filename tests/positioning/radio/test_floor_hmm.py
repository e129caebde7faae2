"""The floor filter: a discrete Bayes filter over floors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import special

from server.positioning.radio import floor_hmm


def test_no_time_no_change_and_a_long_gap_forgets() -> None:
    logp = np.log(np.array([0.9, 0.05, 0.05]))
    np.testing.assert_allclose(floor_hmm.predict(logp, 0.0, 0.01), logp)
    np.testing.assert_allclose(np.exp(floor_hmm.predict(logp, 1e6, 0.01)), [1 / 3] * 3)


def test_rate_is_per_second() -> None:
    logp = np.log(np.array([1.0 - 1e-12, 1e-12]))
    after = np.exp(floor_hmm.predict(logp, 10.0, 0.01))
    eps = 1.0 - math.exp(-0.1)
    assert after[1] == pytest.approx(eps / 2, rel=1e-6)


def test_nothing_known_stays_unknown() -> None:
    empty = np.zeros(0)
    assert floor_hmm.prior(empty, 0, 1000, 0.01) is None
    one = np.zeros(1)
    np.testing.assert_array_equal(floor_hmm.predict(one, 5.0, 0.01), one)


@settings(max_examples=200, deadline=None)
@given(
    p=st.lists(st.floats(1e-6, 1.0), min_size=2, max_size=9),
    dt=st.floats(0.0, 1e5),
    rate=st.floats(0.0, 1.0),
)
def test_prediction_is_a_distribution_nearer_uniform(
    p: list[float], dt: float, rate: float
) -> None:
    probs = np.array(p) / np.sum(p)
    out = np.exp(floor_hmm.predict(np.log(probs), dt, rate))
    assert out.sum() == pytest.approx(1.0)
    assert np.all(out >= 0)
    # mixing with the uniform distribution never moves a floor away from 1/n
    n = len(p)
    assert np.all(np.abs(out - 1 / n) <= np.abs(probs - 1 / n) + 1e-9)


def _same_bits(a: float, b: float) -> bool:
    """Equal to the last bit, NaN included and the sign of zero told apart."""
    return np.float64(a).tobytes() == np.float64(b).tobytes() or (math.isnan(a) and math.isnan(b))


@settings(max_examples=500, deadline=None)
@given(
    values=st.lists(
        st.floats(-1e300, 1e300, allow_nan=False)
        | st.sampled_from([0.0, -0.0, -1.0, -np.inf, np.inf, np.nan, 709.0, -745.0]),
        min_size=1,
        max_size=40,
    )
)
def test_logsumexp_is_scipys_to_the_bit(values: list[float]) -> None:
    a = np.array(values)
    assert _same_bits(floor_hmm.logsumexp(a), float(special.logsumexp(a)))


def test_logsumexp_of_ties_and_long_arrays_is_scipys_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 8, 9, 130, 1000):
        for a in (rng.normal(0, 30, n), np.round(rng.normal(0, 2, n)), np.zeros(n)):
            a[rng.random(n) < 0.2] = -np.inf
            assert _same_bits(floor_hmm.logsumexp(a), float(special.logsumexp(a)))
