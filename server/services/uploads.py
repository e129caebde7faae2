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

What an upload may carry and how it is read is in ``upload_payloads``; what it adds to the
maps (computed outside any transaction) in ``upload_contribution``; what its building
offers to anchor it in ``upload_anchors``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta

import anyio
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.mapping.walk_contribution import Contribution
from server.services.errors import Conflict, Invalid, NotFound, not_found
from server.services.magnetic_maps import fold_sources
from server.services.maps import add_survey
from server.services.upload_anchors import upload_building_id
from server.services.upload_payloads import parse_payload
from server.storage.models import Floor, Upload
from server.storage.repositories import sites as site_repo
from server.storage.repositories import uploads as upload_repo
from server.storage.repositories.pages import Key, Page

QUEUED, PROCESSING, DONE, REJECTED, FAILED = "queued", "processing", "done", "rejected", "failed"
SETTLED = frozenset({DONE, REJECTED, FAILED})
MAX_ATTEMPTS = 3


@dataclass(frozen=True)
class NewUpload:
    site_id: str
    building_id: str | None
    floor_level: int | None
    device_model: str | None
    content_type: str
    payload: bytes  # decompressed
    idempotency_key: str | None


async def create_upload(s: AsyncSession, new: NewUpload) -> tuple[Upload, bool]:
    """Validate and store an upload as ``queued``; with a known idempotency key, the upload
    stored under it (``False``: nothing new was created)."""
    if new.idempotency_key is not None:
        existing = await upload_repo.find_upload_by_key(s, new.idempotency_key)
        if existing is not None:
            if existing.payload != new.payload or existing.site_id != new.site_id:
                raise Conflict(
                    "this idempotency key was used for a different upload",
                    field="idempotency-key",
                )
            return existing, False
    if await site_repo.get_site(s, new.site_id) is None:
        raise NotFound(f"site {new.site_id} not found", field="site_id")
    if new.building_id is not None:
        building = await site_repo.get_building(s, new.building_id)
        if building is None or building.site_id != new.site_id:
            raise NotFound(
                f"building {new.building_id} not found in this site", field="building_id"
            )
    # reading a long trace takes seconds: off the event loop
    await anyio.to_thread.run_sync(parse_payload, new.content_type, new.payload, "upload")
    row = await upload_repo.create_upload(
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
    row = await upload_repo.get_upload(s, upload_id)
    if row is None:
        raise not_found("upload", upload_id)
    return row


async def list_uploads(
    s: AsyncSession, site_id: str | None, status: str | None, after: Key | None, limit: int
) -> Page[Upload]:
    """Uploads newest first (of one site, in one status, when given)."""
    return await upload_repo.upload_page(s, site_id, status, after, limit)


async def stranded_ids(s: AsyncSession, idle_s: float) -> list[str]:
    """Uploads still owed an outcome that nobody has touched for ``idle_s`` seconds: their
    queue entry may be gone (a restarted in-process queue, a Redis that lost its data), so
    the worker queues them again. A duplicate entry is harmless (see the module docstring)."""
    since = datetime.now(UTC) - timedelta(seconds=idle_s)
    return await upload_repo.upload_ids(s, [QUEUED, PROCESSING], since)


async def begin_attempt(s: AsyncSession, upload_id: str) -> Upload | None:
    """Count an attempt and mark the upload ``processing``; None when there is nothing to
    do (unknown, already settled, or out of attempts: then it is settled ``failed``)."""
    row = await upload_repo.lock_upload(s, upload_id)
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
    row = await upload_repo.lock_upload(s, upload_id)
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


async def settle(s: AsyncSession, upload_id: str, result: Contribution) -> bool:
    """Fold a contribution into the maps and mark the upload ``done`` (or ``rejected``) in
    the caller's transaction; False when the upload was settled meanwhile (nothing done)."""
    row = await upload_repo.lock_upload(s, upload_id)
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
        await site_repo.lock_building(s, building_id)
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
    building_id = await upload_building_id(s, row)
    if building_id is None:
        return "the site has several buildings (or none): give building_id"
    level = result.floor_level if result.floor_level is not None else 0
    floor = await site_repo.find_floor(s, building_id, level)
    if floor is None:
        return f"floor level {level} does not exist in the building"
    return floor
