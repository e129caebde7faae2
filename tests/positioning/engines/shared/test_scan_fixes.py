"""The shared radio side: a fix's variance grows with its distance to the nearest
reference scan."""

from __future__ import annotations

import numpy as np
import pytest

from server.positioning.engines.shared import scan_fixes
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.engines.step_ekf import StepEkfParams
from server.positioning.model.events import RadioReading, WifiEvent, radio_key
from server.positioning.radio import scan_matching as sm
from server.positioning.radio.fingerprints import RadioMap

AP_X = np.linspace(0.0, 60.0, 10)


def levels(x_m: float) -> np.ndarray:
    out: np.ndarray = -40.0 - 20.0 * np.log10(np.maximum(np.abs(AP_X - x_m), 1.0))
    return out


def corridor() -> SiteMaps:
    xs = np.arange(0.0, 61.0, 2.0)
    names = [f"02:00:00:00:00:{i:02x}" for i in range(AP_X.size)]
    readings = [
        [(radio_key("wifi", n), float(v)) for n, v in zip(names, levels(x), strict=True)]
        for x in xs
    ]
    xy = np.column_stack([xs, np.zeros_like(xs)])
    scans = sm.build_scan_map(xy, np.zeros(xs.size, dtype=np.int64), readings, min_readings=1)
    radio = RadioMap(
        rp_xy=xy.astype(np.float32),
        rp_floor=np.zeros(xs.size, dtype=np.int32),
        mean_dbm=np.array([levels(x) for x in xs], dtype=np.float32),
        var_db2=np.ones((xs.size, AP_X.size), dtype=np.float32),
        count=np.ones((xs.size, AP_X.size), dtype=np.int32),
        emitters=tuple(radio_key("wifi", n) for n in names),
    )
    return SiteMaps((FloorRef("b", "f", 0),), radio, version="corridor", scans=scans)


def scan(x_m: float, offset_db: float) -> WifiEvent:
    values = levels(x_m) + offset_db
    names = [f"02:00:00:00:00:{i:02x}" for i in range(AP_X.size)]
    return WifiEvent(
        0, tuple(RadioReading(n, float(v)) for n, v in zip(names, values, strict=True))
    )


@pytest.mark.parametrize("power", [0.0, 1.0, 2.0])
def test_the_variance_grows_with_the_distance_to_the_nearest_reference(power: float) -> None:
    maps = corridor()
    params = StepEkfParams(fix_var_match_power=power, min_fix_var_m2=0.01)
    learned = maps.fix_error.variance("wifi", AP_X.size)
    beside = scan_fixes.match(maps, scan(20.0, 0.0), params)
    off = scan_fixes.match(maps, scan(20.0, -15.0), params)  # every reading 15 dB weaker
    assert beside is not None
    assert off is not None
    nearest = float(off.whole.distances_db.min())
    assert nearest > 10.0  # no reference is as weak everywhere
    assert off.var_m2 == pytest.approx(learned * (nearest / params.fix_var_match_db) ** power)
    if power > 0:
        assert beside.var_m2 < off.var_m2
    else:
        assert beside.var_m2 == off.var_m2 == pytest.approx(learned)
