"""The upload worker: takes uploads from the queue and folds them into the maps.

One delivery at a time per worker (the work is CPU-bound; run more worker processes to go
faster). For each delivery: count the attempt (committed), compute the contribution in a
thread, fold it and settle the upload in one transaction, then acknowledge the queue
entry. A failure leaves the entry unacknowledged, so it comes back after the visibility
timeout until the upload runs out of attempts (``services.uploads``). At start, and
every ``RESCAN_S`` seconds while idle, uploads owed an outcome that nobody touched for a
visibility timeout are queued again: that recovers entries a queue lost (a restarted
process, a Redis that keeps nothing on disk).
"""

from __future__ import annotations

import logging
import os
import socket
import time
from functools import partial

import anyio

from server.services import upload_anchors, upload_contribution, uploads
from server.services.runtime import Runtime
from server.storage.upload_queue import Delivery, MemoryUploadQueue

log = logging.getLogger("indoorpos.worker")

RESCAN_S = 30.0
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


async def handle(rt: Runtime, delivery: Delivery) -> None:
    """Process one delivery (see the module docstring)."""
    async with rt.transaction() as s:
        upload = await uploads.begin_attempt(s, delivery.upload_id)
    if upload is None:
        await rt.uploads.ack(delivery)
        return
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
        async with rt.transaction() as s:
            await uploads.settle(s, delivery.upload_id, result)
    except Exception as exc:
        log.exception("upload %s: attempt %d failed", delivery.upload_id, upload.attempts)
        async with rt.transaction() as s:
            settled = await uploads.record_failure(
                s, delivery.upload_id, f"{type(exc).__name__}: {exc}"
            )
        if settled:
            await rt.uploads.ack(delivery)
        return
    rt.maps.invalidate(upload.site_id)
    await rt.uploads.ack(delivery)


async def run(rt: Runtime, consumer: str, stop: anyio.Event | None = None) -> None:
    """Serve the queue until ``stop`` is set (forever without one)."""
    idle_s = rt.settings.upload_visibility_s
    # an in-process queue starts empty: everything unsettled is this process' to redo
    try:
        await requeue_stranded(rt, 0.0 if isinstance(rt.uploads, MemoryUploadQueue) else idle_s)
    except Exception:
        log.exception("could not re-queue stranded uploads; the idle rescan will")
    last_scan = time.monotonic()
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
        if not deliveries and time.monotonic() - last_scan >= RESCAN_S:
            # an idle (or cut off) worker looks for uploads whose queue entry was lost
            last_scan = time.monotonic()
            try:
                await requeue_stranded(rt, idle_s)
            except Exception:
                log.exception("could not re-queue stranded uploads; trying again later")
