"""The fix error table: σ by scan kind and matched emitters, learned from known errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from server.positioning.radio import fix_error
from server.positioning.radio.fix_error import EDGES, FixErrorModel, fit


def rayleigh(sigma: float, n: int, rng: np.random.Generator) -> np.ndarray:
    return np.hypot(rng.normal(0, sigma, n), rng.normal(0, sigma, n))


def test_recovers_the_sigma_of_gaussian_errors_per_bin() -> None:
    rng = np.random.default_rng(0)
    n_matched = np.repeat([2, 10, 40], 4000)
    true_sigma = {2: 12.0, 10: 6.0, 40: 3.0}
    errors = np.concatenate([rayleigh(true_sigma[n], 4000, rng) for n in (2, 10, 40)])
    model = fit(["wifi"] * n_matched.size, n_matched, errors)
    for n, s in true_sigma.items():
        assert model.sigma("wifi", n) == pytest.approx(s, rel=0.05)
    # the 1-σ circle holds 39 % of the errors
    inside = np.mean(errors <= np.array([model.sigma("wifi", int(n)) for n in n_matched]))
    assert inside == pytest.approx(1 - math.exp(-0.5), abs=0.02)


def test_more_emitters_never_mean_a_worse_fix() -> None:
    rng = np.random.default_rng(1)
    # the middle bin is noisier than its neighbours by chance; the table is made monotone
    n_matched = np.repeat([4, 8, 16], 300)
    errors = np.concatenate([rayleigh(s, 300, rng) for s in (8.0, 9.0, 5.0)])
    model = fit(["wifi"] * n_matched.size, n_matched, errors)
    table = model.sigma_m["wifi"]
    assert all(a >= b - 1e-12 for a, b in itertools.pairwise(table))


def test_kinds_are_learned_apart_and_unseen_kinds_use_the_default() -> None:
    rng = np.random.default_rng(2)
    kinds = ["wifi"] * 500 + ["ble"] * 500
    n_matched = np.full(1000, 5)
    errors = np.concatenate([rayleigh(4.0, 500, rng), rayleigh(15.0, 500, rng)])
    model = fit(kinds, n_matched, errors)
    assert model.sigma("ble", 5) > 3 * model.sigma("wifi", 5)
    assert model.sigma("uwb", 5) == fix_error.default_sigma_m(5)
    # bins without fixes take their neighbours' value, and fewer emitters than any seen
    # are never trusted more than the default
    assert model.sigma("wifi", 100) == model.sigma("wifi", 5)
    assert model.sigma("wifi", 1) >= fix_error.default_sigma_m(1)


def test_too_few_fixes_keep_the_default_and_nan_errors_are_ignored() -> None:
    model = fit(["wifi"] * 5, [5] * 5, [1.0, 2.0, np.nan, 3.0, 4.0])
    assert "wifi" not in model.sigma_m
    assert model.variance("wifi", 9) == fix_error.default_sigma_m(9) ** 2
    assert model.error_68_m == fix_error.DEFAULT_ERROR_68_M


def test_the_maps_radio_error_holds_68_percent_of_all_its_fixes() -> None:
    rng = np.random.default_rng(3)
    kinds = ["wifi"] * 3000 + ["ble"] * 1000
    errors = np.concatenate([rayleigh(4.0, 3000, rng), rayleigh(15.0, 1000, rng), [np.nan] * 50])
    model = fit([*kinds, *["ble"] * 50], np.full(errors.size, 5), errors)
    known = errors[np.isfinite(errors)]
    assert np.mean(known <= model.error_68_m) == pytest.approx(0.68, abs=0.001)
    # between the two kinds' own 68 % radii (1.5096 σ)
    assert 1.5096 * 4.0 < model.error_68_m < 1.5096 * 15.0


def test_default_model_falls_with_evidence() -> None:
    model = FixErrorModel()
    sig = [model.sigma("ble", e) for e in EDGES]
    assert all(a > b for a, b in itertools.pairwise(sig))
