"""Inertial data selection (``papers/003_*`` IV-A).

Thresholds are checked in closed form: a sinusoid of frequency ``f`` sampled every ``T``
comes out of the centred moving average of ``2N + 1`` samples scaled by the Dirichlet
kernel ``D = sin(π f (2N+1) T) / ((2N+1) sin(π f T))``, and out of ``a - LP(a)`` (the
gravity removal) scaled by ``|1 - α / (1 - (1 - α) e^{-iωT})|``; with ``f = 1/1.3 Hz`` a
2.6 s window holds exactly two periods, over which the variance of ``A sin`` is ``A²/2``.
The walks come from ``client_sim.imu`` (hand-held phone, 1.8 steps/s, sway and tremor).
"""

from __future__ import annotations

import itertools
import math
from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from client_sim.imu import Gait, ImuTrace, synthesize_walk
from server.positioning.mapping.selection import (
    InertialSelection,
    SelectionParams,
    select_inertial,
)
from server.positioning.motion.pdr import G, PdrParams

T0 = 1_700_000_000_000
F_HZ = 1.0 / 1.3  # two periods per 2.6 s window
PARAMS = SelectionParams()
T_S = PARAMS.pdr.grid_ms / 1000.0


def _dirichlet(f_hz: float, half_window: int, t_s: float) -> float:
    m = 2 * half_window + 1
    return math.sin(math.pi * f_hz * m * t_s) / (m * math.sin(math.pi * f_hz * t_s))


def _high_pass_gain(f_hz: float, tau_s: float, t_s: float) -> float:
    alpha = 1.0 - math.exp(-t_s / tau_s)
    z = complex(math.cos(2 * math.pi * f_hz * t_s), -math.sin(2 * math.pi * f_hz * t_s))
    return abs(1.0 - alpha / (1.0 - (1.0 - alpha) * z))


def _still(duration_s: float, rate_hz: float = 50.0) -> np.ndarray:
    t = T0 + np.arange(0, duration_s * 1000, 1000 / rate_hz)
    return np.column_stack([t, np.zeros_like(t), np.zeros_like(t), np.full_like(t, G)])


def _gyro_sine(amplitude: float, duration_s: float = 30.0) -> np.ndarray:
    t = T0 + np.arange(0, duration_s * 1000, 10.0)  # 100 Hz, as in papers/003_* VI-A
    x = amplitude * np.sin(2 * np.pi * F_HZ * (t - T0) / 1000)
    return np.column_stack([t, x, np.zeros_like(t), np.zeros_like(t)])


@cache
def _walk() -> ImuTrace:
    gait = Gait(
        tilt_x_rad=math.radians(20),
        sway_x_rad=math.radians(3),
        sway_y_rad=math.radians(3),
        heading_sway_rad=math.radians(3),
        tremor_ms2=0.1,
    )
    course = [[0.0, 0.0], [40.0, 0.0], [44.0, math.pi / 2]]  # a 90° turn at walking pace
    return synthesize_walk(course, 60.0, np.random.default_rng(1), gait=gait, t0_ms=T0)


def _assert_tiles(sel: InertialSelection) -> None:
    spans = [(int(s), int(e), "kept") for s, e in sel.kept_spans_ms]
    spans += [(r.start_ms, r.end_ms, "rejected") for r in sel.rejected]
    spans.sort()
    for (_, e0, k0), (s1, _, k1) in itertools.pairwise(spans):
        assert e0 == s1  # contiguous, no overlap
        assert k0 != k1  # maximal runs alternate
    assert all(s < e for s, e, _ in spans)


# ---------------------------------------------------------------- thresholds by hand


@pytest.mark.parametrize(("factor", "usable"), [(0.99, True), (1.01, False)])
def test_gyro_variance_just_below_and_above(factor: float, usable: bool) -> None:
    gain = _dirichlet(F_HZ, PARAMS.pdr.half_window, T_S)
    var = factor * PARAMS.max_gyro_var_rad2s2
    amplitude = math.sqrt(2 * var) / gain
    sel = select_inertial(_still(30.0), _gyro_sine(amplitude), PARAMS)
    inner = slice(1, -1)  # the first and last windows see the filter's edge padding
    np.testing.assert_allclose(sel.gyro_var_rad2s2[inner], var, rtol=1e-9)
    assert np.all(sel.usable[inner] == usable)
    np.testing.assert_allclose(sel.accel_var_m2s4, 0.0, atol=1e-20)
    if not usable:
        (span,) = sel.rejected
        assert span.criteria == ("gyro_variance",)
        assert span.reasons[0].startswith("angular-velocity variance 0.253 rad²/s² (x) >= 0.25")


@pytest.mark.parametrize(("factor", "usable"), [(0.99, True), (1.01, False)])
def test_accel_variance_just_below_and_above(factor: float, usable: bool) -> None:
    pdr = PARAMS.pdr
    gain = _dirichlet(F_HZ, pdr.half_window, T_S) * _high_pass_gain(F_HZ, pdr.vertical_tau_s, T_S)
    var = factor * PARAMS.max_accel_var_m2s4
    amplitude = math.sqrt(2 * var) / gain
    accel = _still(40.0)
    accel[:, 1] = amplitude * np.sin(2 * np.pi * F_HZ * (accel[:, 0] - T0) / 1000)
    sel = select_inertial(accel, _gyro_sine(0.0, 40.0), PARAMS)
    # after 10 s the gravity low-pass (τ = 1 s) has forgotten its start (e^-10)
    steady = (sel.window_start_ms >= T0 + 10_000) & (sel.window_end_ms < sel.window_end_ms[-1])
    assert np.count_nonzero(steady) >= 15
    np.testing.assert_allclose(sel.accel_var_m2s4[steady], var, rtol=1e-4)
    assert np.all(sel.usable[steady] == usable)
    assert np.all(sel.gyro_var_rad2s2 == 0.0)
    if not usable:
        assert all(r.criteria == ("accel_variance",) for r in sel.rejected)
        (text,) = sel.rejected[-1].reasons
        assert text.startswith("acceleration variance 7.")
        assert text.endswith(" m²/s⁴ (x) >= 7 m²/s⁴")


def test_step_change_threshold_is_strict() -> None:
    trace = _walk()
    sel = select_inertial(trace.accel, trace.gyro)
    worst = float(np.nanmax(sel.step_change_ms2))
    assert 0 < worst < 0.5  # a steady hand-held walk: peaks and valleys repeat
    at = select_inertial(trace.accel, trace.gyro, SelectionParams(max_step_change_ms2=worst))
    above = SelectionParams(max_step_change_ms2=float(np.nextafter(worst, math.inf)))
    assert np.all(select_inertial(trace.accel, trace.gyro, above).usable)
    failed = ~at.usable
    assert np.all(at.step_change_ms2[failed] == worst)
    assert {c for r in at.rejected for c in r.criteria} == {"step_extremes"}


def test_uneven_steps_are_rejected_for_their_extremes() -> None:
    # vertical bounce alternating 1.0 and 6.0 m/s² per 0.6 s step, from 20 s to 30 s
    accel = _still(50.0)
    t_s = (accel[:, 0] - T0) / 1000
    step = np.floor(t_s / 0.6).astype(int)
    amplitude = np.where(step % 2 == 0, 1.0, 6.0)
    uneven = (t_s >= 20) & (t_s < 30)
    accel[:, 3] += np.where(uneven, amplitude, 1.0) * np.sin(2 * np.pi * t_s / 0.6)
    sel = select_inertial(accel, _gyro_sine(0.0, 50.0))
    (span,) = sel.rejected
    assert span.criteria == ("step_extremes",)
    assert span.reasons[0].startswith("step peak/valley change ")
    assert span.values[0] >= 3.0
    assert np.all(sel.accel_var_m2s4 < PARAMS.max_accel_var_m2s4)
    assert T0 + 17_400 <= span.start_ms <= T0 + 20_600
    assert T0 + 29_400 <= span.end_ms <= T0 + 32_600


# ---------------------------------------------------------------- walks


def test_steady_walk_with_a_turn_is_all_usable() -> None:
    trace = _walk()
    sel = select_inertial(trace.accel, trace.gyro)
    assert sel.usable.all()
    assert sel.rejected == ()
    assert sel.kept_spans_ms.tolist() == [[T0, T0 + 60_000]]
    assert sel.window_start_ms[0] == T0
    assert np.all(np.diff(sel.window_start_ms)[:-1] == 1300)  # 50 % overlap of 2.6 s
    assert np.all(sel.window_end_ms - sel.window_start_ms == 2600)
    assert sel.window_end_ms[-1] == T0 + 60_000


def test_turbulent_part_of_a_walk_is_rejected_with_the_reason() -> None:
    trace = _walk()
    accel = trace.accel.copy()
    t_s = (accel[:, 0] - T0) / 1000
    shake = (t_s >= 20) & (t_s < 30)
    accel[shake, 1] += 5 * np.sin(2 * np.pi * 1.3 * t_s[shake])
    accel[shake, 2] += 4 * np.cos(2 * np.pi * 1.3 * t_s[shake])
    sel = select_inertial(accel, trace.gyro)

    (span,) = sel.rejected
    # the windows that hold more than a little of the shaking are out, no others
    assert T0 + 17_400 <= span.start_ms <= T0 + 20_500
    assert T0 + 29_500 <= span.end_ms <= T0 + 32_600
    assert span.criteria == ("accel_variance",)
    assert span.values[0] > 7.0
    assert span.reasons[0].startswith("acceleration variance ")
    assert span.reasons[0].endswith(" >= 7 m²/s⁴")
    assert sel.kept_spans_ms.tolist() == [[T0, span.start_ms], [span.end_ms, T0 + 60_000]]
    assert sel.kept_ms + sel.rejected_ms == 60_000
    _assert_tiles(sel)


def test_sensor_gap_is_rejected() -> None:
    trace = _walk()
    t = trace.gyro[:, 0]
    gyro = trace.gyro[(t < T0 + 30_000) | (t >= T0 + 32_000)]
    sel = select_inertial(trace.accel, gyro)
    (span,) = sel.rejected
    assert span.criteria == ("gyro_gap",)
    assert span.reasons == ("gyroscope gap 2.02 s > 0.5 s",)
    assert span.start_ms < T0 + 30_000
    assert span.end_ms > T0 + 32_000


def test_sensor_missing_at_the_end_is_rejected() -> None:
    trace = _walk()
    gyro = trace.gyro[trace.gyro[:, 0] < T0 + 50_000]
    sel = select_inertial(trace.accel, gyro)
    assert sel.rejected[-1].reasons == ("no gyroscope data",)
    assert sel.rejected[-1].end_ms == T0 + 60_000


def test_short_trace_is_rejected_whole() -> None:
    sel = select_inertial(_still(2.0), _gyro_sine(0.0, 2.0))
    assert sel.usable.size == 0
    assert sel.kept_spans_ms.shape == (0, 2)
    (span,) = sel.rejected
    assert span.criteria == ("too_short",)
    assert span.reasons == ("trace of 1.99 s is shorter than one 2.6 s window",)


@settings(max_examples=15, deadline=None)
@given(
    start_s=st.floats(0.0, 50.0),
    length_s=st.floats(0.5, 15.0),
    amplitude=st.floats(0.0, 8.0),
)
def test_kept_and_rejected_spans_tile_the_trace(
    start_s: float, length_s: float, amplitude: float
) -> None:
    trace = _walk()
    accel = trace.accel.copy()
    t_s = (accel[:, 0] - T0) / 1000
    shake = (t_s >= start_s) & (t_s < start_s + length_s)
    accel[shake, 1] += amplitude * np.sin(2 * np.pi * 1.3 * t_s[shake])
    sel = select_inertial(accel, trace.gyro)
    _assert_tiles(sel)
    assert sel.kept_ms + sel.rejected_ms == 60_000
    assert all(len(r.criteria) == len(r.values) == len(r.reasons) >= 1 for r in sel.rejected)
    # a kept instant lies in no failing window
    bad = ~sel.usable
    for s, e in sel.kept_spans_ms:
        assert not np.any(bad & (sel.window_start_ms < e) & (sel.window_end_ms > s))


def test_bad_input_names_the_argument() -> None:
    still = _still(10.0)
    with pytest.raises(ValueError, match="accel must have shape"):
        select_inertial(still[:, :3], still)
    backwards = still[::-1]
    with pytest.raises(ValueError, match="gyro times must be strictly increasing"):
        select_inertial(still, backwards)
    nan = still.copy()
    nan[3, 2] = np.nan
    with pytest.raises(ValueError, match="gyro must be finite"):
        select_inertial(still, nan)
    with pytest.raises(ValueError, match="hop_samples"):
        SelectionParams(hop_samples=0)
    with pytest.raises(ValueError, match="max_gyro_var_rad2s2"):
        SelectionParams(max_gyro_var_rad2s2=-1.0)
    with pytest.raises(ValueError, match="window_samples"):
        SelectionParams(window_samples=1, pdr=PdrParams())
