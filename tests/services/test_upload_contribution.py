"""What one upload adds to the maps, from a recorded ILC walk and from walks of our own
events (no servers needed): placed by the steps found or sent, rejected naming the main
cause."""

from __future__ import annotations

import lzma
import math
from collections.abc import Sequence
from typing import Any

import pytest

from server.positioning.model.events import Event, MagEvent, RadioReading, StepEvent, WifiEvent
from server.services import traces
from server.services.upload_contribution import contribution
from server.storage.models import Upload
from tests.datasets.conftest import dataset_dir


def _upload(level: int = 3) -> Upload:
    path = sorted((dataset_dir("ilc20-sample") / "site2" / "F4" / "path_data_files").iterdir())[0]
    text = lzma.decompress(path.read_bytes())
    return Upload(id="u", site_id="s", content_type="text/plain", payload=text, floor_level=level)


def test_a_walk_is_placed_by_its_steps_and_inertial_selection_thins_it() -> None:
    everything = contribution(_upload())
    assert everything.rejected is None
    assert everything.report["placement"] == "steps between anchors"
    assert 0.5 < everything.report["step_scale"] < 1.6
    steady = contribution(_upload(), inertial_selection=True)
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
    from server.datasets.ilc_trace import parse_trace_text
    from server.positioning.mapping.labelled import interpolate_track
    from server.services.upload_anchors import AnchorContext, Beacon

    upload = _upload()
    trace = parse_trace_text(upload.payload.decode(), "u")
    # the AP heard loudest away from the waypoints, placed where the walk was then
    far = [e for e in trace.wifi if abs(trace.waypoint_t_ms - e.t_ms).min() > 2000]
    t, bssid, rssi = max(
        ((e.t_ms, r.emitter, r.rssi_dbm) for e in far for r in e.readings),
        key=lambda x: x[2],
    )
    xy, ok = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, [t])
    assert ok[0]
    ap = Beacon(bssid.lower(), (float(xy[0, 0]), float(xy[0, 1])), 3, "wifi", rssi - 5.0)
    found = contribution(upload, AnchorContext([ap]))
    assert found.rejected is None
    assert found.report["anchor_passes"] >= 1
    assert found.report["anchors"] == trace.waypoint_t_ms.size + found.report["anchor_passes"]
    # on another floor, or never reached, it adds nothing
    for level, threshold in ((2, rssi - 5.0), (3, rssi + 10.0)):
        other = AnchorContext([Beacon(ap.emitter, ap.xy_m, level, "wifi", threshold)])
        assert contribution(upload, other).report["anchor_passes"] == 0


def test_samples_placed_far_outside_the_floor_plan_are_not_used() -> None:
    from server.positioning.plan.geojson_plan import PLAN_MARGIN_M
    from server.services.upload_anchors import AnchorContext

    everything = contribution(_upload())
    xs = sorted(p.x_m for p in everything.points)
    cut = xs[len(xs) // 2] - PLAN_MARGIN_M  # the plan ends where half the scans are
    half = contribution(_upload(), AnchorContext(extents={3: (-1e4, -1e4, cut, 1e4)}))
    assert 0 < half.report["scans"] < everything.report["scans"]
    assert all(p.x_m <= cut + PLAN_MARGIN_M for p in half.points)
    assert any("outside the floor plan" in r for r in half.report["not_used"])
    # another floor's extent does not apply
    other = contribution(_upload(), AnchorContext(extents={2: (0.0, 0.0, 1.0, 1.0)}))
    assert other.report["scans"] == everything.report["scans"]


# walks made of our own events (a JSON upload), no servers needed
T0 = 1_700_000_000_000
STEP_M, STEP_S = 0.7, 0.5


def _json_upload(events: Sequence[Event], anchors: list[tuple[int, float, float]]) -> Upload:
    payload = traces.encode_trace(traces.trace_from_events(events, anchors))
    return Upload(
        id="u", site_id="s", content_type=traces.CONTENT_TYPE, payload=payload, floor_level=0
    )


def _l_walk() -> tuple[list[Event], list[tuple[int, float, float]], Any]:
    """20 phone steps east from (2, 2), then 20 north, a WiFi scan after every step; the
    anchors are the two ends only. Also where the walker was at a time (ms)."""
    headings = [math.pi / 2] * 20 + [0.0] * 20
    steps = [
        StepEvent(T0 + int(1000 * STEP_S * (k + 1)), STEP_M, h) for k, h in enumerate(headings)
    ]
    scans = [
        WifiEvent(s.t_ms + 100, (RadioReading("02:00:00:00:00:01", -60.0),)) for s in steps[:-1]
    ]
    end = (2.0 + 20 * STEP_M, 2.0 + 20 * STEP_M)
    anchors = [(T0, 2.0, 2.0), (steps[-1].t_ms, *end)]

    def where(t_ms: float) -> tuple[float, float]:
        walked = STEP_M * min((t_ms - T0) / (1000 * STEP_S), 40.0)
        east = min(walked, 20 * STEP_M)
        return 2.0 + east, 2.0 + walked - east

    return [*steps, *scans], anchors, where


def test_the_phone_s_step_events_place_a_walk_without_raw_motion_samples() -> None:
    events, anchors, where = _l_walk()
    found = contribution(_json_upload(events, anchors))
    assert found.rejected is None, found.report
    assert found.report["placement"] == "steps between anchors"
    assert found.report["steps_from"] == "the phone's step events"
    assert found.report["steps"] == 40
    assert found.report["step_scale"] == pytest.approx(1.0, abs=1e-6)
    assert len(found.points) == 39
    # along the L, not on the straight line between its ends (at constant speed the
    # corner would be placed 5 m off)
    for p in found.points:
        assert p.t_ms is not None
        x, y = where(p.t_ms)
        assert math.hypot(p.x_m - x, p.y_m - y) < 0.75, (p.t_ms, p.x_m, p.y_m)
    # without the steps: constant speed, the corner cut
    scans_only = [e for e in events if not isinstance(e, StepEvent)]
    straight = contribution(_json_upload(scans_only, anchors))
    assert straight.report["placement"] == "constant speed between anchors (no steps found)"
    corner = min(straight.points, key=lambda p: abs((p.t_ms or 0) - (T0 + 10_000)))
    assert math.hypot(corner.x_m - 16.0, corner.y_m - 2.0) > 4.0


def test_a_rejection_names_the_cause_that_cost_the_most_samples() -> None:
    # magnetometer samples every 0.5 s for 14 s; anchors 180 km apart from 1 s to 13 s
    events: list[Event] = [MagEvent(T0 + 500 * k, (20.0, 0.0, -40.0)) for k in range(28)]
    anchors = [(T0 + 1000, -90_000.0, 5.0), (T0 + 13_000, 90_000.0, 5.0)]
    found = contribution(_json_upload(events, anchors))
    main = "25 samples between anchors farther apart than a walker goes at 3 m/s"
    minor = "3 samples before the first or after the last anchor"
    assert found.report["not_used"] == [main, minor]
    assert found.rejected == f"nothing could be placed; main cause: {main}; also: {minor}"
    # weak scans: the reason counts the scans lost, not their readings
    weak = [WifiEvent(T0 + 500 * k, (RadioReading("aa", -95.0),)) for k in range(2, 26)]
    near = [(T0 + 1000, 0.0, 5.0), (T0 + 13_000, 12.0, 5.0)]
    found = contribution(_json_upload([*weak, events[0]], near))
    assert found.rejected is not None
    assert found.rejected.startswith(
        "nothing could be placed; main cause: 24 readings weaker than -90 dBm "
        "(24 scans heard nothing stronger); also: 1 samples before"
    ), found.rejected
