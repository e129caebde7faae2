"""The reported radii: a Gaussian's own with the identity calibration, consistent with the
reported covariance with any, and floors that grow with the map's radio error."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.model.accuracy import R68, R95, AccuracyParams, calibrated
from server.positioning.model.events import Fix
from server.positioning.model.params import ParamError


def fix(var_m2: float, **diagnostics: float) -> Fix:
    return Fix(0, 1.0, 2.0, 0, None, (var_m2, 0.0, 0.0, var_m2), "wifi", dict(diagnostics))


def test_the_identity_calibration_gives_a_gaussians_radii() -> None:
    assert pytest.approx(1.5096, abs=1e-4) == R68
    assert pytest.approx(2.4477, abs=1e-4) == R95
    rng = np.random.default_rng(0)
    sigma = 3.0
    errors = np.hypot(*rng.normal(0.0, sigma, (2, 200_000)))
    out = calibrated(fix(sigma**2, floor_prob=0.8), AccuracyParams(), 20.0)
    assert out.cov == (9.0, 0.0, 0.0, 9.0)
    assert np.mean(errors <= out.accuracy_68_m) == pytest.approx(0.68, abs=0.005)
    assert np.mean(errors <= out.accuracy_95_m) == pytest.approx(0.95, abs=0.005)
    assert out.floor_prob == 0.8


@given(
    st.floats(0.01, 400.0),
    st.floats(0.0, 3.0),
    st.floats(0.1, 8.0),
    st.floats(0.0, 3.0),
    st.floats(1.0, 3.0),
    st.floats(1.0, 50.0),
)
def test_the_reported_covariance_has_the_68_radius(
    var: float, floor68: float, scale68: float, more95: float, ratio95: float, error: float
) -> None:
    floor95, scale95 = floor68 + more95, scale68 * ratio95
    params = AccuracyParams(floor68, scale68, floor95, scale95)
    out = calibrated(fix(var), params, error)
    sigma = math.sqrt(var)
    assert out.accuracy_68_m == pytest.approx(math.hypot(floor68 * error, scale68 * R68 * sigma))
    assert out.accuracy_95_m == pytest.approx(math.hypot(floor95 * error, scale95 * R95 * sigma))
    assert out.uncertainty_m * R68 == pytest.approx(out.accuracy_68_m)
    assert math.isnan(out.floor_prob)


def test_an_engine_sure_to_the_metre_still_reports_its_floor() -> None:
    out = calibrated(fix(0.0), AccuracyParams(floor_68=0.5, floor_95=1.0), 12.0)
    assert out.accuracy_68_m == 6.0
    assert out.accuracy_95_m == 12.0
    assert out.uncertainty_m * R68 == pytest.approx(6.0)


def test_the_floors_are_in_the_maps_radio_error() -> None:
    params = AccuracyParams(floor_68=0.8, scale_68=1.0, floor_95=2.0, scale_95=1.0)
    campus, mall = calibrated(fix(1.0), params, 8.0), calibrated(fix(1.0), params, 20.0)
    assert campus.accuracy_68_m == pytest.approx(math.hypot(6.4, R68))
    assert mall.accuracy_68_m == pytest.approx(math.hypot(16.0, R68))
    assert mall.accuracy_95_m == pytest.approx(math.hypot(40.0, R95))


def test_bounds_are_checked() -> None:
    with pytest.raises(ParamError, match="floor_68"):
        AccuracyParams(floor_68=-1.0)
    with pytest.raises(ParamError, match="scale_95"):
        AccuracyParams(scale_95=0.0)
    # the 95 % radius is never the smaller one, nor absurdly large
    with pytest.raises(ParamError, match="floor_95: must not be below floor_68"):
        AccuracyParams(floor_68=5.0, floor_95=2.0)
    with pytest.raises(ParamError, match="scale_95: must be at least"):
        AccuracyParams(scale_68=2.0, scale_95=1.0)
    with pytest.raises(ParamError, match="scale_68: must be at most 100"):
        AccuracyParams(scale_68=200.0, scale_95=400.0)
