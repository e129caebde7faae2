"""Webhook routes: an operator registers receivers of a site's zone events and sees what
was delivered to them (``services.webhooks`` has the body and the signature)."""

from __future__ import annotations

from typing import Annotated

import orjson
from fastapi import APIRouter, Query, Response, status

from server.api.deps import AdminDep, IdPath, PageQuery, RuntimeDep, SqlDep, page_query
from server.api.gated_route import GatedRoute
from server.api.schemas.pages import CREATED, encode_cursor
from server.api.schemas.webhooks import (
    DeliveryList,
    DeliveryRead,
    DeliveryStatus,
    WebhookCreate,
    WebhookCreated,
    WebhookList,
    WebhookRead,
)
from server.services import webhooks
from server.storage.models import Webhook, WebhookDelivery

router = APIRouter(
    prefix="/v1/sites/{site_id}/webhooks",
    tags=["webhooks"],
    dependencies=[AdminDep],
    route_class=GatedRoute,
)
DeliveryPage = Annotated[PageQuery, page_query("deliveries", CREATED)]


def _read(hook: Webhook, info: webhooks.WebhookInfo | None = None) -> dict[str, object]:
    return {
        "id": hook.id,
        "site_id": hook.site_id,
        "url": hook.url,
        "events": hook.events.split(),
        "description": hook.description,
        "created_at": hook.created_at,
        "deliveries": dict(info.counts) if info else {},
        "last_error": info.last_error if info else None,
    }


@router.post("", status_code=status.HTTP_201_CREATED)
async def create_webhook(
    site_id: IdPath, body: WebhookCreate, s: SqlDep, rt: RuntimeDep
) -> WebhookCreated:
    """Register a receiver of the site's zone events (at most 20 a site). Its host must
    resolve to public addresses (unless the service allows its own network). The answer
    holds the secret that signs every delivery, this once: keep it."""
    hook = await webhooks.create_webhook(
        s,
        site_id,
        str(body.url),
        list(body.events),
        body.description,
        rt.settings.webhook_private_networks,
    )
    return WebhookCreated.model_validate({**_read(hook), "secret": hook.secret})


@router.get("")
async def list_webhooks(site_id: IdPath, s: SqlDep) -> WebhookList:
    """The site's webhooks, with their deliveries counted by status and the last error."""
    found = await webhooks.list_webhooks(s, site_id)
    items = [WebhookRead.model_validate(_read(i.hook, i)) for i in found]
    return WebhookList(items=items, count=len(items))


@router.delete("/{webhook_id}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_webhook(site_id: IdPath, webhook_id: IdPath, s: SqlDep) -> Response:
    """Stop the webhook; what it was still owed is dropped."""
    await webhooks.delete_webhook(s, site_id, webhook_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


def _delivery(d: WebhookDelivery) -> DeliveryRead:
    return DeliveryRead(
        id=d.id,
        event_type=d.event_type,
        status=d.status,
        attempts=d.attempts,
        next_attempt_at=d.next_attempt_at if d.status == webhooks.PENDING else None,
        last_status_code=d.last_status_code,
        last_error=d.last_error,
        delivered_at=d.delivered_at,
        created_at=d.created_at,
        payload=orjson.loads(d.payload),
    )


@router.get("/{webhook_id}/deliveries")
async def list_deliveries(
    site_id: IdPath,
    webhook_id: IdPath,
    s: SqlDep,
    page: DeliveryPage,
    status: Annotated[
        DeliveryStatus | None, Query(description="only deliveries in this state")
    ] = None,
) -> DeliveryList:
    """The webhook's deliveries, newest first: what is pending (and when it is tried
    next), delivered, or failed (with the receiver's last answer or the error)."""
    found = await webhooks.list_deliveries(s, site_id, webhook_id, status, page.after, page.limit)
    items = [_delivery(d) for d in found.rows]
    cursor = encode_cursor("deliveries", found.next_key) if found.next_key is not None else None
    return DeliveryList(items=items, count=len(items), next_cursor=cursor)
