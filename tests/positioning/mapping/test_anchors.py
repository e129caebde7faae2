"""Outer anchors (``papers/003_*`` IV-B): GNSS fixes in the building frame, BLE peaks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.mapping.anchors import (
    EARTH_RADIUS_M,
    ble_anchors,
    geo_to_local,
    gnss_anchors,
)
from server.positioning.model.geo import GeoReference
from server.positioning.plan.anchors import DEFAULT_RSSI_DBM

T0 = 1_700_000_000_000
M_PER_MILLIDEG = EARTH_RADIUS_M * math.pi / 180 * 0.001  # 111.195 m
REF = GeoReference(22.3043, 114.1795)  # PolyU, Hong Kong (papers/003_* test site)

# ---------------------------------------------------------------- GNSS


def test_a_thousandth_of_a_degree_north_is_111_m() -> None:
    assert pytest.approx(111.195, abs=1e-3) == M_PER_MILLIDEG
    xy = geo_to_local([REF.origin_lat_deg + 0.001], [REF.origin_lon_deg], REF)
    np.testing.assert_allclose(xy, [[0.0, M_PER_MILLIDEG]], atol=1e-9)


def test_east_shrinks_with_latitude() -> None:
    ref = GeoReference(60.0, 10.0)
    xy = geo_to_local([60.0], [10.001], ref)
    np.testing.assert_allclose(xy, [[M_PER_MILLIDEG / 2, 0.0]], atol=1e-9)


def test_rotation_turns_north_onto_the_building_axes() -> None:
    north = ([REF.origin_lat_deg + 0.001], [REF.origin_lon_deg])
    # y axis pointing east (bearing 90°): north is along -x
    east_up = GeoReference(REF.origin_lat_deg, REF.origin_lon_deg, math.pi / 2)
    np.testing.assert_allclose(geo_to_local(*north, east_up), [[-M_PER_MILLIDEG, 0.0]], atol=1e-9)
    # y axis at bearing 30°: a point 30° east of north lies on the y axis
    ref = GeoReference(REF.origin_lat_deg, REF.origin_lon_deg, math.radians(30))
    d_lat = 0.001 * math.cos(math.radians(30))
    d_lon = 0.001 * math.sin(math.radians(30)) / math.cos(math.radians(REF.origin_lat_deg))
    xy = geo_to_local([REF.origin_lat_deg + d_lat], [REF.origin_lon_deg + d_lon], ref)
    np.testing.assert_allclose(xy, [[0.0, M_PER_MILLIDEG]], atol=1e-9)
    # and north is 30° to the left of it
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(
        geo_to_local(*north, ref), [[-M_PER_MILLIDEG * s, M_PER_MILLIDEG * c]], atol=1e-9
    )


def test_longitude_wraps_at_the_antimeridian() -> None:
    ref = GeoReference(0.0, 179.9995)
    np.testing.assert_allclose(
        geo_to_local([0.0], [-179.9995], ref), [[M_PER_MILLIDEG, 0.0]], atol=1e-6
    )


@given(
    rotation=st.floats(-10.0, 10.0),
    d_lat=st.floats(-0.005, 0.005),
    d_lon=st.floats(-0.005, 0.005),
)
def test_rotation_keeps_distances(rotation: float, d_lat: float, d_lon: float) -> None:
    lat, lon = [REF.origin_lat_deg + d_lat], [REF.origin_lon_deg + d_lon]
    turned = geo_to_local(lat, lon, GeoReference(REF.origin_lat_deg, REF.origin_lon_deg, rotation))
    plain = geo_to_local(lat, lon, REF)
    assert np.linalg.norm(turned) == pytest.approx(np.linalg.norm(plain), rel=1e-12, abs=1e-9)


def test_gnss_fixes_qualify_below_the_paper_thresholds() -> None:
    lat, lon = REF.origin_lat_deg + 0.001, REF.origin_lon_deg
    fixes = [
        [T0 + 0, lat, lon, 4.99, 19.9],  # qualifies
        [T0 + 1, lat, lon, 5.0, 1.0],  # accuracy not below 5 m
        [T0 + 2, lat, lon, 3.0, 20.0],  # HDOP not below 20
        [T0 + 3, lat, lon, np.nan, 1.0],  # accuracy not reported
        [T0 + 4, lat, lon, 3.0, np.nan],  # HDOP not reported
        [T0 + 5, lat, lon, 9.0, 30.0],  # both bad
        [T0 + 6, REF.origin_lat_deg, lon, 1.0, 1.0],  # qualifies, at the origin
    ]
    a = gnss_anchors(fixes, REF)
    assert a.t_ms.tolist() == [T0, T0 + 6]
    assert a.source.tolist() == [0, 6]
    np.testing.assert_allclose(a.xy_m, [[0.0, M_PER_MILLIDEG], [0.0, 0.0]], atol=1e-9)
    assert (a.n_fixes, a.n_bad_accuracy, a.n_bad_hdop) == (7, 3, 3)
    loose = gnss_anchors(fixes, REF, max_accuracy_m=10.0, max_hdop=50.0)
    assert loose.source.tolist() == [0, 1, 2, 5, 6]


def test_gnss_bad_input_names_the_argument() -> None:
    assert gnss_anchors(np.empty((0, 5)), REF).t_ms.size == 0
    with pytest.raises(ValueError, match="fixes must have shape"):
        gnss_anchors([[T0, 22.0, 114.0, 3.0]], REF)
    with pytest.raises(ValueError, match="lat_deg"):
        gnss_anchors([[T0, 95.0, 114.0, 3.0, 1.0]], REF)
    with pytest.raises(ValueError, match="origin_lat_deg"):
        GeoReference(90.0, 0.0)
    with pytest.raises(ValueError, match="rotation_rad"):
        GeoReference(0.0, 0.0, math.inf)


# ---------------------------------------------------------------- BLE

LIFT = ("lift-n", (12.0, 40.0), 6)
DOOR = ("door-s", (80.0, -5.0), 6)
FAR = ("far", (300.0, 300.0), 6)


def _pass_by(
    rng: np.random.Generator, beacon: str, at_s: list[float], duration_s: float = 120.0
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """BLE scans every 300 ms (papers/003_* VI-A) of a walker passing a beacon at 1.2 m/s
    at the times ``at_s``, 1 m abeam: ``r = -45 - 25 log10 d`` + N(0, 4²) dBm, heard
    down to -95 dBm."""
    t_s = np.arange(0.0, duration_s, 0.3)
    along = np.min(np.abs(t_s[:, None] - np.asarray(at_s)[None, :]), axis=1) * 1.2
    d = np.hypot(along, 1.0)
    rssi = -45.0 - 25.0 * np.log10(d) + rng.normal(0.0, 4.0, t_s.size)
    heard = rssi >= -95.0
    return T0 + np.round(t_s[heard] * 1000), [beacon] * int(heard.sum()), rssi[heard]


def test_peak_of_a_noisy_pass_by() -> None:
    rng = np.random.default_rng(7)
    t, ids, r = _pass_by(rng, "lift-n", [30.0, 90.0])
    a = ble_anchors(t, ids, r, [DOOR, LIFT])
    assert a.t_ms.size == 2
    np.testing.assert_allclose(a.t_ms, [T0 + 30_000, T0 + 90_000], atol=1000)
    np.testing.assert_allclose(a.xy_m, [[12.0, 40.0], [12.0, 40.0]])
    assert a.floor.tolist() == [6, 6]
    assert a.beacon.tolist() == [1, 1]
    assert np.all(a.peak_dbm >= DEFAULT_RSSI_DBM)
    assert a.n_unknown == 0


def test_several_beacons_and_unknown_ones() -> None:
    rng = np.random.default_rng(11)
    t1, i1, r1 = _pass_by(rng, "lift-n", [20.0])
    t2, i2, r2 = _pass_by(rng, "door-s", [70.0])
    t3, i3, r3 = _pass_by(rng, "stranger", [50.0])
    t4, i4, r4 = _pass_by(rng, "far", [40.0])
    t = np.concatenate([t1, t2, t3, t4])
    r = np.concatenate([r1, r2, r3, r4 - 40.0])  # "far" never gets near the threshold
    order = np.argsort(t, kind="stable")  # scans arrive interleaved
    ids = [(i1 + i2 + i3 + i4)[k] for k in order]
    a = ble_anchors(t[order], ids, r[order], [LIFT, DOOR, FAR])
    assert a.beacon.tolist() == [0, 1]
    np.testing.assert_allclose(a.t_ms, [T0 + 20_000, T0 + 70_000], atol=1000)
    np.testing.assert_allclose(a.xy_m, [[12.0, 40.0], [80.0, -5.0]])
    assert a.n_unknown == len(i3)


def test_a_trace_starting_in_the_lift_has_its_anchor_at_the_start() -> None:
    rng = np.random.default_rng(3)
    t, ids, r = _pass_by(rng, "lift-n", [0.0], duration_s=60.0)
    a = ble_anchors(t, ids, r, [LIFT])
    assert a.t_ms.size == 1
    assert a.t_ms[0] - T0 <= 1000


def test_threshold_is_inclusive() -> None:
    t = T0 + np.arange(0, 30_000, 300)
    ids = ["lift-n"] * t.size
    r = np.full(t.size, -80.0)
    r[50] = DEFAULT_RSSI_DBM  # just at the threshold: an anchor
    assert ble_anchors(t, ids, r, [LIFT], smooth_ms=0.0).t_ms.tolist() == [t[50]]
    r[50] = DEFAULT_RSSI_DBM - 0.01  # just below: none
    assert ble_anchors(t, ids, r, [LIFT], smooth_ms=0.0).t_ms.size == 0
    # the average filter: one strong scan among weak ones is not a pass-by
    r[50] = -50.0
    assert ble_anchors(t, ids, r, [LIFT]).t_ms.size == 0


def test_close_peaks_count_once() -> None:
    t = T0 + np.arange(0, 30_000, 300)
    r = np.full(t.size, -90.0)
    r[[40, 50, 80]] = [-60.0, -55.0, -58.0]  # 3 s apart, then 9 s later
    a = ble_anchors(t, ["lift-n"] * t.size, r, [LIFT], smooth_ms=0.0, peak_window_ms=5000.0)
    assert a.t_ms.tolist() == [t[50], t[80]]
    np.testing.assert_allclose(a.peak_dbm, [-55.0, -58.0])


def test_ble_bad_input_names_the_argument() -> None:
    with pytest.raises(ValueError, match="beacon_id must have length 2"):
        ble_anchors([T0, T0 + 300], ["lift-n"], [-60.0, -61.0], [LIFT])
    with pytest.raises(ValueError, match="rssi_dbm must have shape"):
        ble_anchors([T0], ["lift-n"], [-60.0, -61.0], [LIFT])
    with pytest.raises(ValueError, match="beacons lists 'lift-n' twice"):
        ble_anchors([T0], ["lift-n"], [-60.0], [LIFT, LIFT])
    with pytest.raises(ValueError, match="beacons: position of 'x'"):
        ble_anchors([T0], ["x"], [-60.0], [("x", (1.0, math.nan), 0)])
    empty = ble_anchors([], [], [], [LIFT])
    assert empty.t_ms.size == 0
    assert empty.xy_m.shape == (0, 2)
