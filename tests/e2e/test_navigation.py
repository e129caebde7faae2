"""Navigation end to end: a walker given a destination on the floor above follows the
steps (up the stairs) and arrives with one ``arrived`` event; a walker that turns the
wrong way, wobbling, is re-routed once and then arrives; the events go out on the live
socket and, signed, to a webhook receiver the test starts."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import numpy as np
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from server.config import Settings
from tests.support.admin_key import ADMIN_KEY
from tests.support.live_server import serve
from tests.support.sessions import scan
from tests.support.toy_site import ToySite, build_toy_site, linked_toy_plan
from tests.support.webhook_receiver import webhook_receiver

ADMIN = {"Authorization": f"Bearer {ADMIN_KEY}"}
T0 = 1_700_000_000_000
SPEED_M_S = 1.2


@pytest.fixture(scope="module")
def nav_url(settings: Settings, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The server with its worker in process (what delivers webhooks), allowed to send to
    loopback; embedded on a database of its own (as the zone events' test)."""
    local: dict[str, Any] = {
        "in_process_worker": True,
        "webhook_private_networks": True,
        "webhook_retry_s": 0.2,
        "webhook_poll_s": 0.05,
    }
    if settings.database_url is None:
        local["data_dir"] = tmp_path_factory.mktemp("navigation")
    yield from serve(settings.model_copy(update=local))


def _along(route: dict[str, Any], walked_m: float) -> tuple[int, float, float]:
    """Where a walker is after ``walked_m`` along a route (the level, x, y)."""
    for leg in route["legs"]:
        xy = np.array(leg["geometry"]["coordinates"])
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        if walked_m <= seg.sum() or leg is route["legs"][-1]:
            k = int(np.searchsorted(np.cumsum(seg), walked_m)) if seg.size else 0
            k = min(k, max(0, seg.size - 1))
            start = float(np.sum(seg[:k]))
            t = 0.0 if seg.size == 0 or seg[k] == 0 else min(1.0, (walked_m - start) / seg[k])
            p = xy[k] + t * (xy[min(k + 1, len(xy) - 1)] - xy[k])
            return int(leg["level"]), float(p[0]), float(p[1])
        walked_m -= float(seg.sum())
    raise AssertionError("unreachable")


class Walker:
    def __init__(self, client: httpx.AsyncClient, site: ToySite, sid: str, token: str):
        self.client, self.site, self.sid = client, site, sid
        self.auth = {"Authorization": f"Bearer {token}"}
        self.seq = 0
        self.rng = np.random.default_rng(7)

    async def at(self, level: int, x: float, y: float) -> dict[str, Any]:
        """One second later, a scan at (x, y) (wobbling 0.3 m): the fix it makes."""
        self.seq += 1
        x += float(self.rng.normal(0, 0.3))
        y += float(self.rng.normal(0, 0.3))
        body = {"seq": self.seq, "events": [scan(T0 + 1000 * self.seq, x, y, level)]}
        r = await self.client.post(f"/v1/sessions/{self.sid}/batches", json=body, headers=self.auth)
        assert r.status_code == 200, r.text
        fix: dict[str, Any] = r.json()["fixes"][-1]
        return fix

    async def follow(self, route: dict[str, Any], limit: int = 60) -> list[dict[str, Any]]:
        """Walk the route at walking speed until navigation ends; the fixes' events."""
        events: list[dict[str, Any]] = []
        for k in range(1, limit):
            level, x, y = _along(route, SPEED_M_S * k)
            nav = (await self.at(level, x, y)).get("navigation")
            if nav is None:
                return events
            events += nav["events"]
            if nav["status"] == "arrived":
                return events
        raise AssertionError("never arrived")


async def _open(client: httpx.AsyncClient, site: ToySite) -> tuple[str, str]:
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, "engine": "wknn"}, headers=site.device
    )
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


async def _socket_events(ws: ClientConnection, sid: str) -> list[dict[str, Any]]:
    """The socket's navigation events until the server closes it (the session ended)."""
    events = []
    with contextlib.suppress(ConnectionClosed):
        while True:
            message = json.loads(await asyncio.wait_for(ws.recv(), timeout=5))
            if message["type"] == "navigation":
                assert message["session_id"] == sid
                events.append(message["event"])
    return events


async def _until(check: Callable[[], bool], timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.05)


async def test_walkers_follow_the_steps_and_arrive_once_rerouted_once(nav_url: str) -> None:
    async with httpx.AsyncClient(base_url=nav_url, timeout=30) as client:
        site = await build_toy_site(client, ADMIN)
        for floor_id in site.floor_ids.values():
            r = await client.put(
                f"/v1/floors/{floor_id}/plan", json=linked_toy_plan(), headers=ADMIN
            )
            assert r.status_code in (200, 201), r.text
        with webhook_receiver() as receiver:
            r = await client.post(
                f"/v1/sites/{site.site_id}/webhooks", json={"url": receiver.url}, headers=ADMIN
            )
            assert r.status_code == 201, r.text
            destination = {"floor_id": site.floor_ids[1], "x_m": 12.0, "y_m": 8.0}

            # one walker follows the steps: up the stairs to the floor above
            sid, token = await _open(client, site)
            walker = Walker(client, site, sid, token)
            ws_url = nav_url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"
            async with connect(ws_url, additional_headers=walker.auth) as ws:
                assert json.loads(await ws.recv())["type"] == "ready"
                await walker.at(0, 10.0, 2.0)
                r = await client.put(
                    f"/v1/sessions/{sid}/navigation",
                    json={"destination": destination},
                    headers=walker.auth,
                )
                assert r.status_code == 200, r.text
                route = r.json()["route"]
                kinds = [s["kind"] for s in route["steps"]]
                assert "stairs_up" in kinds
                events = await walker.follow(route)
                r = await client.delete(f"/v1/sessions/{sid}", headers=walker.auth)
                assert r.status_code == 204, r.text
                on_socket = await _socket_events(ws, sid)
            assert [e["type"] for e in events] == ["floor_change", "arrived"]
            assert events[0]["kind"] == "stairs"
            assert (events[0]["from_level"], events[0]["to_level"]) == (0, 1)
            assert on_socket == events

            # another turns the wrong way (west, wobbling), is re-routed once, then arrives
            sid2, token2 = await _open(client, site)
            lost = Walker(client, site, sid2, token2)
            await lost.at(0, 12.0, 2.0)
            r = await client.put(
                f"/v1/sessions/{sid2}/navigation",
                json={"destination": destination, "settings": {"off_route_m": 3.0}},
                headers=lost.auth,
            )
            assert r.status_code == 200, r.text
            made: list[dict[str, Any]] = []
            for x in (11.0, 10.0, 9.0, 8.0, 7.0, 6.0, 5.0, 4.0, 3.0):
                made += (await lost.at(0, x, 2.0))["navigation"]["events"]
            assert [e["type"] for e in made] == ["rerouted"]
            r = await client.get(f"/v1/sessions/{sid2}/navigation", headers=lost.auth)
            assert r.status_code == 200, r.text
            assert r.json()["navigation"]["route_version"] == 1
            new_route = r.json()["route"]
            assert new_route["origin"]["x_m"] < 6.0  # from where the walker went
            made += await lost.follow(new_route)
            assert [e["type"] for e in made] == ["rerouted", "floor_change", "arrived"]

            expected = 2 + 3
            await _until(lambda: len(receiver.accepted()) >= expected)
            await asyncio.sleep(0.3)  # nothing more comes
            got = receiver.accepted()
            assert len(got) == expected
            by_session = {
                s: sorted(g.json["type"] for g in got if g.json["session_id"] == s)
                for s in (sid, sid2)
            }
            assert by_session == {
                sid: ["navigation.arrived", "navigation.floor_change"],
                sid2: ["navigation.arrived", "navigation.floor_change", "navigation.rerouted"],
            }
            arrived = next(g.json for g in got if g.json["type"] == "navigation.arrived")
            assert arrived["navigation"]["type"] == "arrived"
            assert arrived["position"]["level"] == 1
