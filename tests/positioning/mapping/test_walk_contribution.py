"""What a recorded walk adds to the maps, from a recorded ILC walk and from walks of our own
events: its anchors (waypoints, passes by beacons and anchor APs, satellite fixes), its
samples placed by the steps found or sent, those left out and why, rejected naming the
main cause."""

from __future__ import annotations

import lzma
import math
from collections.abc import Sequence
from functools import cache

import numpy as np
import pytest

from server.positioning.mapping.anchors import EARTH_RADIUS_M
from server.positioning.mapping.labelled import interpolate_track
from server.positioning.mapping.survey_points import SurveyPointData
from server.positioning.mapping.walk_contribution import (
    AnchorContext,
    Beacon,
    walk_contribution,
)
from server.positioning.model.events import (
    BleEvent,
    Event,
    GnssEvent,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)
from server.positioning.model.geo import GeoReference
from server.positioning.model.walk import Walk, trace_from_events
from server.positioning.plan.geojson_plan import PLAN_MARGIN_M
from server.storage.ilc_trace_format import parse_trace_text
from tests.support.datasets import dataset_dir

# ---- a recorded ILC walk (site2, F4: level 3) -------------------------------------------

LEVEL = 3


@cache
def _ilc_walk() -> Walk:
    path = sorted((dataset_dir("ilc20-sample") / "site2" / "F4" / "path_data_files").iterdir())[0]
    return parse_trace_text(lzma.decompress(path.read_bytes()).decode(), "u")


def test_a_walk_is_placed_by_its_steps_and_inertial_selection_thins_it() -> None:
    everything = walk_contribution(_ilc_walk(), LEVEL, AnchorContext())
    assert everything.rejected is None
    assert everything.floor_level == LEVEL
    assert everything.report["placement"] == "steps between anchors"
    assert 0.5 < everything.report["step_scale"] < 1.6
    steady = walk_contribution(_ilc_walk(), LEVEL, AnchorContext(), inertial_selection=True)
    assert steady.rejected is None
    kept = steady.report["inertial_selection_kept"]
    assert 0.0 < kept < 1.0
    # fewer samples, each of them one the full run placed at the same spot
    assert steady.report["scans"] < everything.report["scans"]
    assert steady.report["magnetic_samples"] < everything.report["magnetic_samples"]
    by_time = {p.t_ms: (p.x_m, p.y_m) for p in everything.points}
    assert all(by_time[p.t_ms] == (p.x_m, p.y_m) for p in steady.points)
    assert any(r.startswith("inertial selection") for r in steady.report["not_used"])


def test_a_pass_by_an_anchor_ap_becomes_one_more_anchor() -> None:
    """IV-E3: where the walk's RSS of an anchor AP peaks at or above its P0, the walker was
    at the AP; that pass joins the waypoints as an anchor."""
    trace = _ilc_walk()
    # the AP heard loudest away from the waypoints, placed where the walk was then
    far = [e for e in trace.wifi if abs(trace.waypoint_t_ms - e.t_ms).min() > 2000]
    t, bssid, rssi = max(
        ((e.t_ms, r.emitter, r.rssi_dbm) for e in far for r in e.readings),
        key=lambda x: x[2],
    )
    xy, ok = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, [t])
    assert ok[0]
    ap = Beacon(bssid.lower(), (float(xy[0, 0]), float(xy[0, 1])), LEVEL, "wifi", rssi - 5.0)
    found = walk_contribution(trace, LEVEL, AnchorContext([ap]))
    assert found.rejected is None
    assert found.report["anchor_passes"] >= 1
    assert found.report["anchors"] == trace.waypoint_t_ms.size + found.report["anchor_passes"]
    # on another floor, or never reached, it adds nothing
    for level, threshold in ((2, rssi - 5.0), (LEVEL, rssi + 10.0)):
        other = AnchorContext([Beacon(ap.emitter, ap.xy_m, level, "wifi", threshold)])
        assert walk_contribution(trace, LEVEL, other).report["anchor_passes"] == 0


def test_samples_placed_far_outside_the_floor_plan_are_not_used() -> None:
    everything = walk_contribution(_ilc_walk(), LEVEL, AnchorContext())
    xs = sorted(p.x_m for p in everything.points)
    cut = xs[len(xs) // 2] - PLAN_MARGIN_M  # the plan ends where half the scans are
    half = walk_contribution(
        _ilc_walk(), LEVEL, AnchorContext(extents={LEVEL: (-1e4, -1e4, cut, 1e4)})
    )
    assert 0 < half.report["scans"] < everything.report["scans"]
    assert all(p.x_m <= cut + PLAN_MARGIN_M for p in half.points)
    assert any("outside the floor plan" in r for r in half.report["not_used"])
    # another floor's extent does not apply
    other = walk_contribution(_ilc_walk(), LEVEL, AnchorContext(extents={2: (0.0, 0.0, 1.0, 1.0)}))
    assert other.report["scans"] == everything.report["scans"]


# ---- walks made of our own events -------------------------------------------------------

T0 = 1_700_000_000_000
STEP_M, STEP_S = 0.7, 0.5
START, END = (2.0, 2.0), (2.0 + 20 * STEP_M, 2.0 + 20 * STEP_M)
AP = "02:00:00:00:00:01"


def _walk(events: Sequence[Event], anchors: Sequence[tuple[int, float, float]]) -> Walk:
    return trace_from_events(events, anchors)


def _steps() -> list[StepEvent]:
    """20 phone steps east from START, then 20 north to END, one every STEP_S."""
    headings = [math.pi / 2] * 20 + [0.0] * 20
    return [StepEvent(T0 + int(1000 * STEP_S * (k + 1)), STEP_M, h) for k, h in enumerate(headings)]


T_END = _steps()[-1].t_ms


def _l_walk() -> tuple[list[Event], list[tuple[int, float, float]]]:
    """20 phone steps east from (2, 2), then 20 north, a WiFi scan after every step; the
    anchors are the two ends only (where the walker was: ``where``)."""
    steps = _steps()
    scans = [WifiEvent(s.t_ms + 100, (RadioReading(AP, -60.0),)) for s in steps[:-1]]
    anchors = [(T0, *START), (T_END, *END)]
    return [*steps, *scans], anchors


def where(t_ms: float) -> tuple[float, float]:
    """Where the walker of ``_l_walk`` was at ``t_ms``."""
    walked = STEP_M * min((t_ms - T0) / (1000 * STEP_S), 40.0)
    east = min(walked, 20 * STEP_M)
    return 2.0 + east, 2.0 + walked - east


def assert_along_the_l(points: Sequence[SurveyPointData], tolerance_m: float = 0.75) -> None:
    for p in points:
        assert p.t_ms is not None
        assert_at(p.t_ms, (p.x_m, p.y_m), tolerance_m)


def assert_at(t_ms: float, xy: Sequence[float], tolerance_m: float = 0.75) -> None:
    """That ``xy`` is within ``tolerance_m`` of where the walker of ``_l_walk`` was."""
    x, y = where(t_ms)
    assert math.hypot(xy[0] - x, xy[1] - y) < tolerance_m, (t_ms, xy)


def test_the_phone_s_step_events_place_a_walk_without_raw_motion_samples() -> None:
    events, anchors = _l_walk()
    found = walk_contribution(_walk(events, anchors), 0, AnchorContext())
    assert found.rejected is None, found.report
    assert found.report["placement"] == "steps between anchors"
    assert found.report["steps_from"] == "the phone's step events"
    assert found.report["steps"] == 40
    assert found.report["step_scale"] == pytest.approx(1.0, abs=1e-6)
    assert len(found.points) == 39
    # along the L, not on the straight line between its ends (at constant speed the
    # corner would be placed 5 m off)
    assert_along_the_l(found.points)
    # without the steps: constant speed, the corner cut
    scans_only = [e for e in events if not isinstance(e, StepEvent)]
    straight = walk_contribution(_walk(scans_only, anchors), 0, AnchorContext())
    assert straight.report["placement"] == "constant speed between anchors (no steps found)"
    corner = min(straight.points, key=lambda p: abs((p.t_ms or 0) - (T0 + 10_000)))
    assert math.hypot(corner.x_m - 16.0, corner.y_m - 2.0) > 4.0


def test_a_rejection_names_the_cause_that_cost_the_most_samples() -> None:
    # magnetometer samples every 0.5 s for 14 s; anchors 180 km apart from 1 s to 13 s
    events: list[Event] = [MagEvent(T0 + 500 * k, (20.0, 0.0, -40.0)) for k in range(28)]
    anchors = [(T0 + 1000, -90_000.0, 5.0), (T0 + 13_000, 90_000.0, 5.0)]
    found = walk_contribution(_walk(events, anchors), 0, AnchorContext())
    main = "25 samples between anchors farther apart than a walker goes at 3 m/s"
    minor = "3 samples before the first or after the last anchor"
    assert found.report["not_used"] == [main, minor]
    assert found.rejected == f"nothing could be placed; main cause: {main}; also: {minor}"
    # weak scans: the reason counts the scans lost, not their readings
    weak = [WifiEvent(T0 + 500 * k, (RadioReading("aa", -95.0),)) for k in range(2, 26)]
    near = [(T0 + 1000, 0.0, 5.0), (T0 + 13_000, 12.0, 5.0)]
    found = walk_contribution(_walk([*weak, events[0]], near), 0, AnchorContext())
    assert found.rejected is not None
    assert found.rejected.startswith(
        "nothing could be placed; main cause: 24 readings weaker than -90 dBm "
        "(24 scans heard nothing stronger); also: 1 samples before"
    ), found.rejected


def test_a_walk_with_nothing_to_place_is_rejected_so() -> None:
    found = walk_contribution(_walk(_steps(), [(T0, *START), (T_END, *END)]), 0, AnchorContext())
    assert found.rejected == (
        "nothing could be placed: the walk carries no scans and no magnetometer samples"
    )
    assert found.points == ()
    assert found.magnetic is None
    assert found.report["scans"] == 0
    assert found.report["not_used"] == []


FEWER_THAN_TWO = (
    "fewer than two anchors: no waypoints, and passes by fewer than two of the floor plan's beacons"
)


@pytest.mark.parametrize(("anchors", "source"), [([], "beacons"), ([(T0, 2.0, 2.0)], "waypoints")])
def test_a_walk_with_fewer_than_two_anchors_is_rejected(
    anchors: list[tuple[int, float, float]], source: str
) -> None:
    events, _ = _l_walk()
    found = walk_contribution(_walk(events, anchors), 0, AnchorContext())
    assert found.rejected == FEWER_THAN_TWO
    assert found.floor_level == 0
    assert found.points == ()
    assert found.report == {"anchors": len(anchors), "anchor_source": source, "anchor_passes": 0}


def _beacon_scan(t_ms: int, beacon: str, rssi_dbm: float = -50.0) -> BleEvent:
    return BleEvent(t_ms, (RadioReading(beacon, rssi_dbm),))


BEACONS = (Beacon("b1", START, 0), Beacon("b2", END, 0))


def test_passes_by_two_beacons_anchor_a_walk_without_waypoints() -> None:
    """IV-B: a beacon heard at its loudest (at or above -65 dBm by default) is where the
    walker passed it; two passes anchor the walk like its two ends' waypoints would."""
    events, _ = _l_walk()
    passes = [_beacon_scan(T0, "B1"), _beacon_scan(T_END, "b2")]  # ids compared lower-case
    found = walk_contribution(_walk([*events, *passes], []), 0, AnchorContext(BEACONS))
    assert found.rejected is None, found.report
    assert found.report["anchors"] == 2
    assert found.report["anchor_source"] == "beacons"
    assert found.report["anchor_passes"] == 2
    assert found.report["steps"] == 40
    assert found.report["step_scale"] == pytest.approx(1.0, abs=1e-6)
    wifi = [p for p in found.points if p.wifi]
    assert len(wifi) == 39
    assert_along_the_l(wifi)
    # the beacons' own scans are BLE points, at the beacons
    ble = sorted((p for p in found.points if p.ble), key=lambda p: p.t_ms or 0)
    assert [(p.t_ms, p.ble, p.wifi) for p in ble] == [
        (T0, [("B1", -50.0)], []),
        (T_END, [("b2", -50.0)], []),
    ]
    assert (ble[0].x_m, ble[0].y_m) == pytest.approx(START, abs=1e-6)
    assert (ble[1].x_m, ble[1].y_m) == pytest.approx(END, abs=1e-6)


@pytest.mark.parametrize(
    ("context", "passes"),
    [
        (AnchorContext(), 0),  # no beacons known
        (AnchorContext([Beacon("b1", START, 1), Beacon("b2", END, 1)]), 0),  # another floor
        (AnchorContext([Beacon(b.emitter, b.xy_m, 0, "wifi") for b in BEACONS]), 0),  # APs
        (AnchorContext([Beacon(b.emitter, b.xy_m, 0, threshold_dbm=-40.0) for b in BEACONS]), 0),
        (AnchorContext(BEACONS[:1]), 1),  # one pass alone is not enough
    ],
)
def test_beacons_that_do_not_anchor_the_walk(context: AnchorContext, passes: int) -> None:
    events, _ = _l_walk()
    beacons = [_beacon_scan(T0, "b1"), _beacon_scan(T_END, "b2")]
    found = walk_contribution(_walk([*events, *beacons], []), 0, context)
    assert found.rejected == FEWER_THAN_TWO
    assert found.report["anchor_passes"] == passes


def test_a_pass_within_a_second_of_a_waypoint_is_left_to_the_waypoint() -> None:
    events, anchors = _l_walk()
    beacons = [_beacon_scan(T0 + 900, "b1"), _beacon_scan(T0 + 10_000, "b2")]
    context = AnchorContext([Beacon("b1", (9.0, 9.0), 0), Beacon("b2", (12.0, 2.0), 0)])
    found = walk_contribution(_walk([*events, *beacons], anchors), 0, context)
    assert found.rejected is None
    # b1 900 ms after the first waypoint: dropped; b2 at the corner: one more anchor
    assert found.report["anchor_source"] == "waypoints"
    assert found.report["anchor_passes"] == 1
    assert found.report["anchors"] == 3


def _fix(t_ms: int, xy: tuple[float, float], accuracy_m: float = 3.0) -> GnssEvent:
    """A satellite fix at building coordinates ``xy`` of ``GEO`` (y north)."""
    lat = GEO.origin_lat_deg + math.degrees(xy[1] / EARTH_RADIUS_M)
    coslat = math.cos(math.radians(GEO.origin_lat_deg))
    lon = GEO.origin_lon_deg + math.degrees(xy[0] / (EARTH_RADIUS_M * coslat))
    return GnssEvent(t_ms, lat, lon, accuracy_m, hdop=1.0)


GEO = GeoReference(48.0, 11.0)


def test_good_satellite_fixes_anchor_a_walk() -> None:
    """IV-B: fixes with accuracy < 5 m and HDOP < 20 are anchors; a poor one is not."""
    events, _ = _l_walk()
    fixes = [_fix(T0, START), _fix(T0 + 10_000, (60.0, 0.0), accuracy_m=8.0), _fix(T_END, END)]
    found = walk_contribution(_walk([*events, *fixes], []), 0, AnchorContext(geo=GEO))
    assert found.rejected is None, found.report
    assert found.report["anchors"] == 2
    assert found.report["step_scale"] == pytest.approx(1.0, abs=1e-3)
    assert len(found.points) == 39
    assert_along_the_l(found.points)
    # without the building's geo-reference the fixes say nothing
    unplaced = walk_contribution(_walk([*events, *fixes], []), 0, AnchorContext())
    assert unplaced.rejected == FEWER_THAN_TWO


def test_weak_readings_are_left_out_of_the_scans_that_keep_stronger_ones() -> None:
    events, anchors = _l_walk()
    t = T0 + 5300  # between two of the walk's scans
    mixed: list[Event] = [
        WifiEvent(t, (RadioReading("aa", -70.0, 2000.0), RadioReading("bb", -91.0))),
        BleEvent(t, (RadioReading("cc", -90.0), RadioReading("dd", -95.5, 300.0))),
    ]
    found = walk_contribution(_walk([*events, *mixed], anchors), 0, AnchorContext())
    assert found.rejected is None
    assert found.report["scans"] == 39 + 2
    assert found.report["not_used"] == ["2 readings weaker than -90 dBm"]
    wifi, ble = (p for p in found.points if p.t_ms == t)
    assert (wifi.wifi, wifi.ble, wifi.wifi_age_ms, wifi.ble_age_ms) == (
        [("aa", -70.0)],
        [],
        [2000.0],
        (),
    )
    assert (ble.wifi, ble.ble, ble.wifi_age_ms, ble.ble_age_ms) == ([], [("cc", -90.0)], (), [None])
    assert all(p.floor_level == 0 and p.mag_ut is None for p in found.points)
    assert (ble.x_m, ble.y_m) == pytest.approx((wifi.x_m, wifi.y_m))
    assert_along_the_l([wifi, ble])


def test_magnetometer_samples_are_placed_along_the_walk() -> None:
    events, anchors = _l_walk()
    # a 50 µT field every step, and one before the walk's first anchor
    mag = [MagEvent(s.t_ms + 200, (30.0, 0.0, -40.0)) for s in _steps()[:-1]]
    early = MagEvent(T0 - 1000, (30.0, 0.0, -40.0))
    found = walk_contribution(_walk([*events, *mag, early], anchors), 0, AnchorContext())
    assert found.rejected is None
    assert found.magnetic is not None
    assert found.report["magnetic_samples"] == 39
    assert np.asarray(found.magnetic.magnitude).tolist() == [50.0] * 39
    for event, xy in zip(mag, np.asarray(found.magnetic.xy).tolist(), strict=True):
        assert_at(event.t_ms, xy)
    assert found.report["scans"] == 39
    assert found.report["not_used"] == ["1 samples before the first or after the last anchor"]


def test_a_walk_of_magnetometer_samples_only_is_a_contribution() -> None:
    _, anchors = _l_walk()
    mag = [MagEvent(s.t_ms + 200, (0.0, 30.0, -40.0)) for s in _steps()[:-1]]
    found = walk_contribution(_walk([*_steps(), *mag], anchors), 0, AnchorContext())
    assert found.rejected is None
    assert found.points == []
    assert found.magnetic is not None
    assert np.asarray(found.magnetic.xy).shape == (39, 2)


def test_an_uncalibrated_magnetometer_is_not_used() -> None:
    events, anchors = _l_walk()
    samples = [[T0 + 200 + 500 * k, 30.0, 0.0, -40.0] for k in range(39)]
    block = ImuEvent(T0, magnetic=np.array(samples), magnetic_calibrated=False)
    found = walk_contribution(_walk([*events, block], anchors), 0, AnchorContext())
    assert found.rejected is None
    assert found.magnetic is None
    assert "magnetic_samples" not in found.report
    assert found.report["not_used"] == ["magnetometer: uncalibrated only"]
    assert found.report["scans"] == 39
    # and with nothing else to place, that is the reason given
    only = walk_contribution(_walk([*_steps(), block], anchors), 0, AnchorContext())
    assert only.rejected == "nothing could be placed; main cause: magnetometer: uncalibrated only"
