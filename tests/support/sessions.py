"""Sessions on the toy site (``tests.support.toy_site``) through the API: opening one, the
events of its batches, and its store record lost as a restarted store loses it."""

from __future__ import annotations

import math
import uuid
from typing import Any

import httpx

from server.services.runtime import Runtime
from server.storage.redis_session_store import RedisSessionStore
from tests.support.toy_site import ToySite, rssi_at


async def open_session(
    client: httpx.AsyncClient, site: ToySite, engine: str = "step_ekf"
) -> tuple[str, dict[str, str]]:
    """A session on ``site`` (``step_ekf`` unless told), opened with its device key: its
    id and the header of its token."""
    r = await client.post(
        "/v1/sessions",
        json={"site_id": site.site_id, "engine": engine},
        headers=site.device,
    )
    assert r.status_code == 201, r.text
    body = r.json()
    return body["id"], {"Authorization": f"Bearer {body['token']}"}


def scan(t: int, x: float, y: float, level: int = 0) -> dict[str, Any]:
    """A WiFi scan taken at (x, y) on ``level`` of the toy site."""
    return {"type": "wifi", "t": t, "readings": rssi_at(x, y, level)}


def step(t: int, heading_rad: float = math.pi / 2, length_m: float = 0.7) -> dict[str, Any]:
    """A step (east by default)."""
    return {"type": "step", "t": t, "length_m": length_m, "heading_rad": heading_rad}


async def lose_the_store(rt: Runtime, session_id: str, new_epoch: bool = True) -> None:
    """What a store restarted without its data looks like to this session: its record is
    gone and (``new_epoch``) the store's epoch marker with it."""
    rt.states.drop(session_id)
    await rt.store.delete(session_id)
    if not new_epoch:
        return
    if isinstance(rt.store, RedisSessionStore):
        await rt.store._client.delete(rt.store.epoch_key())
    else:
        rt.store._epoch = uuid.uuid4().hex  # type: ignore[attr-defined]
