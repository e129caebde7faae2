"""Emitter position and path-loss least squares: accuracy, honest covariance, refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.stats import chi2

from server.positioning.radio.path_loss import EmitterFit, fit_emitter, rss_at

FloatArray = NDArray[np.float64]

P0_DBM = -40.0
EXPONENT = 2.5
NOISE_DB = 2.0


def _survey(
    seed: int, n: int = 30, noise_db: float = NOISE_DB
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """An emitter somewhere in the middle of a 40 m x 40 m floor heard at ``n`` random
    places with Gaussian RSS noise: ``(emitter_xy, xy, rss_dbm)``. Nearer than 1 m the
    RSS stays at ``P0``, as in the model."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 40.0, (n, 2))
    emitter = rng.uniform(10.0, 30.0, 2)
    d = np.maximum(np.hypot(*(xy - emitter).T), 1.0)
    rss = P0_DBM - 10.0 * EXPONENT * np.log10(d) + rng.normal(0.0, noise_db, n)
    return emitter, xy, rss


def _fit(xy: FloatArray, rss: FloatArray, **kwargs: object) -> EmitterFit:
    fit = fit_emitter(xy, rss, **kwargs)  # type: ignore[arg-type]
    assert fit is not None
    return fit


def test_noiseless_readings_are_fitted_exactly() -> None:
    emitter, xy, _ = _survey(0)
    rss = P0_DBM - 10.0 * EXPONENT * np.log10(np.maximum(np.hypot(*(xy - emitter).T), 1.0))
    fit = _fit(xy, rss)
    np.testing.assert_allclose(fit.xy, emitter, atol=1e-6)
    assert fit.p0_dbm == pytest.approx(P0_DBM, abs=1e-6)
    assert fit.exponent == pytest.approx(EXPONENT, abs=1e-7)
    assert fit.residual_rms_db < 1e-6
    assert fit.n == 30
    np.testing.assert_allclose(rss_at(fit, xy), rss, atol=1e-6)


@pytest.mark.parametrize("seed", range(20))
def test_estimate_is_close_with_2_db_noise(seed: int) -> None:
    # over 200 seeds of this set-up the position error has median 0.64 m and 99th
    # percentile 2.45 m, the exponent error median 0.14 and 99th percentile 0.54
    emitter, xy, rss = _survey(seed)
    fit = _fit(xy, rss)
    assert np.hypot(*(fit.xy - emitter)) < 2.5
    assert abs(fit.exponent - EXPONENT) < 0.6
    assert 1.0 < fit.residual_rms_db < 3.0  # about the noise, less the 4 fitted dof


def test_estimate_is_close_on_average() -> None:
    pos, expo, p0 = [], [], []
    for seed in range(20):
        emitter, xy, rss = _survey(seed)
        fit = _fit(xy, rss)
        pos.append(np.hypot(*(fit.xy - emitter)))
        expo.append(abs(fit.exponent - EXPONENT))
        p0.append(abs(fit.p0_dbm - P0_DBM))
    assert np.median(pos) < 1.0
    assert np.median(expo) < 0.3
    assert np.median(p0) < 3.0  # P0 is an extrapolation to 1 m: its std is about 2 dB


@pytest.mark.parametrize("rss_std_db", [None, NOISE_DB])
def test_reported_uncertainty_covers_the_error(rss_std_db: float | None) -> None:
    within_3_std = []
    mahalanobis2 = []
    for seed in range(50):
        emitter, xy, rss = _survey(seed)
        fit = _fit(xy, rss, rss_std_db=rss_std_db)
        truth = np.array([*emitter, P0_DBM, EXPONENT])
        err = np.array([*fit.xy, fit.p0_dbm, fit.exponent]) - truth
        within_3_std.append(np.all(np.abs(err) < 3.0 * fit.std))
        mahalanobis2.append(float(err @ np.linalg.solve(fit.cov, err)))
    assert np.mean(within_3_std) >= 0.9
    assert np.mean(np.array(mahalanobis2) < chi2.ppf(0.99, df=4)) >= 0.9
    # and it is not inflated: the 4-D errors are spread like chi2(4), mean about 4
    assert 2.0 < np.mean(mahalanobis2) < 8.0


def test_covariance_is_symmetric_positive_definite_and_shrinks_with_more_readings() -> None:
    few = _fit(*_survey(4, n=10)[1:])
    many = _fit(*_survey(4, n=200)[1:])
    for fit in (few, many):
        np.testing.assert_array_equal(fit.cov, fit.cov.T)
        assert np.all(np.linalg.eigvalsh(fit.cov) > 0)
        assert fit.xy_std_m.shape == (2,)
    assert np.all(many.std < few.std)


def test_a_robust_loss_resists_readings_behind_walls() -> None:
    linear: list[float] = []
    robust: list[float] = []
    for seed in range(20):
        emitter, xy, rss = _survey(seed)
        rng = np.random.default_rng(1000 + seed)
        rss[rng.choice(rss.size, 4, replace=False)] -= 25.0  # 4 of 30 readings blocked
        for loss, errors in (("linear", linear), ("soft_l1", robust)):
            fit = _fit(xy, rss, loss=loss, f_scale_db=3.0)
            errors.append(float(np.hypot(*(fit.xy - emitter))))
    assert np.median(robust) < 1.5
    assert np.median(robust) < 0.6 * np.median(linear)


def test_exactly_four_readings_fit_but_have_unknown_noise() -> None:
    emitter, xy, _ = _survey(0, n=4)
    rss = P0_DBM - 10.0 * EXPONENT * np.log10(np.maximum(np.hypot(*(xy - emitter).T), 1.0))
    fit = _fit(xy, rss)
    assert fit.n == 4
    assert np.all(np.isinf(fit.cov))
    given = _fit(xy, rss, rss_std_db=2.0)
    assert np.all(np.isfinite(given.cov))


def test_too_few_readings_are_refused() -> None:
    _, xy, rss = _survey(0, n=3)
    assert fit_emitter(xy, rss) is None
    assert fit_emitter(np.empty((0, 2)), np.empty(0)) is None


@pytest.mark.parametrize("width_m", [0.0, 1e-9, 1.0])
def test_readings_along_one_line_are_refused(width_m: float) -> None:
    # the emitter 5 m off a 40 m line: from the line it can't be told from its mirror
    rng = np.random.default_rng(0)
    xy = np.column_stack([np.linspace(0.0, 40.0, 30), rng.uniform(-0.5, 0.5, 30) * width_m])
    rss = P0_DBM - 10.0 * EXPONENT * np.log10(np.hypot(xy[:, 0] - 20.0, xy[:, 1] - 5.0))
    assert fit_emitter(xy, rss) is None
    assert fit_emitter(np.zeros((10, 2)), rss[:10]) is None  # all in one place


def test_rss_at_keeps_the_leading_shape_and_floors_at_1_m() -> None:
    fit = EmitterFit(
        xy=np.array([0.0, 0.0]),
        p0_dbm=-40.0,
        exponent=2.0,
        cov=np.eye(4),
        residual_rms_db=0.0,
        n=10,
    )
    grid = np.array([[[0.0, 0.0], [0.5, 0.0]], [[10.0, 0.0], [0.0, 100.0]]])
    np.testing.assert_allclose(rss_at(fit, grid), [[-40.0, -40.0], [-60.0, -80.0]])
    assert rss_at(fit, [3.0, 4.0]).shape == ()
    with pytest.raises(ValueError, match="xy"):
        rss_at(fit, [1.0, 2.0, 3.0])


def _noiseless(seed: int, p0: float, exponent: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """An emitter in the middle of a 40 m x 40 m floor heard without noise at 25 random
    places, exactly as the model says (nearer than 1 m the RSS is ``P0``):
    ``(emitter_xy, xy, rss_dbm)``."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 40.0, (25, 2))
    emitter = rng.uniform(5.0, 35.0, 2)
    d = np.maximum(np.hypot(*(xy - emitter).T), 1.0)
    return emitter, xy, p0 - 10.0 * exponent * np.log10(d)


def _assert_recovered(seed: int, p0: float, exponent: float) -> None:
    emitter, xy, rss = _noiseless(seed, p0, exponent)
    fit = _fit(xy, rss)
    assert np.hypot(*(fit.xy - emitter)) < 1e-3, (seed, p0, exponent, fit.xy, emitter)
    assert fit.exponent == pytest.approx(exponent, abs=1e-4)
    assert fit.p0_dbm == pytest.approx(p0, abs=1e-3)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    p0=st.floats(-60.0, -25.0),
    exponent=st.floats(1.5, 4.5),
)
def test_fit_recovers_any_plausible_model_without_noise(
    seed: int, p0: float, exponent: float
) -> None:
    # readings at any distance, those within 1 m of the emitter included
    _assert_recovered(seed, p0, exponent)


@pytest.mark.parametrize(
    ("seed", "p0", "exponent"),
    [
        # the fitter of before stopped in a local minimum 0.126 m off on this layout (a
        # reading 1.09 m from the emitter), whatever P0 and nearly whatever gamma
        (232, -27.770528332273358, 1.526599238121198),
        (232, -28.0, 1.5),
        (232, -37.39069933629055, 4.383990239186881),
    ],
)
def test_a_layout_that_trapped_the_solver_is_recovered(
    seed: int, p0: float, exponent: float
) -> None:
    _assert_recovered(seed, p0, exponent)


def test_fit_recovers_noiseless_models_over_many_seeds() -> None:
    # the fitter of before missed 8 of the first 2000 of these (232, 1023, 1067, ...);
    # this one missed none of them, nor any of 10000 such layouts tried while writing it
    missed = []
    for seed in range(300):
        p0, exponent = np.random.default_rng([seed, 1]).uniform([-60.0, 1.5], [-25.0, 4.5])
        try:
            _assert_recovered(seed, float(p0), float(exponent))
        except AssertionError:
            missed.append(seed)
    assert missed == []


@pytest.mark.parametrize(
    ("xy", "rss", "kwargs", "match"),
    [
        (np.zeros((5, 3)), np.zeros(5), {}, "xy"),
        (np.zeros((5, 2)), np.zeros(4), {}, "rss_dbm"),
        (np.zeros((5, 2)), np.full(5, math.nan), {}, "finite"),
        (np.zeros((5, 2)), np.zeros(5), {"rss_std_db": 0.0}, "rss_std_db"),
        (np.zeros((5, 2)), np.zeros(5), {"rss_std_db": [1.0, 2.0]}, "rss_std_db"),
        (np.zeros((5, 2)), np.zeros(5), {"f_scale_db": -1.0}, "f_scale_db"),
        (np.zeros((5, 2)), np.zeros(5), {"min_spread_ratio": 1.0}, "min_spread_ratio"),
    ],
)
def test_malformed_input_raises(
    xy: FloatArray, rss: FloatArray, kwargs: dict[str, object], match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        fit_emitter(xy, rss, **kwargs)  # type: ignore[arg-type]
