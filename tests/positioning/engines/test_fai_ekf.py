"""``fai_ekf``: the step EKF whose WiFi/BLE noise is the scan's predicted error."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from server.positioning.engines import fai_ekf, step_ekf
from server.positioning.events import radio_key
from server.positioning.fai import FaiParams
from server.positioning.fingerprint import RadioMap
from server.positioning.fix_error import EDGES, FixErrorModel
from server.positioning.mapping.fai_maps import build_fai_maps
from tests.positioning.engines.test_contract import batches
from tests.positioning.engines.test_pf_magnetic import rssi, site_maps

SIGMA_M = 5.0


def test_a_constant_fai_is_the_plain_step_ekf() -> None:
    # every WiFi fix worth SIGMA_M on the map: step_ekf's learned variance is constant
    model = FixErrorModel(sigma_m={"wifi": (SIGMA_M,) * len(EDGES)})
    maps = replace(site_maps(), fix_error=model)
    plain = step_ekf.StepEkfParams()
    ct = fai_ekf.FaiEkfParams(fai=FaiParams(strategy="ct", ct_m=SIGMA_M))
    rng = np.random.default_rng(0)
    a_state, b_state = step_ekf.initial_state(plain), fai_ekf.initial_state(ct)
    a_fixes, b_fixes = [], []
    for batch in batches():
        a_state, a = step_ekf.run(a_state, batch, maps, plain, rng)
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
