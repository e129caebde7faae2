"""Navigation of a session over the API: started from the latest fix, followed fix by
fix (the next instruction, the distance left, on or off the route), re-routed once after
a walk the wrong way, ended by one arrival; stopped; who may drive it."""

from __future__ import annotations

from typing import Any

import httpx
from fastapi import FastAPI

from tests.support.sessions import open_session, scan
from tests.support.toy_site import ToySite, build_toy_site, device_headers, linked_toy_plan

T0 = 1_700_000_000_000


async def _site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    site = await build_toy_site(client, admin)
    for floor_id in site.floor_ids.values():
        r = await client.put(f"/v1/floors/{floor_id}/plan", json=linked_toy_plan(), headers=admin)
        assert r.status_code in (200, 201), r.text
    return site


class Walker:
    """A session posting one scan a second (wknn: a fix at each scan's place)."""

    def __init__(self, client: httpx.AsyncClient, session_id: str, token: dict[str, str]):
        self.client, self.session_id, self.token = client, session_id, token
        self.seq = 0

    async def at(self, x: float, y: float, level: int = 0) -> dict[str, Any]:
        self.seq += 1
        t = T0 + 1000 * self.seq
        body = {"seq": self.seq, "events": [scan(t, x, y, level)]}
        r = await self.client.post(
            f"/v1/sessions/{self.session_id}/batches", json=body, headers=self.token
        )
        assert r.status_code == 200, r.text
        fixes: list[dict[str, Any]] = r.json()["fixes"]
        assert len(fixes) == 1
        return fixes[0]


async def test_a_walk_along_the_route_arrives_once(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await _site(client, admin)
    session_id, token = await open_session(client, site, engine="wknn")
    walker = Walker(client, session_id, token)
    first = await walker.at(3.0, 8.0)
    assert "navigation" not in first or first["navigation"] is None
    url = f"/v1/sessions/{session_id}/navigation"
    destination = {"floor_id": site.floor_ids[0], "x_m": 17.0, "y_m": 8.0}
    r = await client.put(url, json={"destination": destination}, headers=token)
    assert r.status_code == 200, r.text
    started = r.json()
    assert started["route"]["steps"][0]["kind"] == "start"
    assert started["navigation"]["status"] == "navigating"
    assert started["navigation"]["remaining_m"] > 10.0
    events: list[str] = []
    remaining = []
    fix: dict[str, Any] = {}
    for x in range(4, 20):
        fix = await walker.at(float(x), 8.0)
        if fix.get("navigation") is None:
            break
        nav = fix["navigation"]
        events += [e["type"] for e in nav["events"]]
        remaining.append(nav["remaining_m"])
        assert nav["on_route"]
        assert nav["instruction"]
    assert events == ["arrived"]
    assert remaining == sorted(remaining, reverse=True)  # nearer with every fix
    assert fix.get("navigation") is None  # navigation ended with the arrival
    r = await client.get(url, headers=token)
    assert r.status_code == 404, r.text


async def test_another_process_goes_on_with_the_navigation(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> None:
    """The navigation is in the session's snapshot and log: a process that did not write
    the session (its copy dropped) reads it from the store and goes on."""
    site = await _site(client, admin)
    session_id, token = await open_session(client, site, engine="wknn")
    walker = Walker(client, session_id, token)
    await walker.at(3.0, 8.0)
    destination = {"floor_id": site.floor_ids[0], "x_m": 17.0, "y_m": 8.0}
    r = await client.put(
        f"/v1/sessions/{session_id}/navigation", json={"destination": destination}, headers=token
    )
    assert r.status_code == 200, r.text
    remaining = []
    for x in (5.0, 7.0, 9.0):
        app.state.runtime.states.drop(session_id)  # as a replica that holds no copy
        nav = (await walker.at(x, 8.0))["navigation"]
        remaining.append(nav["remaining_m"])
    assert remaining == sorted(remaining, reverse=True)
    assert remaining[-1] < 10.0


async def test_a_wrong_turn_reroutes_once(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    site = await _site(client, admin)
    session_id, token = await open_session(client, site, engine="wknn")
    walker = Walker(client, session_id, token)
    await walker.at(10.0, 8.0)
    url = f"/v1/sessions/{session_id}/navigation"
    destination = {"floor_id": site.floor_ids[0], "x_m": 18.0, "y_m": 8.0}
    settings = {"off_route_m": 3.0, "reroute_after_s": 3.0}
    r = await client.put(url, json={"destination": destination, "settings": settings},
                         headers=token)  # fmt: skip
    assert r.status_code == 200, r.text
    events = []
    versions = []
    for x in (9.0, 8.0, 7.0, 5.0, 4.0, 3.0, 2.0, 2.0):  # west: away from the destination
        nav = (await walker.at(x, 8.0))["navigation"]
        events += [e["type"] for e in nav["events"]]
        versions.append(nav["route_version"])
    assert events == ["rerouted"]
    assert versions[-1] == 1
    r = await client.get(url, headers=token)
    assert r.status_code == 200, r.text
    assert r.json()["navigation"]["route_version"] == 1


async def test_who_may_drive_and_stopping(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    site = await _site(client, admin)
    session_id, token = await open_session(client, site, engine="wknn")
    walker = Walker(client, session_id, token)
    await walker.at(3.0, 8.0)
    url = f"/v1/sessions/{session_id}/navigation"
    body = {"destination": {"place": "Information desk"}}
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    r = await client.put(url, json=body, headers=viewer)
    assert r.status_code == 403, r.text
    other_id, other_token = await open_session(client, site, engine="wknn")
    r = await client.put(url, json=body, headers=other_token)
    assert r.status_code == 403, r.text
    r = await client.put(url, json=body, headers=admin)  # an admin key of the site may
    assert r.status_code == 200, r.text
    assert r.json()["route"]["destination"]["name"] == "Information desk"
    r = await client.get(url, headers=viewer)  # a viewer reads
    assert r.status_code == 200, r.text
    fix = await walker.at(4.0, 8.0)
    assert fix["navigation"]["destination"]["name"] == "Information desk"
    r = await client.delete(url, headers=token)
    assert r.status_code == 204, r.text
    fix = await walker.at(5.0, 8.0)
    assert fix.get("navigation") is None
    # a session without a fix has nowhere to start from
    r = await client.put(f"/v1/sessions/{other_id}/navigation", json=body, headers=other_token)
    assert r.status_code == 404, r.text
    assert r.json()["message"].startswith("session"), r.text
