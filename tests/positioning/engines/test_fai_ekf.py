"""``fai_ekf``: the step EKF whose WiFi/BLE noise is the scan's predicted error."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from server.positioning.engines import fai_ekf, step_ekf
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.magnetic.field_grid import MagneticMap
from server.positioning.mapping.fai_maps import build_fai_maps
from server.positioning.mapping.magnetic_gridding import grid_from_samples
from server.positioning.model.events import (
    Event,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
    radio_key,
)
from server.positioning.radio.accuracy_indicators import FaiParams
from server.positioning.radio.fingerprints import RadioMap
from server.positioning.radio.fix_error import EDGES, FixErrorModel
from tests.support.corridor_site import LENGTH_M, T0, WIDTH_M, batches, rssi, site_maps

SIGMA_M = 5.0


def test_a_constant_fai_is_the_plain_step_ekf() -> None:
    # every WiFi fix worth SIGMA_M on the map: step_ekf's learned variance is constant
    model = FixErrorModel(sigma_m={"wifi": (SIGMA_M,) * len(EDGES)})
    maps = replace(site_maps(), fix_error=model)
    plain = step_ekf.StepEkfParams()
    ct = fai_ekf.FaiEkfParams(fai=FaiParams(strategy="ct", ct_m=SIGMA_M, mag_steps=0))
    rng = np.random.default_rng(0)
    a_state, b_state = step_ekf.initial_state(plain), fai_ekf.initial_state(ct)
    a_fixes, b_fixes = [], []
    for batch in batches():
        a_state, a = step_ekf.SPEC.run(a_state, batch, maps, plain, rng)
        b_state, b = fai_ekf.SPEC.run(b_state, batch, maps, ct, rng)
        a_fixes += a
        b_fixes += b
    assert a_fixes
    assert [(f.t_ms, f.x_m, f.y_m, f.cov) for f in a_fixes] == [
        (f.t_ms, f.x_m, f.y_m, f.cov) for f in b_fixes
    ]
    np.testing.assert_array_equal(a_state.P, b_state.P)
    assert all(f.diagnostics.get("fai_eta_m") == SIGMA_M for f in b_fixes if f.source == "wifi")


def wide_radio_map() -> RadioMap:
    """The toy corridor's access points surveyed over a 60 m x 15 m area (a strip of
    reference points 2 m wide cannot place an emitter across it)."""
    rp = np.array([(x, y) for x in range(0, 61, 2) for y in np.arange(-6.0, 9.1, 1.5)])
    mean = np.array([rssi(float(x), float(y)) for x, y in rp], dtype=np.float32)
    return RadioMap(
        rp_xy=rp.astype(np.float32),
        rp_floor=np.zeros(len(rp), dtype=np.int32),
        mean_dbm=mean,
        var_db2=np.ones_like(mean),
        count=np.ones(mean.shape, dtype=np.int32),
        emitters=tuple(radio_key("wifi", f"ap{i}") for i in range(mean.shape[1])),
    )


def test_the_indicators_set_each_scans_noise() -> None:
    radio = wide_radio_map()
    maps = replace(site_maps(), radio=radio, fai=build_fai_maps(radio, FaiParams()))
    assert maps.fai is not None
    assert np.isfinite(maps.fai.dsf_m).all()  # every point has alike ones on its floor
    # the noiseless log-distance model of the toy fits every access point
    np.testing.assert_allclose(maps.fai.exponent, 2.5, rtol=1e-3)
    fixes = {}
    for strategy in ("ss", "sd", "wd", "mc", "mcm"):
        params = fai_ekf.FaiEkfParams(fai=FaiParams(strategy=strategy))
        state = fai_ekf.initial_state(params)
        out = []
        for batch in batches():
            state, new = fai_ekf.SPEC.run(state, batch, maps, params, np.random.default_rng(1))
            out += [f for f in new if f.source == "wifi"]
        fixes[strategy] = out
    for f in fixes["mcm"]:
        d = f.diagnostics
        values = [d[k] for k in ("fai_ss", "fai_sd", "fai_wd") if k in d]
        assert d["fai_eta_m"] == max(values)
        assert d["fix_var_m2"] == max(d["fai_eta_m"] ** 2, 4.0)
    for f in fixes["wd"]:
        assert f.diagnostics["fai_eta_m"] == f.diagnostics["fai_wd"]
    assert all(math.isfinite(f.x_m) for fs in fixes.values() for f in fs)


def chirp_ut(x: np.ndarray) -> np.ndarray:
    """A field whose shape along the corridor differs everywhere (a gradient profile,
    blind to the level, finds no twin of a stretch elsewhere)."""
    out: np.ndarray = 45.0 + 8.0 * np.sin(x**2 / 60.0) + 0.3 * x
    return out


def chirp_maps() -> SiteMaps:
    maps = site_maps()
    gx, gy = np.meshgrid(np.arange(0.0, LENGTH_M, 0.25), np.arange(0.0, WIDTH_M, 0.25))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid_from_samples(xy, chirp_ut(xy[:, 0]), extent=(0.0, 0.0, LENGTH_M, WIDTH_M))
    return replace(maps, magnetic=MagneticMap((grid,), "chirp"))


def east_walk(wifi_bias_m: float) -> list[Event]:
    """One WiFi scan heard ``wifi_bias_m`` east of the walker at x = 10 m, then 25 steps
    of 0.7 m east along the corridor with the field measured halfway through each."""
    events: list[Event] = []
    reading = rssi(10.0 + wifi_bias_m, 1.5)
    aps = [RadioReading(f"ap{i}", float(v)) for i, v in enumerate(reading)]
    events.append(WifiEvent(T0, tuple(aps)))
    for k in range(1, 26):
        x = 10.0 + 0.7 * (k - 0.5)
        field = float(chirp_ut(np.array([x]))[0])
        events.append(MagEvent(T0 + 500 * k - 100, magnitude_ut=field))
        events.append(StepEvent(T0 + 500 * k, 0.7, math.pi / 2))
    return events


def test_magnetic_profiles_pull_a_wrong_wifi_start_back() -> None:
    maps = chirp_maps()
    final = {}
    for steps in (0, 10):
        params = fai_ekf.FaiEkfParams(
            fai=FaiParams(strategy="ct", strategy_mag="ct", mag_steps=steps)
        )
        _, fixes = fai_ekf.SPEC.run(
            fai_ekf.initial_state(params), east_walk(6.0), maps, params, np.random.default_rng(0)
        )
        final[steps] = abs(fixes[-1].x_m - (10.0 + 0.7 * 25))
        mag = [f for f in fixes if f.source == "mag"]
        if steps == 0:
            assert not mag
            continue
        # a profile every ten steps after the first fix; each within the circle of
        # 3 x 6 m (CT) around the WiFi fix carried along
        assert len(mag) == 2
        for f in mag:
            assert f.diagnostics["fai_eta_m"] == 5.0  # the magnetic CT
            assert f.diagnostics["mag_candidates"] > 0
    assert final[0] > 4.0  # dead reckoning keeps the WiFi start's error
    assert final[10] < 0.5 * final[0]


def test_the_magnetic_profile_survives_the_state_round_trip() -> None:
    params = fai_ekf.FaiEkfParams()
    state, _ = fai_ekf.SPEC.run(
        fai_ekf.initial_state(params),
        east_walk(0.0)[:12],
        site_maps(),
        params,
        np.random.default_rng(0),
    )
    assert isinstance(state, fai_ekf.FaiEkfState)
    assert state.profile_ut.size == 5
    back = fai_ekf.SPEC.decode(fai_ekf.SPEC.encode(state))
    assert isinstance(back, fai_ekf.FaiEkfState)
    np.testing.assert_array_equal(back.profile_xy, state.profile_xy)
    assert back.radio_eta_m == state.radio_eta_m
