"""Credentials before the body (``server.api.gated_route``), on a real server: a client
declares a large body, sends only its first bytes and waits; every route with a body
answers it, from the headers alone, 401 for a wrong key and 403 for a key without the
route's scope (or a token of no session), and the body is never read."""

from __future__ import annotations

import http.client
import re
import socket
import statistics
import time
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest

from server.api.body_limit import BULK_PATHS

BULK_BYTES = 30 * 1024 * 1024
DEVICE_BYTES = 1024 * 1024  # under the device routes' limit: their gate, not their size
SENT = b'{"points": [' + b" " * 4096  # the only part of the body that is ever sent


@pytest.fixture
def ids(live_url: str, admin: dict[str, str]) -> dict[str, str]:
    with httpx.Client(base_url=live_url, headers=admin) as c:
        site = c.post("/v1/sites", json={"name": "gated"}).json()["id"]
        building = c.post(f"/v1/sites/{site}/buildings", json={"name": "B"}).json()["id"]
        floor = c.post(f"/v1/buildings/{building}/floors", json={"level": 0}).json()["id"]
    return {
        "site_id": site,
        "building_id": building,
        "floor_id": floor,
        "session_id": "ab" * 16,
        "key_id": "cd" * 16,
        "version": "1",
        "name": "wknn",
    }


def _key(live_url: str, admin: dict[str, str], scopes: list[str]) -> str:
    r = httpx.post(f"{live_url}/v1/keys", json={"name": "t", "scopes": scopes}, headers=admin)
    assert r.status_code == 201, r.text
    return str(r.json()["key"])


def _body_routes(live_url: str) -> list[tuple[str, str]]:
    document = httpx.get(f"{live_url}/openapi.json").json()
    return [
        (method.upper(), path)
        for path, methods in document["paths"].items()
        for method, operation in methods.items()
        if "requestBody" in operation
    ]


def _ask(
    live_url: str, method: str, path: str, bearer: str, declared: int
) -> tuple[int, Any, float]:
    """Send a request's headers and the first bytes of a ``declared``-byte body, never the
    rest; the answer's status, body and seconds from the first byte sent."""
    where = urlsplit(live_url)
    head = (
        f"{method} {path} HTTP/1.1\r\nHost: {where.netloc}\r\n"
        f"Authorization: Bearer {bearer}\r\nContent-Type: application/json\r\n"
        f"Content-Length: {declared}\r\n\r\n"
    ).encode()
    with socket.create_connection((where.hostname, where.port), timeout=10) as sock:
        start = time.perf_counter()
        sock.sendall(head + SENT)
        answer = b""
        while b"\r\n\r\n" not in answer or not _whole(answer):
            chunk = sock.recv(65536)
            assert chunk, f"{method} {path}: closed without an answer"
            answer += chunk
        elapsed = time.perf_counter() - start
    head_part, _, body = answer.partition(b"\r\n\r\n")
    status = int(head_part.split(b" ", 2)[1])
    return status, httpx.Response(status, content=body).json(), elapsed


VIEWER_QUERIES = {("POST", "/v1/sites/{site_id}/routes")}
"""Routes with a body that a viewer key may call: a key without the scope is refused."""


def _whole(answer: bytes) -> bool:
    head, _, body = answer.partition(b"\r\n\r\n")
    length = re.search(rb"(?i)content-length: *(\d+)", head)
    return length is not None and len(body) >= int(length[1])


def test_every_route_with_a_body_checks_the_key_before_reading_it(
    live_url: str, admin: dict[str, str], ids: dict[str, str]
) -> None:
    routes = _body_routes(live_url)
    assert len(routes) >= 12
    bulk = [r for r in routes if BULK_PATHS.match(r[1].split("?")[0])]
    assert len(bulk) == 4  # uploads, the radio survey, the magnetic survey, the plan
    viewer = _key(live_url, admin, ["viewer"])
    device = _key(live_url, admin, ["device"])  # for the queries a viewer may send
    times = []
    for method, template in routes:
        path = re.sub(r"\{(\w+)\}", lambda m: ids[str(m[1])], template)
        if template == "/v1/uploads":
            path += f"?site_id={ids['site_id']}"
        declared = BULK_BYTES if (method, template) in bulk else DEVICE_BYTES
        token_route = "{session_id}" in template  # a session's own token, not a key
        lacking = device if (method, template) in VIEWER_QUERIES else viewer
        for bearer, status in (("ipk_not-a-key", 401), (lacking, 403)):
            if token_route:
                status = 403  # one answer for any token that opens no live session
            got, body, elapsed = _ask(live_url, method, path, bearer, declared)
            assert got == status, (method, template, bearer[:4], body)
            assert body["detail"][0]["loc"] == ["authorization"], (method, template, body)
            times.append(elapsed)
    # answered from the headers: nothing waits for the 30 MB that never come
    assert statistics.median(times) < 0.2, times
    assert max(times) < 1.0, times


def test_a_client_that_sends_its_whole_body_before_reading_gets_the_answer(
    live_url: str, ids: dict[str, str]
) -> None:
    # Python's http.client (as many phone stacks) writes the whole body, then reads: the
    # server answered from the headers long before, and drained the rest instead of
    # resetting the connection under it
    where = urlsplit(live_url)
    conn = http.client.HTTPConnection(where.hostname or "", where.port, timeout=30)
    body = b'{"points": [' + b" " * (16 * 1024 * 1024) + b"]}"
    headers = {"Authorization": "Bearer ipk_not-a-key", "Content-Type": "application/json"}
    conn.request("PUT", f"/v1/floors/{ids['floor_id']}/plan", body=body, headers=headers)
    answer = conn.getresponse()
    assert answer.status == 401
    assert (
        httpx.Response(401, content=answer.read()).json()["message"].startswith("authorization: ")
    )
    conn.close()
