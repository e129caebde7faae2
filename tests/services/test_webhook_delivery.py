"""Webhook deliveries against the real stores and a receiver on a loopback port: owed once
per event, retried with a doubling wait, failed after the last attempt with the error
kept, an attempt that outlived its lease recorded by nobody, a receiver on the service's
own network refused unless allowed, old settled deliveries purged."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import select, update

from server.config import Settings
from server.services import sites, webhook_delivery, webhooks
from server.services.errors import Conflict, Invalid, NotFound
from server.services.runtime import Runtime, open_runtime
from server.storage import db
from server.storage.models import WebhookDelivery, utcnow
from server.storage.repositories import webhooks as webhook_repo
from tests.support.webhook_receiver import webhook_receiver

ZONE_EVENT = {
    "type": "enter",
    "zone_id": "cafe",
    "zone_name": "Café",
    "floor_id": "f" * 32,
    "level": 0,
    "t": 1_700_000_003_000,
    "since": 1_700_000_000_000,
    "dwell_s": None,
    "reason": "crossed",
}
FIX = {"x_m": 1.0, "y_m": 2.0, "floor_id": "f" * 32, "level": 0, "lat": None, "lon": None}


@pytest.fixture
def worker_settings(settings: Settings, tmp_path: Path) -> Settings:
    """A worker's settings: it may send to loopback, retries at once, two attempts.
    Embedded, on a database of its own: the suite's embedded app runs a worker of its own
    on the shared one, which would take these deliveries too."""
    fast: dict[str, Any] = {
        "webhook_private_networks": True,
        "webhook_retry_s": 0.001,
        "webhook_attempts": 2,
    }
    if settings.database_url is None:
        fast["data_dir"] = tmp_path
    own = settings.model_copy(update=fast)
    db.migrate(own.resolved_database_url)
    return own


async def _site(rt: Runtime) -> str:
    async with rt.transaction() as s:
        return (await sites.create_site(s, "hooks")).id


async def _hook(rt: Runtime, site_id: str, url: str, events: list[str] | None = None) -> str:
    async with rt.transaction() as s:
        hook = await webhooks.create_webhook(
            s, site_id, url, events or ["zone.enter", "zone.exit"], "", private_networks=True
        )
        return hook.id


async def _deliveries(rt: Runtime, hook_id: str) -> list[WebhookDelivery]:
    async with rt.transaction() as s:
        stmt = select(WebhookDelivery).where(WebhookDelivery.webhook_id == hook_id)
        return list((await s.scalars(stmt)).all())


async def _owe(rt: Runtime, site_id: str, event: dict[str, Any] = ZONE_EVENT) -> int:
    return await webhooks.owe_events(rt, site_id, "s" * 32, 7, [{**FIX, "zone_events": [event]}])


async def _round(rt: Runtime) -> int:
    async with httpx.AsyncClient(timeout=5) as client:
        return await webhook_delivery.deliver_due(rt, client)


async def _until_attempted(rt: Runtime, hook_id: str, attempts: int) -> WebhookDelivery:
    """Rounds (which may take other tests' deliveries too) until the webhook's one
    delivery has had ``attempts`` attempts."""
    for _ in range(200):
        (delivery,) = await _deliveries(rt, hook_id)
        if delivery.attempts >= attempts and delivery.leased_until is None:
            return delivery
        await _round(rt)
    raise AssertionError(f"not attempted {attempts} times")


async def test_an_event_is_owed_once_to_each_webhook_that_asked_for_it(
    worker_settings: Settings,
) -> None:
    async with open_runtime(worker_settings) as rt:
        site_id = await _site(rt)
        both = await _hook(rt, site_id, "http://127.0.0.1:9/a")
        exits = await _hook(rt, site_id, "http://127.0.0.1:9/b", ["zone.exit"])
        assert await _owe(rt, site_id) == 1  # the enter: to the first only
        assert await _owe(rt, site_id) == 0  # made again (a replayed batch): owed once
        assert len(await _deliveries(rt, both)) == 1
        assert await _deliveries(rt, exits) == []
        exit_event = {**ZONE_EVENT, "type": "exit", "dwell_s": 4.0}
        assert await _owe(rt, site_id, exit_event) == 2
        (delivery,) = await _deliveries(rt, exits)
        assert delivery.event_type == "zone.exit"
        assert delivery.status == "pending"


async def test_a_refusing_receiver_is_tried_again_then_failed_with_the_error(
    worker_settings: Settings,
) -> None:
    async with open_runtime(worker_settings) as rt:
        with webhook_receiver(fail_first=-1) as receiver:
            site_id = await _site(rt)
            hook_id = await _hook(rt, site_id, receiver.url)
            await _owe(rt, site_id)
            first = await _until_attempted(rt, hook_id, 1)
            assert first.attempts == 1
            if first.status == "pending":  # else the doubling wait (1 ms) ran out already
                assert first.last_status_code == 500
                assert first.last_error == "HTTP 500"
            second = await _until_attempted(rt, hook_id, 2)
            assert (second.status, second.attempts) == ("failed", 2)
            assert (second.last_status_code, second.last_error) == (500, "HTTP 500")
            await _round(rt)
            assert len(receiver.received) == 2  # a failed delivery is not tried again


def test_the_wait_doubles_up_to_an_hour() -> None:
    waits = [webhook_delivery.backoff_s(10.0, n) for n in (1, 2, 3, 4, 20)]
    assert waits == [10.0, 20.0, 40.0, 80.0, 3600.0]


async def test_an_attempt_that_outlived_its_lease_records_nothing(
    worker_settings: Settings,
) -> None:
    async with open_runtime(worker_settings) as rt:
        with webhook_receiver() as receiver:
            site_id = await _site(rt)
            hook_id = await _hook(rt, site_id, receiver.url)
            await _owe(rt, site_id)
            (delivery,) = await _deliveries(rt, hook_id)
            async with rt.transaction() as s:  # a worker leased it (attempt 1) ...
                assert await webhook_repo.lease(s, delivery, utcnow(), 120.0)
                # ... and, its lease run out, another took attempt 2 (and holds it)
                await s.execute(
                    update(WebhookDelivery)
                    .where(WebhookDelivery.id == delivery.id)
                    .values(attempts=2, leased_until=utcnow() + timedelta(seconds=120))
                )
            async with httpx.AsyncClient() as client:
                await webhook_delivery.attempt(rt, client, delivery, (await _hook_row(rt, hook_id)))
            (after,) = await _deliveries(rt, hook_id)
            assert (after.status, after.attempts) == (
                "pending",
                2,
            )  # the first's answer is not kept
            assert len(receiver.accepted()) == 1


async def _hook_row(rt: Runtime, hook_id: str) -> Any:
    async with rt.transaction() as s:
        return await webhook_repo.get_webhook(s, hook_id)


async def test_the_service_s_own_network_is_refused_unless_allowed(
    worker_settings: Settings,
) -> None:
    async with open_runtime(worker_settings) as rt:
        site_id = await _site(rt)
        async with rt.transaction() as s:
            for url in ("http://127.0.0.1/x", "http://10.1.2.3/x", "http://169.254.169.254/x"):
                with pytest.raises(Invalid) as refused:
                    await webhooks.create_webhook(s, site_id, url, ["zone.enter"], "")
                assert refused.value.field == "url"
                assert "not a public address" in str(refused.value)
            await webhooks.create_webhook(s, site_id, "https://1.1.1.1/x", ["zone.enter"], "")
        # a host that resolves elsewhere later is refused at delivery
        hook_id = await _hook(rt, site_id, "http://127.0.0.1:9/x")
        await _owe(rt, site_id)
        strict = rt.settings.model_copy(update={"webhook_private_networks": False})
        async with open_runtime(strict) as worker:
            refused_delivery = await _until_attempted(worker, hook_id, 1)
        assert (refused_delivery.last_error or "").startswith("refused: 127.0.0.1 resolves to")


async def test_a_site_has_at_most_twenty_webhooks_and_a_missing_site_none(
    worker_settings: Settings,
) -> None:
    async with open_runtime(worker_settings) as rt:
        site_id = await _site(rt)
        for k in range(webhooks.MAX_PER_SITE):
            await _hook(rt, site_id, f"https://1.1.1.1/{k}")
        async with rt.transaction() as s:
            with pytest.raises(Conflict) as full:
                await webhooks.create_webhook(s, site_id, "https://1.1.1.1/x", ["zone.enter"], "")
            assert full.value.field == "url"
            with pytest.raises(NotFound):
                await webhooks.create_webhook(s, "0" * 32, "https://1.1.1.1/x", ["zone.enter"], "")


async def test_settled_deliveries_past_the_retention_are_purged(worker_settings: Settings) -> None:
    async with open_runtime(worker_settings) as rt:
        site_id = await _site(rt)
        hook_id = await _hook(rt, site_id, "http://127.0.0.1:9/a")
        await _owe(rt, site_id)
        await _owe(rt, site_id, {**ZONE_EVENT, "since": 1})
        old = utcnow() - timedelta(days=rt.settings.webhook_retention_days + 1)
        first = (await _deliveries(rt, hook_id))[0].id
        async with rt.transaction() as s:
            await s.execute(
                update(WebhookDelivery)
                .where(WebhookDelivery.webhook_id == hook_id)
                .values(created_at=old)
            )
            await s.execute(
                update(WebhookDelivery)
                .where(WebhookDelivery.id == first)
                .values(status="delivered")
            )
        assert await webhook_delivery.purge(rt) >= 1
        left = await _deliveries(rt, hook_id)
        assert [d.status for d in left] == ["pending"]  # a pending one stays, however old
