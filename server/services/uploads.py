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

What is folded today: traces whose positions are known at waypoints (ILC 2.0 path files,
as surveyors record them) place their scans and magnetometer samples by interpolation
between waypoints (``mapping.labelled``), as the survey API does. A walk without waypoints
is rejected with that reason.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
from sqlalchemy.ext.asyncio import AsyncSession

from server.datasets.ilc import IlcTrace, TraceFormatError, floor_level, parse_trace_text
from server.positioning.events import WifiEvent
from server.positioning.magnetic import MagneticSamples
from server.positioning.mapping.labelled import interpolate_track
from server.services.errors import Conflict, Invalid, NotFound
from server.services.magnetic_maps import fold_sources
from server.services.maps import SurveyPointData, add_survey
from server.storage import repositories as repo
from server.storage.models import Floor, Upload

QUEUED, PROCESSING, DONE, REJECTED, FAILED = "queued", "processing", "done", "rejected", "failed"
SETTLED = frozenset({DONE, REJECTED, FAILED})
MAX_ATTEMPTS = 3
ILC_TEXT = "text/plain"


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
    if content_type != ILC_TEXT:
        raise Invalid(f"unsupported content type {content_type!r}", field="content-type")
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
    parse_payload(new.content_type, new.payload, "upload")
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


def contribution(upload: Upload) -> Contribution:
    """The readings an upload adds to the maps (CPU work, no I/O: run it in a thread)."""
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
    if trace.waypoint_t_ms.size < 2:
        return Contribution(
            level,
            rejected="no waypoints: walks without waypoints need anchor alignment, "
            "which this server does not do yet",
        )
    report: dict[str, Any] = {"waypoints": int(trace.waypoint_t_ms.size)}
    not_used = []
    events = [e for e in trace.radio_events() if e.readings]
    points: list[SurveyPointData] = []
    if events:
        t = np.array([e.t_ms for e in events], dtype=np.int64)
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, t)
        for event, (x, y), ok in zip(events, xy.tolist(), valid.tolist(), strict=True):
            if not ok:
                continue
            pairs = [(r.emitter, r.rssi_dbm) for r in event.readings]
            wifi = pairs if isinstance(event, WifiEvent) else []
            points.append(
                SurveyPointData(x, y, level, event.t_ms, wifi, [] if wifi else pairs, None)
            )
        if len(points) < len(events):
            not_used.append(
                f"{len(events) - len(points)} scans before the first or after the last waypoint"
            )
    report["scans"] = len(points)
    magnetic = None
    samples = trace.magnetic
    if samples.shape[0] and "magnetic" not in trace.uncalibrated:
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, samples[:, 0])
        strength = np.linalg.norm(samples[:, 1:4], axis=1)
        keep = valid & np.isfinite(strength)
        if keep.any():
            magnetic = MagneticSamples(xy=xy[keep], magnitude=strength[keep])
        report["magnetic_samples"] = int(keep.sum())
    elif samples.shape[0]:
        not_used.append("magnetometer: uncalibrated only")
    report["not_used"] = not_used
    if not points and magnetic is None:
        return Contribution(level, rejected="nothing placed between waypoints", report=report)
    return Contribution(level, points, magnetic, report=report)


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
    if result.points:
        radio = await add_survey(s, building_id, result.points, upload_id=row.id)
        report["radio_map_version"] = radio.version
    if result.magnetic is not None:
        await repo.lock_building(s, building_id)
        version = await fold_sources(s, target.id, [result.magnetic], source="upload")
        report["magnetic_map_version"] = version.version
    row.status = DONE
    row.report = report
    return True


async def _target_floor(s: AsyncSession, row: Upload, result: Contribution) -> Floor | str:
    """The floor an upload's readings go to, or why there is none."""
    building_id = row.building_id
    if building_id is None:
        buildings = await repo.list_buildings(s, row.site_id)
        if len(buildings) != 1:
            return "the site has several buildings (or none): give building_id"
        building_id = buildings[0].id
    level = result.floor_level if result.floor_level is not None else 0
    floor = await repo.find_floor(s, building_id, level)
    if floor is None:
        return f"floor level {level} does not exist in the building"
    return floor
