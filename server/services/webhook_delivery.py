"""Sending what webhooks are owed (``services.webhooks``): the worker's delivery loop.

Each round leases the due deliveries (their attempt counted, in one transaction), POSTs
them concurrently, and settles each as its answer comes: a 2xx answer makes it
``delivered``; anything else (another status, a refused connection, no answer within
``webhook_timeout_s``, a host that now resolves to a private address) records the error
and schedules the next attempt after ``webhook_retry_s`` × 2^(attempt − 1) (at most an
hour), until ``webhook_attempts`` are spent (``failed``). A worker that dies holding a
lease leaves the delivery to the next after ``LEASE_S``; an attempt that outlives its
lease records nothing (the next worker's attempt is the one that counts). A delivery may
so reach its receiver more than once (an answer lost on the way back): its ``id`` (also
the ``X-Indoorpos-Delivery`` header) tells a repeat.

Each attempt is logged on ``indoorpos.webhooks`` and counted in
``indoorpos_webhook_deliveries_total{outcome}``. Settled deliveries are deleted
``webhook_retention_days`` after they were made (their bodies say where a person was).
"""

from __future__ import annotations

import logging
import math
import time
from datetime import timedelta

import anyio
import httpx
from prometheus_client import Counter

from server.services.runtime import Runtime
from server.services.webhooks import (
    DELIVERED,
    FAILED,
    SIGNATURE_HEADER,
    Unreachable,
    check_destination,
    signature,
)
from server.storage.models import Webhook, WebhookDelivery, utcnow
from server.storage.repositories import webhooks as repo

log = logging.getLogger("indoorpos.webhooks")

LEASE_S = 120.0  # longer than an attempt can take
ROUND = 32  # deliveries leased at a time
MAX_BACKOFF_S = 3600.0
PURGE_EVERY_S = 600.0
DELIVERIES = Counter(
    "indoorpos_webhook_deliveries",
    "Webhook delivery attempts by outcome (delivered, retry, failed).",
    ["outcome"],
)


def backoff_s(base_s: float, attempt: int) -> float:
    """The wait after failed attempt ``attempt`` (1, 2, ...)."""
    return float(min(base_s * 2 ** (attempt - 1), MAX_BACKOFF_S))


async def deliver_due(rt: Runtime, client: httpx.AsyncClient) -> int:
    """One round (module docstring); how many deliveries it attempted."""
    now = utcnow()
    taken: list[tuple[WebhookDelivery, Webhook]] = []
    async with rt.transaction() as s:
        for delivery, hook in await repo.due_deliveries(s, now, ROUND):
            if await repo.lease(s, delivery, now, LEASE_S):
                taken.append((delivery, hook))
    async with anyio.create_task_group() as tg:
        for delivery, hook in taken:
            tg.start_soon(attempt, rt, client, delivery, hook)
    return len(taken)


async def attempt(
    rt: Runtime, client: httpx.AsyncClient, delivery: WebhookDelivery, hook: Webhook
) -> None:
    """POST one leased delivery and record how it went."""
    tried = delivery.attempts + 1  # the lease counted this attempt
    code, error = await _post(rt, client, delivery, hook)
    extra = {"delivery_id": delivery.id, "webhook_id": hook.id, "attempt": tried}
    settled = utcnow()
    async with rt.transaction() as s:
        if error is None:
            values: dict[str, object] = {"status": DELIVERED, "delivered_at": settled}
            outcome = "delivered"
        elif tried >= rt.settings.webhook_attempts:
            values, outcome = {"status": FAILED}, "failed"
        else:
            wait = backoff_s(rt.settings.webhook_retry_s, tried)
            values, outcome = {"next_attempt_at": settled + timedelta(seconds=wait)}, "retry"
        if error is not None:  # a delivery that got through keeps what failed before
            values["last_error"] = error
        recorded = await repo.settle(s, delivery.id, tried, last_status_code=code, **values)
    if not recorded:  # the lease ran out and another worker took the delivery over
        log.warning("delivery %s: attempt %d outlived its lease", delivery.id, tried, extra=extra)
        return
    DELIVERIES.labels(outcome).inc()
    extra["outcome"] = outcome
    if outcome == "delivered":
        log.info("delivery %s of webhook %s: delivered", delivery.id, hook.id, extra=extra)
    else:
        log.warning(
            "delivery %s of webhook %s: attempt %d failed (%s)%s",
            delivery.id,
            hook.id,
            tried,
            error,
            "; out of attempts" if outcome == "failed" else "; tried again later",
            extra=extra,
        )


async def _post(
    rt: Runtime, client: httpx.AsyncClient, delivery: WebhookDelivery, hook: Webhook
) -> tuple[int | None, str | None]:
    """The receiver's status code (None: no answer) and the error (None: delivered). Only
    the status is kept of the answer: its body is not read (a receiver on somebody else's
    network would otherwise have it copied into the delivery's error)."""
    try:
        await check_destination(hook.url, rt.settings.webhook_private_networks)
    except Unreachable as exc:
        return None, f"refused: {exc}"
    body = delivery.payload
    headers = {
        "Content-Type": "application/json",
        "User-Agent": "indoorpos-webhooks",
        "X-Indoorpos-Event": delivery.event_type,
        "X-Indoorpos-Delivery": delivery.id,
        SIGNATURE_HEADER: signature(hook.secret, int(time.time()), body),
    }
    try:
        # the whole attempt, however slowly the receiver answers, well within the lease
        with anyio.fail_after(min(rt.settings.webhook_timeout_s, LEASE_S / 2)):
            async with client.stream("POST", hook.url, content=body, headers=headers) as answer:
                code = answer.status_code
    except TimeoutError:
        return None, "no answer in time"
    except httpx.HTTPError as exc:
        return None, type(exc).__name__
    if 200 <= code < 300:
        return code, None
    return code, f"HTTP {code}"


async def purge(rt: Runtime) -> int:
    """Delete the settled deliveries past ``webhook_retention_days``; how many."""
    before = utcnow() - timedelta(days=rt.settings.webhook_retention_days)
    async with rt.transaction() as s:
        return await repo.purge_deliveries(s, before)


async def run(rt: Runtime, stop: anyio.Event) -> None:
    """Deliver until ``stop`` is set: a round whenever one is due, else a look every
    ``webhook_poll_s``; every ``PURGE_EVERY_S``, the old settled deliveries go."""
    timeout = httpx.Timeout(rt.settings.webhook_timeout_s)
    last_purge = -math.inf
    async with httpx.AsyncClient(timeout=timeout, follow_redirects=False) as client:
        while not stop.is_set():
            attempted = 0
            try:
                attempted = await deliver_due(rt, client)
                if time.monotonic() - last_purge >= PURGE_EVERY_S:
                    last_purge = time.monotonic()
                    if purged := await purge(rt):
                        log.info("deleted %d webhook deliveries past their retention", purged)
            except Exception:  # the store failed under us: leases run out, rows come back
                log.exception("webhook deliveries could not be taken; trying again later")
            if not attempted:
                with anyio.move_on_after(rt.settings.webhook_poll_s):
                    await stop.wait()
