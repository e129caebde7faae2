"""Zone events end to end: a walker crossing a zone makes one ``enter`` and one ``exit``
(no flapping), pushed on the live socket and delivered, signed, to the site's webhooks;
a receiver that fails twice still gets each event once, later; one that always fails
shows its deliveries failed, with the error; a batch answered again owes nothing twice;
a session that ends inside a zone leaves it."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import json
import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from server.config import Settings
from tests.support.admin_key import ADMIN_KEY
from tests.support.live_server import serve
from tests.support.toy_site import build_toy_site, walk_batch
from tests.support.webhook_receiver import Receiver, webhook_receiver

ADMIN = {"Authorization": f"Bearer {ADMIN_KEY}"}
ATTEMPTS = 3
# the walk goes east along y = 5 from x = 2 to x = 16.5 (through the zone and out), then
# back west (walk_batch turns round at n = 30)
ZONE = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "id": "cafe",
            "feature_type": "geofence",
            "properties": {"name": {"en": "Café"}, "open": "9-17"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [[[7, 0], [12, 0], [12, 10], [7, 10], [7, 0]]],
            },
        },
        {"type": "Feature", "properties": {"kind": "walkable"}, "geometry": None},
    ],
}


@pytest.fixture(scope="module")
def zones_url(settings: Settings, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The server with its worker in process (what delivers webhooks), retrying fast, and
    allowed to send to loopback (where the receivers listen). Embedded, on a database of
    its own: the suite's other embedded servers run workers of their own on theirs, which
    would take these deliveries (and refuse loopback)."""
    fast = {"webhook_retry_s": 0.2, "webhook_poll_s": 0.05, "webhook_attempts": ATTEMPTS}
    local: dict[str, Any] = {"in_process_worker": True, "webhook_private_networks": True}
    if settings.database_url is None:
        local["data_dir"] = tmp_path_factory.mktemp("zones")
    yield from serve(settings.model_copy(update=fast | local))


def _signed_by(secret: str, headers: dict[str, str], body: bytes) -> bool:
    parts = dict(p.split("=", 1) for p in headers["x-indoorpos-signature"].split(","))
    mac = hmac.new(secret.encode(), f"{parts['t']}.".encode() + body, hashlib.sha256)
    fresh = abs(time.time() - int(parts["t"])) < 60
    return fresh and hmac.compare_digest(mac.hexdigest(), parts["v1"])


async def _hook(client: httpx.AsyncClient, site_id: str, receiver: Receiver) -> dict[str, Any]:
    r = await client.post(
        f"/v1/sites/{site_id}/webhooks", json={"url": receiver.url}, headers=ADMIN
    )
    assert r.status_code == 201, r.text
    created: dict[str, Any] = r.json()
    assert created["secret"].startswith("whsec_")
    assert created["events"] == [  # every kind of event unless told
        "navigation.arrived",
        "navigation.floor_change",
        "navigation.rerouted",
        "zone.enter",
        "zone.exit",
    ]
    return created


async def _until(check: Callable[[], bool], timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.05)


async def _zone_messages(ws: ClientConnection, sid: str) -> list[dict[str, Any]]:
    """The socket's zone events until the server closes it (the session ended)."""
    events = []
    with contextlib.suppress(ConnectionClosed):
        while True:
            message = json.loads(await asyncio.wait_for(ws.recv(), timeout=5))
            if message["type"] == "zone":
                assert message["session_id"] == sid
                events.append(message["event"])
    return events


async def test_a_walk_through_a_zone_enters_and_leaves_once_on_the_socket_and_webhooks(
    zones_url: str,
) -> None:
    async with httpx.AsyncClient(base_url=zones_url, timeout=30) as client:
        site = await build_toy_site(client, ADMIN)
        floor_id = site.floor_ids[0]
        r = await client.put(f"/v1/floors/{floor_id}/zones", json=ZONE, headers=ADMIN)
        assert r.status_code == 200, r.text
        assert [(f["id"], f["name"]) for f in r.json()["features"]] == [("cafe", "Café")]
        assert r.json()["skipped"] == 1
        with (
            webhook_receiver() as healthy,
            webhook_receiver(fail_first=2) as flaky,
            webhook_receiver(fail_first=-1) as broken,
        ):
            hooks = {
                "healthy": await _hook(client, site.site_id, healthy),
                "flaky": await _hook(client, site.site_id, flaky),
                "broken": await _hook(client, site.site_id, broken),
            }
            r = await client.post(
                "/v1/sessions", json={"site_id": site.site_id}, headers=site.device
            )
            assert r.status_code == 201, r.text
            sid, token = r.json()["id"], r.json()["token"]
            auth = {"Authorization": f"Bearer {token}"}
            url = f"/v1/sessions/{sid}/batches"
            ws_url = zones_url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"
            answered: list[tuple[int, dict[str, Any]]] = []  # (seq, fix)
            async with connect(ws_url, additional_headers=auth) as ws:
                assert json.loads(await ws.recv())["type"] == "ready"
                for n in range(60):  # east through the zone, then back into it
                    r = await client.post(
                        url, json={"seq": n + 1, "events": walk_batch(n)}, headers=auth
                    )
                    assert r.status_code == 200, r.text
                    fixes = r.json()["fixes"]
                    answered += [(n + 1, fix) for fix in fixes]
                    if any(e["type"] == "exit" for f in fixes for e in f["zone_events"]):
                        # sent again (its answer lost, say): the same answer, and its
                        # event is not owed twice
                        again = {"seq": n + 1, "events": walk_batch(n)}
                        r = await client.post(url, json=again, headers=auth)
                        assert r.status_code == 200, r.text
                        assert r.json()["replayed"] is True
                        assert r.json()["fixes"] == fixes
                    if n >= 30 and fixes and fixes[-1]["zones"] == ["cafe"]:
                        break
                made = [(seq, e) for seq, fix in answered for e in fix["zone_events"]]
                # ended inside the zone: it leaves
                r = await client.delete(f"/v1/sessions/{sid}", headers=auth)
                assert r.status_code == 204, r.text
                on_socket = await _zone_messages(ws, sid)

            in_fixes = [e for _, e in made]
            assert [(e["type"], e["reason"]) for e in on_socket] == [
                ("enter", "crossed"),
                ("exit", "crossed"),
                ("enter", "crossed"),
                ("exit", "session_ended"),
            ]
            assert on_socket[:3] == in_fixes
            enter, leave, back, ended = on_socket
            assert enter["zone_id"] == leave["zone_id"] == ended["zone_id"] == "cafe"
            assert enter["zone_name"] == "Café"
            assert enter["floor_id"] == floor_id
            assert enter["level"] == 0
            assert enter["since"] <= enter["t"] <= leave["since"] <= leave["t"]
            assert leave["dwell_s"] == pytest.approx((leave["since"] - enter["since"]) / 1000)
            assert enter["dwell_s"] is None
            assert ended["since"] == ended["t"] >= back["t"]
            assert ended["dwell_s"] == pytest.approx((ended["t"] - back["since"]) / 1000)
            # the fixes between an entry and its exit say the session is in the zone
            fixes = [fix for _, fix in answered]
            inside = [f["zones"] for f in fixes if enter["t"] <= f["t"] < leave["t"]]
            assert inside
            assert all(z == ["cafe"] for z in inside)
            assert all(f["zones"] == [] for f in fixes if f["t"] < enter["t"])

            await _until(lambda: len(healthy.accepted()) == 4 and len(flaky.accepted()) == 4)
            await _until(lambda: len(broken.received) == 4 * ATTEMPTS)
            await asyncio.sleep(0.5)  # nothing more comes
            for receiver, name in ((healthy, "healthy"), (flaky, "flaky")):
                got = receiver.accepted()
                assert len(got) == 4  # each event once
                assert sorted((g.json["type"], g.json["reason"]) for g in got) == [
                    ("zone.enter", "crossed"),
                    ("zone.enter", "crossed"),
                    ("zone.exit", "crossed"),
                    ("zone.exit", "session_ended"),
                ]
                for g in got:
                    assert _signed_by(hooks[name]["secret"], g.headers, g.body)
                    assert g.headers["x-indoorpos-event"] == g.json["type"]
                    assert g.headers["x-indoorpos-delivery"] == g.json["id"]
                    assert g.json["session_id"] == sid
                    assert g.json["zone"] == {
                        "id": "cafe",
                        "name": "Café",
                        "floor_id": floor_id,
                        "level": 0,
                    }
                    assert g.json["position"]["floor_id"] == floor_id
            # the flaky receiver saw each delivery three times: two refusals, then it
            for g in flaky.accepted():
                assert flaky.attempts_of(g.json["id"]) == 3
            assert len(broken.accepted()) == 0

            # what the operator sees
            r = await client.get(f"/v1/sites/{site.site_id}/webhooks", headers=ADMIN)
            assert r.status_code == 200, r.text
            listed = {h["url"]: h for h in r.json()["items"]}
            assert listed[healthy.url]["deliveries"] == {"delivered": 4}
            assert listed[flaky.url]["deliveries"] == {"delivered": 4}
            assert listed[flaky.url]["last_error"] == "HTTP 500"
            assert listed[broken.url]["deliveries"] == {"failed": 4}
            assert "secret" not in listed[broken.url]
            pages: list[dict[str, Any]] = []
            cursor = None
            while True:  # two to a page
                params: dict[str, Any] = {"status": "failed", "limit": 2}
                if cursor:
                    params["cursor"] = cursor
                r = await client.get(
                    f"/v1/sites/{site.site_id}/webhooks/{hooks['broken']['id']}/deliveries",
                    params=params,
                    headers=ADMIN,
                )
                assert r.status_code == 200, r.text
                pages += r.json()["items"]
                cursor = r.json()["next_cursor"]
                if cursor is None:
                    break
            assert len({d["id"] for d in pages}) == 4
            for delivery in pages:
                assert delivery["attempts"] == ATTEMPTS
                assert delivery["last_status_code"] == 500
                assert delivery["next_attempt_at"] is None
                assert delivery["payload"]["session_id"] == sid
