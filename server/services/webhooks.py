"""Webhooks: an operator's receivers of a site's zone and navigation events, and the
deliveries they are owed (``services.webhook_delivery`` sends them).

An event is owed to every webhook of its site that asked for its type, as one delivery
row (``WebhookDelivery``), written before the batch that made it is answered. The row is
keyed by the event (session, zone, kind and the time its run began), so an event made
again (a retried batch, answered from the session's replies, owes its events again) is
owed once.

The body of a delivery is JSON::

    {"id": "<delivery id>", "type": "zone.enter" | "zone.exit", "created": "<ISO 8601>",
     "site_id", "session_id", "seq", "zone": {"id", "name", "floor_id", "level"},
     "t": <ms>, "since": <ms>, "dwell_s": <s or null>,
     "position": {"x_m", "y_m", "floor_id", "level", "lat", "lon", "accuracy_m"}}

or, for a navigation event (``navigation.rerouted``, ``navigation.floor_change``,
``navigation.arrived``), ``"navigation"`` (the event as the fix carries it) and ``"t"``
in place of the zone's fields.

signed as described in :func:`signature`.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import socket
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import anyio
import httpx
import orjson
from sqlalchemy.ext.asyncio import AsyncSession

from server.services.auth import new_secret
from server.services.errors import Conflict, Invalid, NotFound
from server.services.runtime import Runtime
from server.services.sites import get_site
from server.storage.models import Webhook, WebhookDelivery, new_id, utcnow
from server.storage.repositories import webhooks as repo
from server.storage.repositories.pages import Key, Page

SECRET_PREFIX = "whsec_"
SIGNATURE_HEADER = "X-Indoorpos-Signature"
PENDING, DELIVERED, FAILED = "pending", "delivered", "failed"
MAX_PER_SITE = 20


def signature(secret: str, timestamp_s: int, body: bytes) -> str:
    """The ``X-Indoorpos-Signature`` header of a delivery: ``t=<unix seconds>,v1=<hex>``,
    where the hex is the HMAC-SHA256, keyed with the webhook's secret, of
    ``"<t>." + body``. A receiver recomputes it, compares in constant time, and refuses a
    ``t`` too far from its clock (a replayed delivery)."""
    mac = hmac.new(secret.encode(), f"{timestamp_s}.".encode() + body, hashlib.sha256)
    return f"t={timestamp_s},v1={mac.hexdigest()}"


class Unreachable(ValueError):
    """A webhook URL the service may not send to: it names no host, does not resolve, or
    resolves to an address that is not public."""


async def check_destination(url: str, private_networks: bool) -> None:
    """Raise :class:`Unreachable` unless ``url``'s host resolves to public addresses only
    (any address with ``private_networks``): an API key must not make the worker reach
    the service's own network (loopback, private ranges, the cloud metadata address).
    Checked when a webhook is registered and before each delivery (the name may resolve
    elsewhere later)."""
    host = httpx.URL(url).host
    if not host:
        raise Unreachable("the URL names no host")
    if private_networks:
        return
    try:
        found = await anyio.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except OSError as exc:
        raise Unreachable(f"{host} does not resolve ({exc.strerror or exc})") from None
    for *_, sockaddr in found:
        address = ipaddress.ip_address(str(sockaddr[0]).split("%", 1)[0])
        if not address.is_global:
            raise Unreachable(
                f"{host} resolves to {address}, not a public address (set "
                "INDOORPOS_WEBHOOK_PRIVATE_NETWORKS to send to the service's own network)"
            )


async def create_webhook(
    s: AsyncSession,
    site_id: str,
    url: str,
    events: Sequence[str],
    description: str,
    private_networks: bool = False,
) -> Webhook:
    """A new webhook of the site for ``events`` (``zone.enter``, ``zone.exit``); its
    ``secret`` is shown to the caller this once. A site has at most ``MAX_PER_SITE``."""
    await get_site(s, site_id)
    try:
        await check_destination(url, private_networks)
    except Unreachable as exc:
        raise Invalid(str(exc), field="url") from None
    if len(await repo.site_webhooks(s, site_id)) >= MAX_PER_SITE:
        raise Conflict(
            f"the site has {MAX_PER_SITE} webhooks, the most it may: delete one first",
            field="url",
        )
    hook = Webhook(
        site_id=site_id,
        url=url,
        events=" ".join(sorted(set(events))),
        secret=new_secret(SECRET_PREFIX),
        description=description,
    )
    s.add(hook)
    await s.flush()
    return hook


async def get_webhook(s: AsyncSession, site_id: str, webhook_id: str) -> Webhook:
    hook = await repo.get_webhook(s, webhook_id)
    if hook is None or hook.site_id != site_id:
        raise NotFound(f"webhook {webhook_id} not found", field="webhook_id")
    return hook


@dataclass(frozen=True)
class WebhookInfo:
    hook: Webhook
    counts: Mapping[str, int]  # deliveries by status
    last_error: str | None  # of the newest delivery that has one


async def list_webhooks(s: AsyncSession, site_id: str) -> list[WebhookInfo]:
    await get_site(s, site_id)
    hooks = await repo.site_webhooks(s, site_id)
    counts = await repo.delivery_counts(s, [h.id for h in hooks])
    errors = await repo.last_errors(s, [h.id for h in hooks])
    return [WebhookInfo(h, counts.get(h.id, {}), errors.get(h.id)) for h in hooks]


async def delete_webhook(s: AsyncSession, site_id: str, webhook_id: str) -> None:
    await s.delete(await get_webhook(s, site_id, webhook_id))
    await s.flush()


async def list_deliveries(
    s: AsyncSession,
    site_id: str,
    webhook_id: str,
    status: str | None,
    after: Key | None,
    limit: int,
) -> Page[WebhookDelivery]:
    await get_webhook(s, site_id, webhook_id)
    return await repo.delivery_page(s, webhook_id, status, after, limit)


def has_events(fixes_json: bytes) -> bool:
    """Whether a batch's answer (its fixes as JSON) holds a zone or navigation event,
    without parsing it (``zone_events`` and ``navigation.events`` are empty in most)."""
    return b'"zone_events":[{' in fixes_json or b'"events":[{' in fixes_json


async def owe_events(
    rt: Runtime, site_id: str, session_id: str, seq: int, fixes: Sequence[Mapping[str, Any]]
) -> int:
    """Owe the zone and navigation events of a batch's ``fixes`` (wire form) to the site's
    webhooks that asked for them; how many deliveries are new."""
    events = [
        (fix, f"zone.{event['type']}", event)
        for fix in fixes
        for event in fix.get("zone_events", ())
    ] + [
        (fix, f"navigation.{event['type']}", event)
        for fix in fixes
        for event in (fix.get("navigation") or {}).get("events", ())
    ]
    # a site has few webhooks (MAX_PER_SITE) and a batch few events: one statement
    if not events:
        return 0
    async with rt.transaction() as s:
        hooks = await repo.site_webhooks(s, site_id)
        now = utcnow()
        rows = [
            _delivery(hook, site_id, session_id, seq, fix, kind, event, now)
            for hook in hooks
            for fix, kind, event in events
            if kind in hook.events.split()
        ]
        return await repo.add_deliveries(s, rows)


def _delivery(
    hook: Webhook,
    site_id: str,
    session_id: str,
    seq: int,
    fix: Mapping[str, Any],
    event_type: str,
    event: Mapping[str, Any],
    now: datetime,
) -> dict[str, Any]:
    delivery_id = new_id()
    body: dict[str, Any] = {
        "id": delivery_id,
        "type": event_type,
        "created": now.isoformat(),
        "site_id": site_id,
        "session_id": session_id,
        "seq": seq,
    }
    if event_type.startswith("zone."):
        body |= {
            "zone": {
                "id": event["zone_id"],
                "name": event["zone_name"],
                "floor_id": event["floor_id"],
                "level": event["level"],
            },
            "t": event["t"],
            "since": event["since"],
            "dwell_s": event["dwell_s"],
            "reason": event.get("reason", "crossed"),
        }
        key = (
            f"{session_id}:{event['floor_id']}/{event['zone_id']}:{event['type']}:{event['since']}"
        )
    else:
        body |= {"navigation": dict(event), "t": event["t"]}
        key = f"{session_id}:navigation:{event['type']}:{event['route_version']}:{event['t']}"
    body["position"] = {
        k: fix.get(k) for k in ("x_m", "y_m", "floor_id", "level", "lat", "lon", "accuracy_m")
    }
    return {
        "id": delivery_id,
        "webhook_id": hook.id,
        "event_key": key[:200],
        "event_type": event_type,
        "payload": orjson.dumps(body),
        "status": PENDING,
        "attempts": 0,
        "next_attempt_at": now,
        "created_at": now,
    }
