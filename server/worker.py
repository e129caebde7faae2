"""The upload worker: takes uploads from the queue and folds them into the maps.

Beside it, it sends what webhooks are owed (``services.webhook_delivery``). When the
queue is quiet it builds what is owed of new radio map versions (the fix-error table,
FAI maps and floor graphs: ``build_maps``, ``services.map_builds``).

One delivery at a time per worker (the work is CPU-bound; run more worker processes to go
faster). For each delivery: count the attempt (committed), compute the contribution in a
thread, fold it and settle the upload in one transaction, then acknowledge the queue
entry. A failure leaves the entry unacknowledged, so it comes back after the visibility
timeout until the upload runs out of attempts (``services.uploads``). At start, and
every ``RESCAN_S`` seconds while idle, uploads owed an outcome that nobody touched for a
visibility timeout are queued again: that recovers entries a queue lost (a restarted
process, a Redis that keeps nothing on disk).

Each delivery is logged at INFO on ``indoorpos.worker``: the attempt taken, then how it
settled: ``folded`` (with the map versions it made), ``rejected`` (with the reason),
``retry`` (the attempt raised and the upload comes back after the visibility timeout) or
``failed`` (out of attempts). The lines carry ``upload_id`` and ``outcome`` as extra fields
(``INDOORPOS_LOG_FORMAT=json`` writes them out).
"""

from __future__ import annotations

import logging
import os
import socket
import time
from functools import partial

import anyio

from server.services import (
    history,
    map_builds,
    sites,
    upload_anchors,
    upload_contribution,
    uploads,
    webhook_delivery,
)
from server.services.errors import NotFound
from server.services.runtime import Runtime
from server.storage.upload_queue import Delivery, MemoryUploadQueue

log = logging.getLogger("indoorpos.worker")

RESCAN_S = 30.0
# a version is built once it has been the newest this long: a survey sent in several
# requests makes a version per request, and only the last is worth building
BUILD_SETTLE_S = 5.0
BUILD_POLL_S = 2.0  # how often a quiet worker asks SQL for a version to build
READ_BLOCK_MS = 1000


def consumer_name() -> str:
    return f"{socket.gethostname()}-{os.getpid()}"


async def requeue_stranded(rt: Runtime, idle_s: float) -> int:
    async with rt.transaction() as s:
        ids = await uploads.stranded_ids(s, idle_s)
    for upload_id in ids:
        await rt.uploads.publish(upload_id)
    if ids:
        log.info("queued %d stranded uploads again", len(ids))
    return len(ids)


def _settled_line(upload_id: str, status: str, report: dict[str, object], took_s: float) -> None:
    """The INFO line for an upload just settled ``done`` or ``rejected``."""
    extra = {"upload_id": upload_id, "outcome": status, "took_s": round(took_s, 3)}
    if status == uploads.REJECTED:
        reason = report.get("reason")
        log.info("upload %s: rejected: %s (%.1f s)", upload_id, reason, took_s, extra=extra)
        return
    made = [
        f"{kind} map v{report[key]}"
        for kind, key in (("radio", "radio_map_version"), ("magnetic", "magnetic_map_version"))
        if key in report
    ]
    extra["outcome"] = "folded"
    log.info(
        "upload %s: folded into %s (%.1f s)",
        upload_id,
        " and ".join(made) or "no map (nothing to add)",
        took_s,
        extra=extra,
    )


async def handle(rt: Runtime, delivery: Delivery) -> None:
    """Process one delivery (see the module docstring)."""
    upload_id = delivery.upload_id
    started = time.monotonic()
    async with rt.transaction() as s:
        upload = await uploads.begin_attempt(s, upload_id)
        if upload is None:  # for the log line: settled already, out of attempts, or gone
            try:
                status = (await uploads.get_upload(s, upload_id)).status
            except NotFound:
                status = "unknown"
    if upload is None:
        log.info(
            "upload %s: not taken (it is %s)",
            upload_id,
            status,
            extra={"upload_id": upload_id, "outcome": "skipped", "status": status},
        )
        await rt.uploads.ack(delivery)
        return
    log.info(
        "upload %s: attempt %d of %d taken (site %s, %s, %d bytes)",
        upload_id,
        upload.attempts,
        uploads.MAX_ATTEMPTS,
        upload.site_id,
        upload.content_type,
        len(upload.payload),
        extra={"upload_id": upload_id, "outcome": "taken", "attempt": upload.attempts},
    )
    try:
        async with rt.transaction() as s:  # after the attempt is counted: its failures count
            context = await upload_anchors.anchor_context(s, upload)
        result = await anyio.to_thread.run_sync(
            partial(
                upload_contribution.contribution,
                upload,
                context,
                inertial_selection=rt.settings.upload_inertial_selection,
            )
        )
        settled: tuple[str, dict[str, object]] | None = None  # its status and report
        async with rt.transaction() as s:
            if await uploads.settle(s, upload_id, result):
                row = await uploads.get_upload(s, upload_id)
                settled = (row.status, dict(row.report or {}))
    except Exception as exc:
        log.exception("upload %s: attempt %d failed", upload_id, upload.attempts)
        async with rt.transaction() as s:
            gave_up = await uploads.record_failure(s, upload_id, f"{type(exc).__name__}: {exc}")
        if gave_up:
            log.warning(
                "upload %s: failed after %d attempts; it is not retried",
                upload_id,
                upload.attempts,
                extra={"upload_id": upload_id, "outcome": "failed", "attempt": upload.attempts},
            )
            await rt.uploads.ack(delivery)
        else:
            log.info(
                "upload %s: attempt %d of %d failed; retried after the visibility timeout (%g s)",
                upload_id,
                upload.attempts,
                uploads.MAX_ATTEMPTS,
                rt.settings.upload_visibility_s,
                extra={"upload_id": upload_id, "outcome": "retry", "attempt": upload.attempts},
            )
        return
    if settled is None:
        log.info(
            "upload %s: settled meanwhile by another worker; nothing folded",
            upload_id,
            extra={"upload_id": upload_id, "outcome": "skipped"},
        )
    else:
        _settled_line(upload_id, *settled, time.monotonic() - started)
    rt.maps.invalidate(upload.site_id)
    await rt.uploads.ack(delivery)


async def build_maps(
    rt: Runtime,
    settle_s: float = 0.0,
    stop: anyio.Event | None = None,
    building_id: str | None = None,
    limit: int | None = None,
) -> int:
    """Build what is owed of pending radio map versions made at least ``settle_s`` ago
    (``services.map_builds``; of one building with ``building_id``), one after the other
    until none is left, ``limit`` were taken or ``stop`` is set; how many were built."""
    done = taken = 0
    while (stop is None or not stop.is_set()) and (limit is None or taken < limit):
        async with rt.transaction() as s:  # the lease (and the attempt) is committed first
            claim = await map_builds.claim(s, settle_s, building_id)
        if claim is None:
            break
        taken += 1
        version_id, attempt = claim.version_id, claim.attempt
        extra = {"radio_map_id": version_id, "outcome": "taken", "attempt": attempt}
        log.info("radio map %s: map build taken (attempt %d)", version_id, attempt, extra=extra)
        try:
            async with rt.transaction() as s:
                inputs = await map_builds.build_inputs(s, version_id)
                site_id = await sites.site_of(s, claim.building_id, None)
            # CPU-bound: in a thread, the event loop keeps serving; at shutdown the task
            # stops waiting for it (the lease runs out and the version is built again)
            built = await anyio.to_thread.run_sync(map_builds.build, inputs, abandon_on_cancel=True)
            async with rt.transaction() as s:
                stored = await map_builds.store(s, inputs, built, attempt)
        except Exception as exc:
            log.exception("radio map %s: map build failed", version_id)
            async with rt.transaction() as s:
                gave_up = await map_builds.record_failure(
                    s, version_id, f"{type(exc).__name__}: {exc}", attempt
                )
            extra["outcome"] = "failed" if gave_up else "retry"
            log.warning("radio map %s: map build %s", version_id, extra["outcome"], extra=extra)
            continue
        extra["outcome"] = "built" if stored else "not kept"
        log.info(
            "radio map %s: maps built in %.1f s (%d scans)%s",
            version_id,
            built.seconds,
            len(inputs.records.scans),
            "" if stored else "; not kept (a floor plan changed meanwhile, or the lease ran out)",
            extra=extra,
        )
        if site_id is not None:
            rt.maps.invalidate(site_id)
        done += stored
    return done


async def run(rt: Runtime, consumer: str, stop: anyio.Event | None = None) -> None:
    """Serve the queue, and send what webhooks are owed (``services.webhook_delivery``),
    until ``stop`` is set (forever without one)."""
    stop = stop or anyio.Event()
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(webhook_delivery.run, rt, stop)
        await serve_uploads(rt, consumer, stop)


async def serve_uploads(rt: Runtime, consumer: str, stop: anyio.Event | None = None) -> None:
    """Serve the queue until ``stop`` is set (forever without one)."""
    idle_s = rt.settings.upload_visibility_s
    # an in-process queue starts empty: everything unsettled is this process' to redo
    try:
        await requeue_stranded(rt, 0.0 if isinstance(rt.uploads, MemoryUploadQueue) else idle_s)
    except Exception:
        log.exception("could not re-queue stranded uploads; the idle rescan will")
    if isinstance(rt.uploads, MemoryUploadQueue):  # the only worker: its old leases died
        try:
            async with rt.transaction() as s:
                await map_builds.release_leases(s)
        except Exception:
            log.exception("could not release the map builds' leases; they run out")
    last_scan = last_build_poll = time.monotonic()
    while stop is None or not stop.is_set():
        deliveries = []
        try:
            deliveries = await rt.uploads.read(consumer, count=1, block_ms=READ_BLOCK_MS)
        except Exception:
            log.exception("upload queue unavailable; retrying")
            await anyio.sleep(1.0)
        for delivery in deliveries:
            try:
                await handle(rt, delivery)
            except Exception:  # the store failed under us: the entry comes back later
                log.exception(
                    "upload %s: could not be handled; it will be redelivered", delivery.upload_id
                )
        if not deliveries and time.monotonic() - last_build_poll >= BUILD_POLL_S:
            # uploads first: a build waits until the queue is quiet
            last_build_poll = time.monotonic()
            try:
                await build_maps(rt, BUILD_SETTLE_S, stop, limit=1)  # then the queue again
            except Exception:  # the store failed under us: the lease runs out, it comes back
                log.exception("map builds could not be taken; trying again later")
        if not deliveries and time.monotonic() - last_scan >= RESCAN_S:
            # an idle (or cut off) worker looks for uploads whose queue entry was lost
            last_scan = time.monotonic()
            try:
                await requeue_stranded(rt, idle_s)
            except Exception:
                log.exception("could not re-queue stranded uploads; trying again later")
            retention = rt.settings.walk_retention_days
            if retention is not None:
                try:
                    async with rt.transaction() as s:
                        pruned = await map_builds.prune_walks(s, retention)
                    if pruned:
                        log.info("deleted %d survey points past the walks' retention", pruned)
                except Exception:
                    log.exception("could not prune old walks; trying again later")
            try:
                purged = await history.purge(rt)
                if purged:
                    log.info("deleted %d batches of fixes past the history's retention", purged)
            except Exception:
                log.exception("could not purge old session history; trying again later")
