"""Gyro/compass heading fusion (``papers/003_*`` section III) on synthetic walks.

A gyro with a bias, a stretch of disturbed magnetic field, a turn, batches cut anywhere.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.positioning.model import state_codec
from server.positioning.motion.heading_fusion import (
    HeadingParams,
    HeadingState,
    fuse_heading,
    initial_heading,
)
from tests.support.synthetic_phone import (
    T0_MS,
    angle_error_deg,
    short_walk,
    split_at,
    walk,
)


def test_fused_heading_survives_gyro_bias_and_a_disturbed_stretch() -> None:
    data = walk()
    params = HeadingParams()
    _, fused = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)
    _, gyro_only = fuse_heading(
        initial_heading(params), data.gyro, data.accel, np.zeros((0, 4)), params
    )
    truth = data.heading_rad

    assert fused.shape == (len(data.gyro), 3)
    np.testing.assert_array_equal(fused[:, 0], data.gyro[:, 0])
    assert angle_error_deg(fused[-1, 1], truth[-1]) < 2.0
    assert np.max(angle_error_deg(fused[-500:, 1], truth[-500:])) < 2.0
    # integrating the gyro alone from the true start drifts: the bias about the vertical
    # (0.47 deg/s, 28 deg in 60 s) less the walking accelerations leaking into the up vector
    drifted = truth[0] + gyro_only[-1, 1] - gyro_only[0, 1]
    assert angle_error_deg(drifted, truth[-1]) > 10.0


def test_disturbed_stretch_is_not_quasi_static() -> None:
    data = walk()
    params = HeadingParams()
    _, fused = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)
    qsmf = fused[:, 2] == 1.0
    t_s = (fused[:, 0] - T0_MS) / 1000.0
    clean = ~data.disturbed & (t_s > 2.0)

    assert np.isin(fused[:, 2], [0.0, 1.0]).all()
    assert qsmf[data.disturbed].mean() < 0.1
    assert qsmf[clean].mean() > 0.8


def test_fused_heading_follows_a_turn_and_the_sway() -> None:
    data = walk(duration_s=30.0, heading0_deg=-120.0, disturbed_s=None, turn=(10.0, 3.0, 90.0))
    params = HeadingParams()
    _, fused = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)
    assert np.max(angle_error_deg(fused[500:, 1], data.heading_rad[500:])) < 2.0


def test_gyro_only_heading_starts_at_zero_and_is_never_quasi_static() -> None:
    data = walk(duration_s=5.0, disturbed_s=None)
    params = HeadingParams()
    state, out = fuse_heading(
        initial_heading(params), data.gyro, data.accel, np.empty((0, 4)), params
    )
    assert out[0, 1] == 0.0
    assert not state.initialized
    assert (out[:, 2] == 0.0).all()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=3))
def test_fuse_heading_is_incremental(fractions: list[float]) -> None:
    data = short_walk()
    params = HeadingParams()
    t_min, t_max = data.gyro[0, 0], data.gyro[-1, 0] + 1.0
    cuts = sorted(t_min + f * (t_max - t_min) for f in fractions)
    _, whole = fuse_heading(initial_heading(params), data.gyro, data.accel, data.magnetic, params)

    state = initial_heading(params)
    parts = []
    gyro, accel, magnetic = data.gyro, data.accel, data.magnetic
    for cut in [*cuts, math.inf]:
        g_now, gyro = split_at(gyro, cut)
        a_now, accel = split_at(accel, cut)
        m_now, magnetic = split_at(magnetic, cut)
        state, out = fuse_heading(
            state_codec.from_arrays(HeadingState, state_codec.to_arrays(state)),
            g_now,
            a_now,
            m_now,
            params,
        )
        parts.append(out)
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=0.0, atol=1e-9)


def test_heading_state_round_trips_through_arrays() -> None:
    data = short_walk()
    h_params = HeadingParams()
    h_state, _ = fuse_heading(
        initial_heading(h_params), data.gyro, data.accel, data.magnetic, h_params
    )
    for state in (h_state, initial_heading(h_params)):
        arrays = state_codec.to_arrays(state)
        again = state_codec.to_arrays(state_codec.from_arrays(type(state), arrays))
        assert arrays.keys() == again.keys()
        for key, value in arrays.items():
            assert value.dtype == again[key].dtype
            np.testing.assert_array_equal(value, again[key])
    assert 0 < len(h_state.window) <= h_params.window_entries + 2
    with pytest.raises(ValueError, match="must have shape"):
        state_codec.from_arrays(
            HeadingState, {**state_codec.to_arrays(h_state), "gravity": np.zeros(2)}
        )


def test_heading_params_are_validated() -> None:
    with pytest.raises(ValueError, match="window_s"):
        HeadingParams(window_s=0.0)
    assert dataclasses.replace(HeadingParams(), q_bias=1e-6).q_bias == 1e-6
