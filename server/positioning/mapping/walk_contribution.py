"""What one upload adds to the maps: its scans and magnetometer samples placed along the
walk (CPU work; the service's ``uploads.settle`` folds the result in).

What is folded today: a trace with at least two known positions (anchors; in an ILC 2.0
path file its waypoints, as surveyors or an entrance and an elevator give them) places its
scans and magnetometer samples by the walker's own steps between the anchors: steps found
on the server in the raw IMU or, when that gives none, the ``step`` events the phone sent,
aligned onto the anchors by a similarity transform and smoothed forward-backward between
them (``mapping.placement``); without either, at constant speed between the anchors
(``mapping.labelled``). A walk with fewer than two anchors is rejected with that reason.
Its anchors are its waypoints, its passes by the beacons and anchor APs of its floor
(``AnchorContext``, which the service's ``upload_anchors`` fills) and its good satellite
fixes (``papers/003_*`` IV-B, IV-E3).

The report's ``not_used`` says why samples (scans, magnetometer samples) were left out,
the reason that cost the most samples first; a walk of which nothing could be placed is
rejected naming that main cause, then the others.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.mapping.anchors import ble_anchors, gnss_anchors
from server.positioning.mapping.labelled import interpolate_track
from server.positioning.mapping.magnetic_gridding import MagneticSamples
from server.positioning.mapping.placement import place_samples
from server.positioning.mapping.selection import select_inertial
from server.positioning.mapping.survey_points import SurveyPointData
from server.positioning.model.events import WifiEvent
from server.positioning.model.geo import GeoReference
from server.positioning.model.walk import Walk
from server.positioning.motion.step_tracker import TrackerParams
from server.positioning.motion.walk_steps import anchored_steps
from server.positioning.plan.geojson_plan import PLAN_MARGIN_M, near_extent


@dataclass(frozen=True)
class Beacon:
    """An emitter at a known place: a BLE beacon a floor plan marks (an entrance, an
    elevator; ``papers/003_*`` IV-B), or one of the floor's own WiFi APs located from the
    radio map (IV-E2). A walk passes it where its smoothed RSS peaks at or above
    ``threshold_dbm`` (None: ``mapping.anchors``' default for beacons)."""

    emitter: str  # lower-case id, as scans carry it
    xy_m: tuple[float, float]
    level: int
    kind: str = "ble"  # or "wifi"
    threshold_dbm: float | None = None


@dataclass(frozen=True)
class AnchorContext:
    """What an upload's building offers to anchor a walk: beacons and anchor APs, and
    the geo-reference that turns satellite fixes into building coordinates."""

    beacons: Sequence[Beacon] = ()
    geo: GeoReference | None = None
    # per floor level, the plan's extent: samples placed farther out than PLAN_MARGIN_M
    # are not used (a wrong anchor must not stretch a floor's maps across a city)
    extents: Mapping[int, tuple[float, float, float, float]] = field(default_factory=dict)


WEAK_DBM = -90.0  # papers/003_* IV-D: weaker readings are not signatures
MAX_WALK_MPS = 3.0  # brisk walking is under 2 m/s; faster between anchors is not a walk

# why samples were not used: (how many samples it cost, what to tell the sender)
Loss = tuple[int, str]


@dataclass(frozen=True)
class Contribution:
    """What one upload adds to the maps, or why it adds nothing (``rejected``)."""

    floor_level: int | None
    points: Sequence[SurveyPointData] = ()
    magnetic: MagneticSamples | None = None
    rejected: str | None = None
    report: dict[str, Any] = field(default_factory=dict)


def walk_contribution(
    trace: Walk,
    level: int,
    context: AnchorContext,
    *,
    inertial_selection: bool = False,
) -> Contribution:
    """The readings a walk on floor ``level`` adds to the maps (CPU work: run it in a
    thread). Its anchors are its waypoints, its passes by the beacons and anchor APs of its
    floor and its good satellite fixes (``papers/003_*`` IV-B, IV-E3)."""
    n_waypoints = int(trace.waypoint_t_ms.size)
    trace = _with_passes(trace, [b for b in context.beacons if b.level == level], context.geo)
    report: dict[str, Any] = {
        "anchors": int(trace.waypoint_t_ms.size),
        "anchor_source": "waypoints" if n_waypoints else "beacons",
        "anchor_passes": int(trace.waypoint_t_ms.size) - n_waypoints,
    }
    if trace.waypoint_t_ms.size < 2:
        return Contribution(
            level,
            rejected="fewer than two anchors: no waypoints, and passes by fewer than two "
            "of the floor plan's beacons",
            report=report,
        )
    events = [e for e in trace.radio_events() if e.readings]
    samples = trace.magnetic
    field_usable = bool(samples.shape[0]) and "magnetic" not in trace.uncalibrated
    times = np.concatenate(
        [
            np.array([e.t_ms for e in events], dtype=np.float64),
            samples[:, 0] if field_usable else np.empty(0),
        ]
    )
    xy, placed, not_used = _place(trace, times, report)
    if level in context.extents:
        inside = near_extent(context.extents[level], xy).all(axis=1)
        if n_out := int(np.count_nonzero(placed & ~inside)):
            m = PLAN_MARGIN_M
            not_used.append(
                (n_out, f"{n_out} samples placed more than {m:g} m outside the floor plan")
            )
        placed = placed & inside
    if inertial_selection:
        placed = placed & _selected(trace, times, placed, report, not_used)
    points: list[SurveyPointData] = []
    weak = weak_scans = 0
    for event, (x, y), ok in zip(events, xy[: len(events)].tolist(), placed, strict=False):
        if ok:
            # papers/003_* IV-D: readings weaker than -90 dBm are left out of the maps
            kept = [r for r in event.readings if r.rssi_dbm >= WEAK_DBM]
            weak += len(event.readings) - len(kept)
            if not kept:
                weak_scans += 1
                continue
            pairs = [(r.emitter, r.rssi_dbm) for r in kept]
            ages = [r.age_ms for r in kept]
            is_wifi = isinstance(event, WifiEvent)
            points.append(
                SurveyPointData(
                    x,
                    y,
                    level,
                    event.t_ms,
                    pairs if is_wifi else [],
                    [] if is_wifi else pairs,
                    None,
                    wifi_age_ms=ages if is_wifi else (),
                    ble_age_ms=() if is_wifi else ages,
                )
            )
    report["scans"] = len(points)
    if weak:
        scans = f" ({weak_scans} scans heard nothing stronger)" if weak_scans else ""
        not_used.append((weak_scans, f"{weak} readings weaker than {WEAK_DBM:g} dBm{scans}"))
    magnetic = None
    if field_usable:
        strength = np.linalg.norm(samples[:, 1:4], axis=1)
        keep = placed[len(events) :] & np.isfinite(strength)
        if keep.any():
            magnetic = MagneticSamples(xy=xy[len(events) :][keep], magnitude=strength[keep])
        report["magnetic_samples"] = int(keep.sum())
    elif samples.shape[0]:
        not_used.append((int(samples.shape[0]), "magnetometer: uncalibrated only"))
    not_used.sort(key=lambda loss: -loss[0])  # the main cause first (stable on ties)
    report["not_used"] = [why for _, why in not_used]
    if not points and magnetic is None:
        return Contribution(level, rejected=_nothing_placed(not_used), report=report)
    return Contribution(level, points, magnetic, report=report)


def _nothing_placed(not_used: Sequence[Loss]) -> str:
    """The reason of a walk of which nothing could be placed: the cause that cost the most
    samples (``not_used`` is sorted so), then the others."""
    if not not_used:
        return "nothing could be placed: the walk carries no scans and no magnetometer samples"
    (_, main), rest = not_used[0], not_used[1:]
    also = f"; also: {'; '.join(why for _, why in rest)}" if rest else ""
    return f"nothing could be placed; main cause: {main}{also}"


def _selected(
    trace: Walk,
    times: NDArray[np.float64],
    placed: NDArray[np.bool_],
    report: dict[str, Any],
    not_used: list[Loss],
) -> NDArray[np.bool_]:
    """Which sample times fall in spans of steady walking (``papers/003_*`` IV-A,
    ``mapping.selection``); the reasons for the rest go into the report, each with the
    placed samples its spans took (a span failing two criteria counts for both)."""
    selection = select_inertial(trace.accel, trace.gyro)
    spans = selection.kept_spans_ms
    inside = np.zeros(times.shape, dtype=bool)
    for start, end in spans.tolist():
        inside |= (times >= start) & (times < end)
    total = selection.kept_ms + selection.rejected_ms
    report["inertial_selection_kept"] = round(selection.kept_ms / total, 3) if total else 0.0
    worst: dict[str, tuple[int, NDArray[np.bool_]]] = {}
    for span in selection.rejected:
        in_span = placed & (times >= span.start_ms) & (times < span.end_ms)
        for criterion in span.criteria:
            ms, lost = worst.get(criterion, (0, np.zeros(times.shape, dtype=bool)))
            worst[criterion] = (ms + span.end_ms - span.start_ms, lost | in_span)
    for name, (ms, lost) in sorted(worst.items(), key=lambda kv: -kv[1][0]):
        n = int(np.count_nonzero(lost & ~inside))
        not_used.append((n, f"inertial selection: {ms / 1000:.0f} s failed {name}"))
    return inside


def _with_passes(trace: Walk, beacons: Sequence[Beacon], geo: GeoReference | None) -> Walk:
    """The trace with its passes by known beacons and anchor APs, and its good satellite
    fixes, added to its waypoints (``papers/003_*`` IV-B and IV-E3: where the smoothed RSS
    of one of them peaks at or above its threshold, the walker was at its place; a fix
    with accuracy < 5 m and HDOP < 20 places it too). One within a second of a waypoint
    is left out: the waypoint says it better."""
    found_t, found_xy = [trace.waypoint_t_ms.astype(np.float64)], [trace.waypoint_xy_m]
    if geo is not None and trace.gnss.shape[0]:
        fixes = gnss_anchors(trace.gnss, geo)
        found_t.append(fixes.t_ms.astype(np.float64))
        found_xy.append(fixes.xy_m)
    for kind, scans in (("ble", trace.ble), ("wifi", trace.wifi)):
        readings = [(e.t_ms, r.emitter.lower(), r.rssi_dbm) for e in scans for r in e.readings]
        for threshold in {b.threshold_dbm for b in beacons if b.kind == kind}:
            group = [b for b in beacons if b.kind == kind and b.threshold_dbm == threshold]
            known = {b.emitter for b in group}
            mine = [r for r in readings if r[1] in known]
            if not mine:
                continue
            t, ids, rssi = zip(*mine, strict=True)
            places = [(b.emitter, b.xy_m, b.level) for b in group]
            options = {} if threshold is None else {"threshold_dbm": threshold}
            passes = ble_anchors(t, list(ids), rssi, places, **options)
            found_t.append(passes.t_ms.astype(np.float64))
            found_xy.append(passes.xy_m)
    if len(found_t) == 1:
        return trace
    t_all, xy_all = np.concatenate(found_t), np.concatenate(found_xy)
    n_wp = trace.waypoint_t_ms.size
    keep = np.ones(t_all.size, dtype=bool)
    if n_wp:
        gap = np.abs(t_all[n_wp:, None] - trace.waypoint_t_ms[None, :]).min(axis=1)
        keep[n_wp:] = gap > 1000
    order = np.argsort(t_all[keep], kind="stable")
    return replace(
        trace,
        waypoint_t_ms=t_all[keep][order].astype(np.int64),
        waypoint_xy_m=np.ascontiguousarray(xy_all[keep][order]),
    )


def _between_fast_anchors(trace: Walk, times: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which ``times`` fall between two consecutive anchors that a walker could not go
    between at ``MAX_WALK_MPS`` (a wrong anchor, or one from another building)."""
    t = trace.waypoint_t_ms.astype(np.float64)
    dt_s = np.maximum(np.diff(t), 1.0) / 1000.0
    speed = np.linalg.norm(np.diff(trace.waypoint_xy_m, axis=0), axis=1) / dt_s
    segment = np.clip(np.searchsorted(t, times, side="right") - 1, 0, speed.size - 1)
    out: NDArray[np.bool_] = speed[segment] > MAX_WALK_MPS
    return out


def _steps(trace: Walk) -> tuple[NDArray[np.float64], str] | None:
    """The walk's steps between its first and last anchor as ``(n, 3)`` rows ``[t_ms,
    length_m, heading_rad]`` and where they come from: found in the raw motion samples
    (``walk_steps.anchored_steps``), else the phone's own ``step`` events; None when neither
    gives two, or the anchors lie too close along the walk for steps to be turned onto them
    (``walk_steps.MIN_ANCHORED_PATH_M``)."""
    found = anchored_steps(trace, TrackerParams())
    if found is None:
        return None
    if found.t_ms.size >= 2:
        rows = np.column_stack([found.t_ms, found.length_m, found.heading_rad])
        return rows.astype(np.float64), "raw motion samples"
    t = trace.steps[:, 0]
    phone = trace.steps[(t > trace.waypoint_t_ms[0]) & (t <= trace.waypoint_t_ms[-1])]
    return (phone, "the phone's step events") if phone.shape[0] >= 2 else None


def _place(
    trace: Walk, times: NDArray[np.float64], report: dict[str, Any]
) -> tuple[NDArray[np.float64], NDArray[np.bool_], list[Loss]]:
    """Positions of samples at ``times``: by the walker's steps between the anchors
    (``mapping.placement``), or at constant speed between them when the trace has no
    steps; why the others were not placed, with how many each reason cost."""
    steps = _steps(trace)
    if steps is None:
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, times)
        report["placement"] = "constant speed between anchors (no steps found)"
        reasons: list[Loss] = []
        if outside := int(np.count_nonzero(~valid)):
            reasons.append(
                (outside, f"{outside} samples before the first or after the last anchor")
            )
        too_fast = valid & _between_fast_anchors(trace, times)
        if n_fast := int(np.count_nonzero(too_fast)):
            reasons.append(
                (
                    n_fast,
                    f"{n_fast} samples between anchors farther apart than a walker goes at "
                    f"{MAX_WALK_MPS:g} m/s",
                )
            )
        return xy, valid & ~too_fast, reasons
    rows, source = steps
    placement = place_samples(
        rows[:, 0], rows[:, 1], rows[:, 2], trace.waypoint_t_ms, trace.waypoint_xy_m, times
    )
    report["placement"] = "steps between anchors"
    report["steps"] = int(rows.shape[0])
    report["steps_from"] = source
    if np.isfinite(placement.scale):
        report["step_scale"] = round(placement.scale, 3)
    lost = zip(placement.not_used_samples, placement.not_used, strict=True)
    return placement.xy_m, placement.placed, list(lost)
