"""What one upload adds to the maps, from a recorded ILC walk (no servers needed)."""

from __future__ import annotations

import lzma

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
    from server.positioning.floorplan_geojson import PLAN_MARGIN_M
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
