"""Webhooks and their deliveries."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.inserts import insert_ignoring
from server.storage.models import Webhook, WebhookDelivery
from server.storage.repositories.pages import Key, Page, keyset_page


async def get_webhook(s: AsyncSession, webhook_id: str) -> Webhook | None:
    return await s.get(Webhook, webhook_id)


async def site_webhooks(s: AsyncSession, site_id: str) -> Sequence[Webhook]:
    stmt = select(Webhook).where(Webhook.site_id == site_id)
    return (await s.scalars(stmt.order_by(Webhook.created_at, Webhook.id))).all()


async def delivery_counts(s: AsyncSession, webhook_ids: Sequence[str]) -> dict[str, dict[str, int]]:
    """Deliveries per webhook and status."""
    if not webhook_ids:
        return {}
    stmt = (
        select(WebhookDelivery.webhook_id, WebhookDelivery.status, func.count())
        .where(WebhookDelivery.webhook_id.in_(webhook_ids))
        .group_by(WebhookDelivery.webhook_id, WebhookDelivery.status)
    )
    out: dict[str, dict[str, int]] = {}
    for hook_id, status, n in (await s.execute(stmt)).all():
        out.setdefault(hook_id, {})[status] = n
    return out


async def last_errors(s: AsyncSession, webhook_ids: Sequence[str]) -> dict[str, str]:
    """Per webhook, the error of its newest delivery attempt that failed."""
    out: dict[str, str] = {}
    for hook_id in webhook_ids:
        stmt = (
            select(WebhookDelivery.last_error)
            .where(WebhookDelivery.webhook_id == hook_id)
            .where(WebhookDelivery.last_error.is_not(None))
            .order_by(WebhookDelivery.created_at.desc())
            .limit(1)
        )
        error = await s.scalar(stmt)
        if error is not None:
            out[hook_id] = error
    return out


DELIVERIES_BY_CREATED = (WebhookDelivery.created_at, WebhookDelivery.id)


async def delivery_page(
    s: AsyncSession, webhook_id: str, status: str | None, after: Key | None, limit: int
) -> Page[WebhookDelivery]:
    """A webhook's deliveries newest first (of one status, when given)."""
    stmt = select(WebhookDelivery).where(WebhookDelivery.webhook_id == webhook_id)
    if status is not None:
        stmt = stmt.where(WebhookDelivery.status == status)
    return await keyset_page(s, stmt, DELIVERIES_BY_CREATED, after, limit, descending=True)


async def add_deliveries(s: AsyncSession, rows: Sequence[Mapping[str, Any]]) -> int:
    """Insert deliveries, skipping any whose (webhook, event) is owed already; how many
    were new."""
    return await insert_ignoring(s, WebhookDelivery, rows, ("webhook_id", "event_key"))


def _unleased(now: datetime) -> Any:
    return (WebhookDelivery.leased_until.is_(None)) | (WebhookDelivery.leased_until < now)


async def due_deliveries(
    s: AsyncSession, now: datetime, limit: int
) -> Sequence[tuple[WebhookDelivery, Webhook]]:
    """Pending deliveries whose next attempt is due and nobody holds, with their webhook,
    the longest waiting first."""
    stmt = (
        select(WebhookDelivery, Webhook)
        .join(Webhook, WebhookDelivery.webhook_id == Webhook.id)
        .where(WebhookDelivery.status == "pending")
        .where(WebhookDelivery.next_attempt_at <= now)
        .where(_unleased(now))
        .order_by(WebhookDelivery.next_attempt_at, WebhookDelivery.id)
        .limit(limit)
    )
    return [(d, h) for d, h in (await s.execute(stmt)).all()]


async def lease(s: AsyncSession, delivery: WebhookDelivery, now: datetime, lease_s: float) -> bool:
    """Take a due delivery for one attempt (a compare-and-set on its attempts: two workers
    never both win); the attempt is counted."""
    taken = await s.execute(
        update(WebhookDelivery)
        .where(WebhookDelivery.id == delivery.id)
        .where(WebhookDelivery.status == "pending")
        .where(WebhookDelivery.attempts == delivery.attempts)
        .where(_unleased(now))
        .values(leased_until=now + timedelta(seconds=lease_s), attempts=delivery.attempts + 1)
        .execution_options(synchronize_session=False)
    )
    return bool(getattr(taken, "rowcount", 0))


async def settle(s: AsyncSession, delivery_id: str, attempt: int, **values: Any) -> bool:
    """Record how attempt ``attempt`` went, unless the delivery has moved on meanwhile (its
    lease ran out and another worker took the next attempt): whether it was recorded."""
    done = await s.execute(
        update(WebhookDelivery)
        .where(WebhookDelivery.id == delivery_id)
        .where(WebhookDelivery.status == "pending")
        .where(WebhookDelivery.attempts == attempt)
        .values(leased_until=None, **values)
        .execution_options(synchronize_session=False)
    )
    return bool(getattr(done, "rowcount", 0))


async def purge_deliveries(s: AsyncSession, before: datetime) -> int:
    """Delete the deliveries settled (delivered or failed) that were made before
    ``before``; how many."""
    gone = await s.execute(
        delete(WebhookDelivery)
        .where(WebhookDelivery.status != "pending")
        .where(WebhookDelivery.created_at < before)
        .execution_options(synchronize_session=False)
    )
    return int(getattr(gone, "rowcount", 0) or 0)
