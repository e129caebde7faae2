"""A whole session run against ``indoorpos serve`` (its own process, access log on, INFO):
no session token and no admin key appears in anything it logged, in either log format."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from websockets.asyncio.client import connect

from tests.support.toy_site import build_toy_site, rssi_at

T0 = 1_700_000_000_000
ADMIN_KEY = "admin-key-that-must-not-be-logged"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def _session_run(base: str) -> list[str]:
    """Everything a phone and an operator do in one session; the secrets it used."""
    admin = {"Authorization": f"Bearer {ADMIN_KEY}"}
    ws_base = base.replace("http", "ws", 1)
    async with httpx.AsyncClient(base_url=base, timeout=30) as client:
        site = await build_toy_site(client, admin)
        r = await client.post("/v1/sessions", json={"site_id": site.site_id}, headers=site.device)
        assert r.status_code == 201, r.text
        sid, token = r.json()["id"], r.json()["token"]
        auth = {"Authorization": f"Bearer {token}"}
        live = f"{ws_base}/v1/sessions/{sid}/live"
        async with connect(live, additional_headers=auth) as ws:
            assert json.loads(await ws.recv())["type"] == "ready"
            batch = {"seq": 1, "events": [{"type": "wifi", "t": T0, "readings": rssi_at(4, 4, 0)}]}
            r = await client.post(f"/v1/sessions/{sid}/batches", json=batch, headers=auth)
            assert r.status_code == 200, r.text
            assert json.loads(await ws.recv())["type"] == "fix"
        async with connect(live) as ws:  # a browser's way
            await ws.send(json.dumps({"type": "auth", "token": token}))
            assert json.loads(await ws.recv())["type"] == "ready"
        # the deprecated way: accepted here (the server runs with it on), scrubbed from logs
        async with connect(f"{live}?token={token}") as ws:
            assert json.loads(await ws.recv())["type"] == "ready"
        # a careless client puts the admin key in a query: refused, and not logged either
        r = await client.get(f"/v1/sites?key={ADMIN_KEY}")
        assert r.status_code == 401
        assert (await client.get(f"/v1/sessions/{sid}", headers=auth)).status_code == 200
        assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    device_key = site.device["Authorization"].split()[1]
    return [token, ADMIN_KEY, device_key]


@pytest.mark.parametrize("log_format", ["text", "json"])
def test_no_token_or_key_in_the_logs_of_a_session_run(tmp_path: Path, log_format: str) -> None:
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")} | {
        "INDOORPOS_DATA_DIR": str(tmp_path),
        "INDOORPOS_ADMIN_KEY": ADMIN_KEY,
        "INDOORPOS_LOG_FORMAT": log_format,
        "INDOORPOS_LOG_LEVEL": "DEBUG",
        "INDOORPOS_LIVE_QUERY_TOKEN": "1",
    }
    log_path = tmp_path / "server.log"
    with log_path.open("w") as log:
        server = subprocess.Popen(
            [str(Path(sys.executable).parent / "indoorpos"), "serve", "--port", str(port)],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            base = f"http://127.0.0.1:{port}"
            deadline = time.monotonic() + 60
            while True:
                assert server.poll() is None, log_path.read_text()
                try:
                    if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                assert time.monotonic() < deadline, "server did not start"
                time.sleep(0.2)
            secrets = asyncio.run(_session_run(base))
        finally:
            server.terminate()
            server.wait(timeout=30)
    text = log_path.read_text()
    assert "WebSocket /v1/sessions/" in text, text  # the socket lines were logged...
    assert "token=[redacted]" in text  # ...with the query scrubbed
    for secret in secrets:
        assert secret not in text
