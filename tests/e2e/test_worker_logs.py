"""The upload worker logs at INFO each upload it takes and how it settles: folded (with the
map versions it made), rejected (with the reason), retried after an attempt that raised,
and failed once it is out of attempts.

An embedded service of its own (SQLite in a temporary directory, the in-process worker
and queue) with a short visibility timeout, so a failed attempt comes back quickly.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager
from pydantic import SecretStr

from server.app import create_app
from server.config import Settings
from server.positioning.mapping.walk_contribution import Contribution
from server.services import upload_contribution
from server.storage import db
from tests.support.admin_key import ADMIN_KEY

ADMIN = {"Authorization": f"Bearer {ADMIN_KEY}"}
VISIBILITY_S = 0.3
SETTLE_TIMEOUT_S = 30.0
T0_MS = 1_700_000_000_000
AP_XY = [(0.0, 0.0), (20.0, 0.0), (0.0, 10.0), (20.0, 10.0), (10.0, 5.0)]


@pytest.fixture
def embedded(tmp_path: Path) -> Settings:
    """Settings of an embedded service of this test's own, its database migrated."""
    settings = Settings(
        data_dir=tmp_path,
        database_url=None,
        redis_url=None,
        admin_key=SecretStr(ADMIN_KEY),
        rate_limits=False,
        upload_visibility_s=VISIBILITY_S,
        in_process_worker=True,
    )
    db.migrate(settings.resolved_database_url)
    return settings


@pytest.fixture
async def client(embedded: Settings) -> AsyncIterator[httpx.AsyncClient]:
    app = create_app(embedded)
    async with LifespanManager(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
            yield c


async def _site(client: httpx.AsyncClient) -> str:
    """A site with one building and its ground floor (level 0)."""
    r = await client.post("/v1/sites", json={"name": "logged"}, headers=ADMIN)
    site_id: str = r.json()["id"]
    r = await client.post(f"/v1/sites/{site_id}/buildings", json={"name": "b"}, headers=ADMIN)
    r = await client.post(
        f"/v1/buildings/{r.json()['id']}/floors", json={"level": 0}, headers=ADMIN
    )
    assert r.status_code == 201, r.text
    return site_id


def _walk() -> dict[str, Any]:
    """Our own events: a walk east along y = 5 m from x = 2 m to 18 m in 16 s, a WiFi scan
    each second, its two ends given as anchors."""
    events = []
    for k in range(17):
        x = 2.0 + k
        readings = [
            {
                "bssid": f"02:00:00:00:00:{i:02x}",
                "rssi_dbm": -40.0 - 25.0 * math.log10(max(math.hypot(x - ax, 5.0 - ay), 1.0)),
            }
            for i, (ax, ay) in enumerate(AP_XY)
        ]
        events.append({"type": "wifi", "t": T0_MS + 1000 * k, "readings": readings})
    anchors = [
        {"t": T0_MS, "x_m": 2.0, "y_m": 5.0},
        {"t": T0_MS + 16_000, "x_m": 18.0, "y_m": 5.0},
    ]
    return {"events": events, "anchors": anchors}


async def _upload(client: httpx.AsyncClient, site_id: str, floor: int) -> str:
    r = await client.post(
        "/v1/uploads", params={"site_id": site_id, "floor": floor}, json=_walk(), headers=ADMIN
    )
    assert r.status_code == 202, r.text
    upload_id: str = r.json()["id"]
    return upload_id


async def _settled(client: httpx.AsyncClient, upload_id: str) -> dict[str, Any]:
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    while time.monotonic() < deadline:
        r = await client.get(f"/v1/uploads/{upload_id}", headers=ADMIN)
        body: dict[str, Any] = r.json()
        if body["status"] not in ("queued", "processing"):
            return body
        await asyncio.sleep(0.05)
    pytest.fail(f"upload {upload_id} did not settle in {SETTLE_TIMEOUT_S} s")


def _lines(caplog: pytest.LogCaptureFixture, upload_id: str) -> list[logging.LogRecord]:
    """The worker's INFO-or-above records about one upload, in order."""
    return [
        r
        for r in caplog.records
        if r.name == "indoorpos.worker"
        and r.levelno >= logging.INFO
        and getattr(r, "upload_id", None) == upload_id
    ]


async def _logged(
    caplog: pytest.LogCaptureFixture, upload_id: str, outcome: str
) -> list[logging.LogRecord]:
    """The upload's records once one with ``outcome`` is among them (the line is written
    just after the row is settled, so it may trail the API's answer a little)."""
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    while time.monotonic() < deadline:
        records = _lines(caplog, upload_id)
        if any(getattr(r, "outcome", None) == outcome for r in records):
            return records
        await asyncio.sleep(0.05)
    pytest.fail(f"no {outcome!r} line for upload {upload_id}: {caplog.text}")


def _outcomes(records: list[logging.LogRecord]) -> list[str]:
    return [str(getattr(r, "outcome", "")) for r in records if hasattr(r, "outcome")]


async def test_a_folded_upload_is_logged_with_its_map_version(
    client: httpx.AsyncClient, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="indoorpos.worker")
    upload_id = await _upload(client, await _site(client), floor=0)
    upload = await _settled(client, upload_id)
    assert upload["status"] == "done", upload
    records = await _logged(caplog, upload_id, "folded")
    assert _outcomes(records) == ["taken", "folded"]
    taken, folded = (r.getMessage() for r in records)
    assert f"upload {upload_id}: attempt 1 of 3 taken" in taken
    version = upload["report"]["radio_map_version"]
    assert f"folded into radio map v{version}" in folded
    assert all(r.levelno == logging.INFO for r in records)


async def test_a_rejected_upload_is_logged_with_the_reason(
    client: httpx.AsyncClient, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="indoorpos.worker")
    upload_id = await _upload(client, await _site(client), floor=7)
    upload = await _settled(client, upload_id)
    assert upload["status"] == "rejected", upload
    records = await _logged(caplog, upload_id, "rejected")
    assert _outcomes(records) == ["taken", "rejected"]
    line = records[-1].getMessage()
    assert line.startswith(f"upload {upload_id}: rejected: ")
    assert upload["report"]["reason"] in line  # "floor level 7 does not exist ..."


def _failing(times: int) -> Callable[..., Contribution]:
    """``contribution`` whose first ``times`` calls raise (a worker crashing on an
    upload), the rest do the real work."""
    real = upload_contribution.contribution
    calls = {"n": 0}

    def contribution(*args: Any, **kwargs: Any) -> Contribution:
        calls["n"] += 1
        if calls["n"] <= times:
            raise RuntimeError(f"worker crash {calls['n']}")
        return real(*args, **kwargs)

    return contribution


async def test_a_failed_attempt_is_logged_as_retried_then_the_retry_settles(
    client: httpx.AsyncClient, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    caplog.set_level(logging.INFO, logger="indoorpos.worker")
    site_id = await _site(client)
    monkeypatch.setattr(upload_contribution, "contribution", _failing(1))
    upload_id = await _upload(client, site_id, floor=0)
    assert (await _settled(client, upload_id))["status"] == "done"
    records = await _logged(caplog, upload_id, "folded")
    assert _outcomes(records) == ["taken", "retry", "taken", "folded"]
    messages = [r.getMessage() for r in records if hasattr(r, "outcome")]
    assert "attempt 1 of 3 failed; retried after the visibility timeout" in messages[1]
    assert "attempt 2 of 3 taken" in messages[2]
    # the failure itself: an ERROR line naming the upload, with the traceback
    assert any(
        r.levelno == logging.ERROR and upload_id in r.getMessage() and r.exc_info
        for r in caplog.records
    )


async def test_an_upload_out_of_attempts_is_logged_as_failed(
    client: httpx.AsyncClient, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    caplog.set_level(logging.INFO, logger="indoorpos.worker")
    site_id = await _site(client)
    monkeypatch.setattr(upload_contribution, "contribution", _failing(99))
    upload_id = await _upload(client, site_id, floor=0)
    upload = await _settled(client, upload_id)
    assert upload["status"] == "failed", upload
    records = await _logged(caplog, upload_id, "failed")
    assert _outcomes(records) == ["taken", "retry", "taken", "retry", "taken", "failed"]
    assert records[-1].levelno == logging.WARNING
    assert "failed after 3 attempts" in records[-1].getMessage()
