"""Crowdsourced uploads: accepted durably, processed at least once, folded exactly once.

Life of an upload (``Upload.status``)::

    queued ──► processing ──► done        (its readings are in the maps)
                   │    └───► rejected    (nothing usable; the report says why)
                   └────────► failed      (processing raised MAX_ATTEMPTS times; dead letter)

The row is written (and committed) before the sender hears 202, so an acknowledged upload
survives anything after that. A worker takes an entry from the queue, counts an attempt
in its own committed transaction (``begin_attempt``), computes the contribution outside
any transaction, then folds it into the maps and marks the row ``done`` in one
transaction that first re-checks, under a row lock, that nobody settled it meanwhile
(``settle``). A crash anywhere leaves the row ``processing`` with its queue entry
unacknowledged; the entry is re-delivered and the work repeated, and the re-check makes
the second fold impossible. An upload that keeps crashing its worker stops after
``MAX_ATTEMPTS`` attempts as ``failed``.

What is folded today: a trace with at least two known positions (anchors; in an ILC 2.0
path file its waypoints, as surveyors or an entrance and an elevator give them) places its
scans and magnetometer samples by the walker's own steps between the anchors: steps found
on the server in the raw IMU, aligned onto the anchors by a similarity transform and
smoothed forward-backward between them (``mapping.placement``); without motion data, at
constant speed between the anchors (``mapping.labelled``). A walk with fewer than two
anchors is rejected with that reason.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from typing import Any

import anyio
import numpy as np
from numpy.typing import NDArray
from sqlalchemy.ext.asyncio import AsyncSession

from server.datasets.ilc import IlcTrace, TraceFormatError, floor_level, parse_trace_text
from server.positioning.anchors import anchors_from_plan
from server.positioning.events import WifiEvent
from server.positioning.fingerprint import MISSING_DBM
from server.positioning.floorplan_geojson import PLAN_MARGIN_M, plan_extent
from server.positioning.mapping.anchors import GeoReference, ble_anchors, gnss_anchors
from server.positioning.mapping.labelled import interpolate_track
from server.positioning.mapping.magnetic_gridding import MagneticSamples
from server.positioning.mapping.placement import place_samples
from server.positioning.mapping.selection import select_inertial
from server.positioning.mapping.wifi_anchors import anchor_nodes
from server.positioning.step_tracker import TrackerParams
from server.services import traces
from server.services.errors import Conflict, Invalid, NotFound
from server.services.magnetic_maps import fold_sources
from server.services.maps import SurveyPointData, add_survey, stored_radio_map
from server.storage import repositories as repo
from server.storage.codec import CodecError
from server.storage.models import Floor, Upload

QUEUED, PROCESSING, DONE, REJECTED, FAILED = "queued", "processing", "done", "rejected", "failed"
SETTLED = frozenset({DONE, REJECTED, FAILED})
MAX_ATTEMPTS = 3
ILC_TEXT = "text/plain"
WEAK_DBM = -90.0  # papers/003_* IV-D: weaker readings are not signatures
MAX_WALK_MPS = 3.0  # brisk walking is under 2 m/s; faster between anchors is not a walk


@dataclass(frozen=True)
class NewUpload:
    site_id: str
    building_id: str | None
    floor_level: int | None
    device_model: str | None
    content_type: str
    payload: bytes  # decompressed
    idempotency_key: str | None


@dataclass(frozen=True)
class Contribution:
    """What one upload adds to the maps, or why it adds nothing (``rejected``)."""

    floor_level: int | None
    points: Sequence[SurveyPointData] = ()
    magnetic: MagneticSamples | None = None
    rejected: str | None = None
    report: dict[str, Any] = field(default_factory=dict)


def parse_payload(content_type: str, payload: bytes, path_id: str) -> IlcTrace:
    """The trace an upload carries; :class:`Invalid` naming the line when it cannot be read."""
    if content_type == traces.CONTENT_TYPE:
        try:
            return traces.decode_trace(payload, path_id)
        except (CodecError, KeyError) as exc:
            raise Invalid(f"not a stored trace: {exc}", field="body") from None
    if content_type != ILC_TEXT:
        raise Invalid(
            f"unsupported content type {content_type!r}: send text/plain (ILC 2.0), "
            "application/x-xz or application/json (our events)",
            field="content-type",
        )
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise Invalid(f"byte {exc.start}: the trace is not UTF-8 text", field="body") from None
    try:
        trace = parse_trace_text(text, path_id)
    except TraceFormatError as exc:
        raise Invalid(f"line {exc.line}: {exc.reason}", field="body") from None
    if trace.t_last_ms == 0:
        raise Invalid("the trace holds no records", field="body")
    return trace


async def create_upload(s: AsyncSession, new: NewUpload) -> tuple[Upload, bool]:
    """Validate and store an upload as ``queued``; with a known idempotency key, the upload
    stored under it (``False``: nothing new was created)."""
    if new.idempotency_key is not None:
        existing = await repo.find_upload_by_key(s, new.idempotency_key)
        if existing is not None:
            if existing.payload != new.payload or existing.site_id != new.site_id:
                raise Conflict(
                    "this idempotency key was used for a different upload",
                    field="idempotency-key",
                )
            return existing, False
    if await repo.get_site(s, new.site_id) is None:
        raise NotFound(f"site {new.site_id} not found", field="site_id")
    if new.building_id is not None:
        building = await repo.get_building(s, new.building_id)
        if building is None or building.site_id != new.site_id:
            raise NotFound(
                f"building {new.building_id} not found in this site", field="building_id"
            )
    # reading a long trace takes seconds: off the event loop
    await anyio.to_thread.run_sync(parse_payload, new.content_type, new.payload, "upload")
    row = await repo.create_upload(
        s,
        site_id=new.site_id,
        building_id=new.building_id,
        floor_level=new.floor_level,
        device_model=new.device_model,
        content_type=new.content_type,
        payload=new.payload,
        idempotency_key=new.idempotency_key,
        status=QUEUED,
    )
    return row, True


async def get_upload(s: AsyncSession, upload_id: str) -> Upload:
    row = await repo.get_upload(s, upload_id)
    if row is None:
        raise NotFound(f"upload {upload_id} not found", field="upload_id")
    return row


async def stranded_ids(s: AsyncSession, idle_s: float) -> list[str]:
    """Uploads still owed an outcome that nobody has touched for ``idle_s`` seconds: their
    queue entry may be gone (a restarted in-process queue, a Redis that lost its data), so
    the worker queues them again. A duplicate entry is harmless (see the module docstring)."""
    since = datetime.now(UTC) - timedelta(seconds=idle_s)
    return await repo.upload_ids(s, [QUEUED, PROCESSING], since)


async def begin_attempt(s: AsyncSession, upload_id: str) -> Upload | None:
    """Count an attempt and mark the upload ``processing``; None when there is nothing to
    do (unknown, already settled, or out of attempts: then it is settled ``failed``)."""
    row = await repo.lock_upload(s, upload_id)
    if row is None or row.status in SETTLED:
        return None
    if row.attempts >= MAX_ATTEMPTS:
        _settle_failed(row, "processing did not finish")
        return None
    row.attempts += 1
    row.status = PROCESSING
    return row


async def record_failure(s: AsyncSession, upload_id: str, error: str) -> bool:
    """After an attempt raised: settle ``failed`` when it was the last one (True), else
    leave it for the next delivery."""
    row = await repo.lock_upload(s, upload_id)
    if row is None or row.status in SETTLED:
        return True
    row.report = {**(row.report or {}), "last_error": error}
    if row.attempts >= MAX_ATTEMPTS:
        _settle_failed(row, error)
        return True
    return False


def _settle_failed(row: Upload, error: str) -> None:
    row.status = FAILED
    row.report = {
        **(row.report or {}),
        "reason": f"gave up after {row.attempts} attempts: {error}",
        "attempts": row.attempts,
    }


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


async def _building_id(s: AsyncSession, upload: Upload) -> str | None:
    if upload.building_id is not None:
        return upload.building_id
    buildings = await repo.list_buildings(s, upload.site_id)
    return buildings[0].id if len(buildings) == 1 else None


async def anchor_context(s: AsyncSession, upload: Upload) -> AnchorContext:
    """The beacons the floor plans of the upload's building mark, the WiFi APs that
    qualify as anchors in its current radio map (``mapping.wifi_anchors``) and its
    geo-reference; nothing when the site has several buildings and the upload names
    none."""
    building_id = await _building_id(s, upload)
    building = await repo.get_building(s, building_id) if building_id else None
    if building is None:
        return AnchorContext()
    geo = None
    if building.origin_lat is not None and building.origin_lon is not None:
        geo = GeoReference(building.origin_lat, building.origin_lon, building.rotation_rad)
    extents = {
        f.level: extent
        for f in await repo.list_floors(s, building.id)
        if (extent := plan_extent(f.plan_geojson)) is not None
    }
    return AnchorContext(await _beacons(s, building.id), geo, extents)


async def _beacons(s: AsyncSession, building_id: str) -> list[Beacon]:
    floors = await repo.list_floors(s, building_id)
    found = []
    for floor in floors:
        for a in anchors_from_plan(floor.plan_geojson, 0):
            found.append(Beacon(a.emitter.split(":", 1)[1], (a.x_m, a.y_m), floor.level))
    current = await repo.latest_radio_map(s, building_id)
    if current is not None:
        found += await _wifi_anchors(s, building_id, current.id, {f.id: f.level for f in floors})
    return found


# per building: when located, from which map version, the anchor APs
_WIFI_ANCHORS: OrderedDict[str, tuple[float, str, list[Beacon]]] = OrderedDict()
# anchor APs change slowly with the map, and locating them reads the whole radio map:
# a worker locates them again at most this often per building
WIFI_ANCHOR_REFRESH_S = 300.0


async def _wifi_anchors(
    s: AsyncSession, building_id: str, map_id: str, levels: dict[str, int]
) -> list[Beacon]:
    cached = _WIFI_ANCHORS.get(building_id)
    if cached is not None and (
        cached[1] == map_id or time.monotonic() - cached[0] < WIFI_ANCHOR_REFRESH_S
    ):
        return cached[2]
    stored = await repo.load_radio_map(s, map_id, MISSING_DBM)
    order = sorted(levels)
    radio = stored_radio_map(stored, {f: i for i, f in enumerate(order)})
    nodes = await anyio.to_thread.run_sync(anchor_nodes, radio)
    beacons = [
        Beacon(
            n.emitter.split(":", 1)[1],
            (float(n.fit.xy[0]), float(n.fit.xy[1])),
            levels[order[n.floor]],
            kind="wifi",
            threshold_dbm=n.fit.p0_dbm,
        )
        for n in nodes
    ]
    _WIFI_ANCHORS[building_id] = (time.monotonic(), map_id, beacons)
    _WIFI_ANCHORS.move_to_end(building_id)
    while len(_WIFI_ANCHORS) > 16:
        _WIFI_ANCHORS.popitem(last=False)
    return beacons


def contribution(
    upload: Upload,
    context: AnchorContext | None = None,
    *,
    inertial_selection: bool = False,
) -> Contribution:
    """The readings an upload adds to the maps (CPU work, no I/O: run it in a thread).
    Its anchors are its waypoints, its passes by the beacons and anchor APs of its floor
    and its good satellite fixes (``papers/003_*`` IV-B, IV-E3)."""
    context = context or AnchorContext()
    try:
        trace = parse_payload(upload.content_type, upload.payload, upload.id)
    except Invalid as exc:  # stored before a stricter reader: say why, do not retry
        return Contribution(None, rejected=exc.message)
    level = upload.floor_level
    if level is None:
        try:
            level = floor_level(trace.floor)
        except ValueError:
            return Contribution(None, rejected="no floor: give the floor hint (floor)")
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
        x0, y0, x1, y1 = context.extents[level]
        m = PLAN_MARGIN_M
        inside = (xy[:, 0] >= x0 - m) & (xy[:, 0] <= x1 + m) & (xy[:, 1] >= y0 - m)
        inside &= xy[:, 1] <= y1 + m
        if np.any(placed & ~inside):
            not_used.append(
                f"{int(np.count_nonzero(placed & ~inside))} samples placed more than "
                f"{m:g} m outside the floor plan"
            )
        placed = placed & inside
    if inertial_selection:
        placed = placed & _selected(trace, times, report, not_used)
    points: list[SurveyPointData] = []
    weak = 0
    for event, (x, y), ok in zip(events, xy[: len(events)].tolist(), placed, strict=False):
        if ok:
            # papers/003_* IV-D: readings weaker than -90 dBm are left out of the maps
            pairs = [(r.emitter, r.rssi_dbm) for r in event.readings if r.rssi_dbm >= WEAK_DBM]
            weak += len(event.readings) - len(pairs)
            if not pairs:
                continue
            wifi = pairs if isinstance(event, WifiEvent) else []
            points.append(
                SurveyPointData(x, y, level, event.t_ms, wifi, [] if wifi else pairs, None)
            )
    report["scans"] = len(points)
    if weak:
        not_used.append(f"{weak} readings weaker than {WEAK_DBM:g} dBm")
    magnetic = None
    if field_usable:
        strength = np.linalg.norm(samples[:, 1:4], axis=1)
        keep = placed[len(events) :] & np.isfinite(strength)
        if keep.any():
            magnetic = MagneticSamples(xy=xy[len(events) :][keep], magnitude=strength[keep])
        report["magnetic_samples"] = int(keep.sum())
    elif samples.shape[0]:
        not_used.append("magnetometer: uncalibrated only")
    report["not_used"] = not_used
    if not points and magnetic is None:
        why = f": {'; '.join(not_used)}" if not_used else ""
        return Contribution(level, rejected=f"nothing could be placed{why}", report=report)
    return Contribution(level, points, magnetic, report=report)


def _selected(
    trace: IlcTrace, times: NDArray[np.float64], report: dict[str, Any], not_used: list[str]
) -> NDArray[np.bool_]:
    """Which sample times fall in spans of steady walking (``papers/003_*`` IV-A,
    ``mapping.selection``); the reasons for the rest go into the report."""
    selection = select_inertial(trace.accel, trace.gyro)
    spans = selection.kept_spans_ms
    inside = np.zeros(times.shape, dtype=bool)
    for start, end in spans.tolist():
        inside |= (times >= start) & (times < end)
    total = selection.kept_ms + selection.rejected_ms
    report["inertial_selection_kept"] = round(selection.kept_ms / total, 3) if total else 0.0
    worst: dict[str, int] = {}
    for span in selection.rejected:
        for criterion in span.criteria:
            worst[criterion] = worst.get(criterion, 0) + span.end_ms - span.start_ms
    for name, ms in sorted(worst.items(), key=lambda kv: -kv[1]):
        not_used.append(f"inertial selection: {ms / 1000:.0f} s failed {name}")
    return inside


def _with_passes(trace: IlcTrace, beacons: Sequence[Beacon], geo: GeoReference | None) -> IlcTrace:
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


def _between_fast_anchors(trace: IlcTrace, times: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which ``times`` fall between two consecutive anchors that a walker could not go
    between at ``MAX_WALK_MPS`` (a wrong anchor, or one from another building)."""
    t = trace.waypoint_t_ms.astype(np.float64)
    dt_s = np.maximum(np.diff(t), 1.0) / 1000.0
    speed = np.linalg.norm(np.diff(trace.waypoint_xy_m, axis=0), axis=1) / dt_s
    segment = np.clip(np.searchsorted(t, times, side="right") - 1, 0, speed.size - 1)
    out: NDArray[np.bool_] = speed[segment] > MAX_WALK_MPS
    return out


def _place(
    trace: IlcTrace, times: NDArray[np.float64], report: dict[str, Any]
) -> tuple[NDArray[np.float64], NDArray[np.bool_], list[str]]:
    """Positions of samples at ``times``: by the walker's steps between the anchors
    (``mapping.placement``), or at constant speed between them when the trace has no
    motion data to find steps in."""
    steps = traces.anchored_steps(trace, TrackerParams())
    if steps is None or steps.t_ms.size < 2:
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, times)
        report["placement"] = "constant speed between anchors (no steps found)"
        outside = int(np.count_nonzero(~valid))
        reasons = [f"{outside} samples before the first or after the last anchor"]
        reasons = reasons if outside else []
        too_fast = valid & _between_fast_anchors(trace, times)
        if too_fast.any():
            reasons.append(
                f"{int(np.count_nonzero(too_fast))} samples between anchors farther apart "
                f"than a walker goes at {MAX_WALK_MPS:g} m/s"
            )
        return xy, valid & ~too_fast, reasons
    placement = place_samples(
        steps.t_ms,
        steps.length_m,
        steps.heading_rad,
        trace.waypoint_t_ms,
        trace.waypoint_xy_m,
        times,
    )
    report["placement"] = "steps between anchors"
    report["steps"] = int(steps.t_ms.size)
    if np.isfinite(placement.scale):
        report["step_scale"] = round(placement.scale, 3)
    return placement.xy_m, placement.placed, list(placement.not_used)


async def settle(s: AsyncSession, upload_id: str, result: Contribution) -> bool:
    """Fold a contribution into the maps and mark the upload ``done`` (or ``rejected``) in
    the caller's transaction; False when the upload was settled meanwhile (nothing done)."""
    row = await repo.lock_upload(s, upload_id)
    if row is None or row.status in SETTLED:
        return False
    report = {**(row.report or {}), **result.report}
    report.pop("last_error", None)
    target = await _target_floor(s, row, result) if result.rejected is None else None
    if isinstance(target, str):
        result = replace(result, rejected=target)
    if result.rejected is not None or not isinstance(target, Floor):
        row.status = REJECTED
        row.report = {**report, "reason": result.rejected}
        return True
    building_id = target.building_id
    if result.magnetic is not None:  # first: it may refuse the walk before anything is written
        await repo.lock_building(s, building_id)
        try:
            version = await fold_sources(s, target.id, [result.magnetic], source="upload")
        except Invalid as exc:
            row.status = REJECTED
            row.report = {**report, "reason": f"magnetic samples: {exc.message}"}
            return True
        report["magnetic_map_version"] = version.version
    if result.points:
        radio = await add_survey(s, building_id, result.points, upload_id=row.id)
        report["radio_map_version"] = radio.version
    row.status = DONE
    row.report = report
    return True


async def _target_floor(s: AsyncSession, row: Upload, result: Contribution) -> Floor | str:
    """The floor an upload's readings go to, or why there is none."""
    building_id = await _building_id(s, row)
    if building_id is None:
        return "the site has several buildings (or none): give building_id"
    level = result.floor_level if result.floor_level is not None else 0
    floor = await repo.find_floor(s, building_id, level)
    if floor is None:
        return f"floor level {level} does not exist in the building"
    return floor
