"""The live socket pushes every fix of its session, only to that session's token and to
keys that may view its site; a key that stops working (revoked or rotated) closes the
sockets it opened (an error, then 4401) within a second, on every replica."""

from __future__ import annotations

import asyncio
import json
import time
from contextlib import AsyncExitStack
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from tests.support.admin_key import ADMIN_KEY
from tests.support.toy_site import ToySite, build_toy_site, device_headers, new_key, rssi_at

T0 = 1_700_000_000_000
ADMIN = {"Authorization": f"Bearer {ADMIN_KEY}"}
CLOSE_WITHIN_S = 1.0


async def _session(client: httpx.AsyncClient, site: ToySite) -> tuple[str, str]:
    r = await client.post("/v1/sessions", json={"site_id": site.site_id}, headers=site.device)
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


async def _recv(ws: ClientConnection) -> dict[str, Any]:
    message: dict[str, Any] = json.loads(await asyncio.wait_for(ws.recv(), timeout=5))
    return message


def _ws_url(live_url: str, sid: str) -> str:
    return live_url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"


async def _closed_with(ws: ClientConnection, code: int) -> None:
    with pytest.raises(ConnectionClosed) as closed:
        await asyncio.wait_for(ws.recv(), timeout=5)
    assert closed.value.rcvd is not None
    assert closed.value.rcvd.code == code


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


async def test_fixes_posted_over_http_arrive_on_the_socket(live_url: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid, token = await _session(client, site)
        async with connect(_ws_url(live_url, sid), additional_headers=_bearer(token)) as ws:
            assert (await _recv(ws))["type"] == "ready"
            batch = {
                "seq": 1,
                "events": [
                    {"type": "wifi", "t": T0, "readings": rssi_at(4, 4, 0)},
                    {"type": "step", "t": T0 + 600, "length_m": 0.7, "heading_rad": 0.0},
                ],
            }
            r = await client.post(
                f"/v1/sessions/{sid}/batches",
                json=batch,
                headers={"Authorization": f"Bearer {token}"},
            )
            assert r.status_code == 200, r.text
            fixes = r.json()["fixes"]
            assert len(fixes) == 2
            pushed = [await _recv(ws) for _ in fixes]
            assert [m["type"] for m in pushed] == ["fix", "fix"]
            assert [m["seq"] for m in pushed] == [1, 1]
            assert [m["fix"] for m in pushed] == fixes

            # a batch sent over the socket gets its result there, and its fix is pushed too
            await ws.send(
                json.dumps(
                    {
                        "type": "batch",
                        "seq": 2,
                        "events": [
                            {"type": "step", "t": T0 + 1200, "length_m": 0.7, "heading_rad": 0.0}
                        ],
                    }
                )
            )
            got = [await _recv(ws), await _recv(ws)]
            kinds = sorted(m["type"] for m in got)
            assert kinds == ["batch_result", "fix"]
            result = next(m for m in got if m["type"] == "batch_result")
            assert result["seq"] == 2
            assert len(result["fixes"]) == 1

            # invalid input over the socket is an error message, the socket stays open
            await ws.send(json.dumps({"type": "batch", "seq": 4, "events": [{"type": "step"}]}))
            err = await _recv(ws)
            assert err["type"] == "error"
            assert err["status"] == 422
            assert "events.0.t" in err["message"]

            # a binary frame is read as UTF-8 text, like a text frame
            await ws.send(
                json.dumps(
                    {
                        "type": "batch",
                        "seq": 3,
                        "events": [
                            {"type": "step", "t": T0 + 1800, "length_m": 0.7, "heading_rad": 0.0}
                        ],
                    }
                ).encode()
            )
            got = [await _recv(ws), await _recv(ws)]
            assert sorted(m["type"] for m in got) == ["batch_result", "fix"]

            # ending the session closes the socket
            r = await client.delete(
                f"/v1/sessions/{sid}", headers={"Authorization": f"Bearer {token}"}
            )
            assert r.status_code == 204
            with pytest.raises(ConnectionClosed):
                await asyncio.wait_for(ws.recv(), timeout=5)


async def test_socket_refuses_another_sessions_token(live_url: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid_a, _ = await _session(client, site)
        _, token_b = await _session(client, site)
        async with connect(_ws_url(live_url, sid_a)) as ws:
            # a browser's way: the token as the first message
            await ws.send(json.dumps({"type": "auth", "token": token_b}))
            err = await _recv(ws)
            assert err["type"] == "error"
            assert err["status"] == 403
            await _closed_with(ws, 4403)


async def test_a_browser_authenticates_with_its_first_message(live_url: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid, token = await _session(client, site)
        async with connect(_ws_url(live_url, sid)) as ws:
            await ws.send(json.dumps({"type": "auth", "token": token}))
            assert (await _recv(ws))["type"] == "ready"


@pytest.mark.parametrize("first", ['{"type": "batch", "seq": 1, "events": []}', "not json"])
async def test_a_socket_without_credentials_is_closed(live_url: str, first: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid, _ = await _session(client, site)
        async with connect(_ws_url(live_url, sid)) as ws:
            await ws.send(first)
            err = await _recv(ws)
            assert err["status"] == 401
            assert err["message"].startswith("token: ")
            await _closed_with(ws, 4401)


async def test_a_token_in_the_url_is_refused(live_url: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid, token = await _session(client, site)
        async with connect(_ws_url(live_url, sid) + f"?token={token}") as ws:
            err = await _recv(ws)
            assert err["status"] == 401
            assert "URL" in err["message"]


async def test_a_viewer_key_of_the_site_follows_a_session(live_url: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid, token = await _session(client, site)
        viewer = await device_headers(client, ADMIN, ("viewer",), site.site_id)
        async with connect(_ws_url(live_url, sid), additional_headers=viewer) as ws:
            assert (await _recv(ws))["type"] == "ready"
            batch = {
                "seq": 1,
                "events": [
                    {"type": "wifi", "t": T0, "readings": rssi_at(4, 4, 0)},
                    {"type": "step", "t": T0 + 600, "length_m": 0.7, "heading_rad": 0.0},
                ],
            }
            r = await client.post(f"/v1/sessions/{sid}/batches", json=batch, headers=_bearer(token))
            assert r.status_code == 200, r.text
            fixes = r.json()["fixes"]
            assert [(await _recv(ws))["fix"] for _ in fixes] == fixes
            # the key follows; it does not send batches (the socket stays open)
            await ws.send(json.dumps({**batch, "type": "batch", "seq": 2}))
            err = await _recv(ws)
            assert (err["type"], err["status"], err["seq"]) == ("error", 403, 2)
            assert err["message"].startswith("authorization: ")
            r = await client.get(f"/v1/sessions/{sid}", headers=_bearer(token))
            assert r.json()["last_seq"] == 1
            # an admin key follows too, authenticating as a browser does
            async with connect(_ws_url(live_url, sid)) as admin_ws:
                await admin_ws.send(json.dumps({"type": "auth", "token": ADMIN_KEY}))
                assert (await _recv(admin_ws))["type"] == "ready"
            # the session's end closes the follower's socket
            r = await client.delete(f"/v1/sessions/{sid}", headers=_bearer(token))
            assert r.status_code == 204
            with pytest.raises(ConnectionClosed):
                await asyncio.wait_for(ws.recv(), timeout=5)


@pytest.mark.parametrize("scopes", [("device",), ("viewer",)])
async def test_keys_that_may_not_view_the_site_are_refused(
    live_url: str, scopes: tuple[str, ...]
) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, ADMIN)
        other = await build_toy_site(client, ADMIN)
        sid, _ = await _session(client, site)
        # a device key of the site itself: refused (403); a viewer key of another site
        # hears of the session what it hears of one that does not exist (404)
        key_site = site.site_id if scopes == ("device",) else other.site_id
        key = await device_headers(client, ADMIN, scopes, key_site)
        status, close_code = (403, 4403) if scopes == ("device",) else (404, 4404)
        answers = []
        for session_id in (sid, "0" * 32):
            async with connect(_ws_url(live_url, session_id), additional_headers=key) as ws:
                err = await _recv(ws)
                assert err["status"] == status, err
                await _closed_with(ws, close_code)
                answers.append(json.dumps(err).replace(session_id, "<id>"))
        assert answers[0] == answers[1]


async def _stop_key(client: httpx.AsyncClient, key_id: str, how: str) -> str | None:
    """Revoke or rotate key ``key_id``; the new secret of a rotated one."""
    if how == "revoke":
        r = await client.delete(f"/v1/keys/{key_id}", headers=ADMIN)
        assert r.status_code == 204, r.text
        return None
    r = await client.post(f"/v1/keys/{key_id}:rotate", headers=ADMIN)
    assert r.status_code == 200, r.text
    return str(r.json()["key"])


async def _closed_for_the_key(ws: ClientConnection, within_s: float) -> None:
    """``ws`` is told its key stopped working and closed with 4401 within ``within_s``."""
    start = time.monotonic()
    err = await _recv(ws)
    assert (err["type"], err["status"]) == ("error", 401), err
    with pytest.raises(ConnectionClosed) as closed:
        await asyncio.wait_for(ws.recv(), timeout=within_s)
    assert closed.value.rcvd is not None
    assert closed.value.rcvd.code == 4401
    assert time.monotonic() - start < within_s


@pytest.mark.parametrize("how", ["revoke", "rotate"])
async def test_a_key_stopped_on_another_replica_closes_its_socket(
    live_url: str, replica_url: str, how: str
) -> None:
    """A socket on replica A, its key revoked (or rotated) through replica B: A closes it
    within a second; the session's own socket on A stays."""
    async with (
        httpx.AsyncClient(base_url=live_url) as a,
        httpx.AsyncClient(base_url=replica_url) as b,
    ):
        site = await build_toy_site(a, ADMIN)
        sid, token = await _session(a, site)
        key_id, secret = await new_key(a, ADMIN, ("viewer",), site.site_id)
        url = _ws_url(live_url, sid)
        async with (
            connect(url, additional_headers=_bearer(secret)) as viewer,
            connect(url, additional_headers=_bearer(token)) as own,
        ):
            assert (await _recv(viewer))["type"] == "ready"
            assert (await _recv(own))["type"] == "ready"
            await _stop_key(b, key_id, how)
            await _closed_for_the_key(viewer, within_s=1.0)
            batch = {"seq": 1, "events": [{"type": "wifi", "t": T0, "readings": rssi_at(4, 4, 0)}]}
            r = await b.post(f"/v1/sessions/{sid}/batches", json=batch, headers=_bearer(token))
            assert r.status_code == 200, r.text
            assert [(await _recv(own))["fix"] for _ in r.json()["fixes"]] == r.json()["fixes"]


async def test_a_revoked_key_closes_its_socket_on_a_redis_cluster(cluster_live_url: str) -> None:
    async with httpx.AsyncClient(base_url=cluster_live_url) as client:
        site = await build_toy_site(client, ADMIN)
        sid, _ = await _session(client, site)
        key_id, secret = await new_key(client, ADMIN, ("viewer",), site.site_id)
        url = _ws_url(cluster_live_url, sid)
        async with connect(url, additional_headers=_bearer(secret)) as viewer:
            assert (await _recv(viewer))["type"] == "ready"
            r = await client.delete(f"/v1/keys/{key_id}", headers=ADMIN)
            assert r.status_code == 204, r.text
            await _closed_for_the_key(viewer, within_s=1.0)


async def _follow(stack: AsyncExitStack, url: str, sid: str, secret: str) -> ClientConnection:
    """A socket on session ``sid`` opened with ``secret``, once it is ready."""
    ws_url = url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"
    ws = await stack.enter_async_context(connect(ws_url, additional_headers=_bearer(secret)))
    assert (await _recv(ws))["type"] == "ready"
    return ws


async def _closed_since(ws: ClientConnection, since: float) -> float:
    """Seconds from ``since`` until ``ws`` was told its key stopped working and closed
    with 4401 (fixes still on their way may come first)."""
    message = await _recv(ws)
    while message["type"] == "fix":
        message = await _recv(ws)
    assert (message["type"], message["status"]) == ("error", 401), message
    assert message["message"].startswith("authorization: ")
    with pytest.raises(ConnectionClosed) as closed:
        await asyncio.wait_for(ws.recv(), CLOSE_WITHIN_S)
    took = time.monotonic() - since
    assert closed.value.rcvd is not None
    assert closed.value.rcvd.code == 4401
    return took


async def _post_step(client: httpx.AsyncClient, sid: str, token: str, seq: int) -> list[Any]:
    events: list[dict[str, Any]] = [
        {"type": "step", "t": T0 + 600 * seq, "length_m": 0.7, "heading_rad": 0.0}
    ]
    if seq == 1:
        events.insert(0, {"type": "wifi", "t": T0, "readings": rssi_at(4, 4, 0)})
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": events}, headers=_bearer(token)
    )
    assert r.status_code == 200, r.text
    fixes: list[Any] = r.json()["fixes"]
    assert fixes
    return fixes


async def _fixes(ws: ClientConnection, count: int) -> list[Any]:
    return [(await _recv(ws))["fix"] for _ in range(count)]


@pytest.mark.parametrize("how", ["revoke", "rotate"])
async def test_a_key_that_stops_working_closes_its_sockets_only(live_url: str, how: str) -> None:
    async with httpx.AsyncClient(base_url=live_url) as client, AsyncExitStack() as stack:
        site = await build_toy_site(client, ADMIN)
        r = await client.post("/v1/sessions", json={"site_id": site.site_id}, headers=site.device)
        assert r.status_code == 201, r.text
        sid, token = r.json()["id"], r.json()["token"]
        key_id, secret = await new_key(client, ADMIN, ("viewer",), site.site_id)
        _, other_secret = await new_key(client, ADMIN, ("viewer",), site.site_id)
        doomed = [await _follow(stack, live_url, sid, secret) for _ in range(2)]
        kept = [
            await _follow(stack, live_url, sid, token),  # the session's own token
            await _follow(stack, live_url, sid, other_secret),  # another key
            await _follow(stack, live_url, sid, ADMIN_KEY),  # the configured admin key
        ]
        fixes = await _post_step(client, sid, token, 1)
        for ws in doomed + kept:
            assert await _fixes(ws, len(fixes)) == fixes

        new_secret = await _stop_key(client, key_id, how)
        if new_secret is not None:  # a socket of the new secret is no socket of the old one
            kept.append(await _follow(stack, live_url, sid, new_secret))
        answered = time.monotonic()
        for ws in doomed:
            took = await _closed_since(ws, answered)
            assert took < CLOSE_WITHIN_S, f"closed {took:.3f} s after the answer"

        fixes = await _post_step(client, sid, token, 2)
        for ws in kept:
            assert await _fixes(ws, len(fixes)) == fixes
