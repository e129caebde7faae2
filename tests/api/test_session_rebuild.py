"""A session whose store record was lost with the store's data (a Redis restarted without
it) is rebuilt from SQL at its next call and says so; one that expired or ended is not."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import httpx
import pytest
from fastapi import FastAPI
from sqlalchemy import update

from server.storage.models import SessionRecord
from tests.support.sessions import lose_the_store, open_session, scan, step
from tests.support.toy_site import ToySite, build_toy_site

T0 = 1_700_000_000_000


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def _batch(
    client: httpx.AsyncClient, sid: str, auth: dict[str, str], seq: int
) -> httpx.Response:
    t = T0 + 2000 * seq
    events = [scan(t, 5, 5), step(t + 600)]
    return await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": events}, headers=auth
    )


async def test_a_session_lost_with_the_store_is_rebuilt_at_its_next_batch(
    client: httpx.AsyncClient, site: ToySite, app: FastAPI
) -> None:
    sid, auth = await open_session(client, site)
    for seq in (1, 2, 3):
        r = await _batch(client, sid, auth, seq)
        assert r.status_code == 200, r.text
        assert r.json()["reinitialised"] is False
    old_version = (await app.state.runtime.store.get(sid)).version
    await lose_the_store(app.state.runtime, sid)

    before = datetime.now(UTC)
    r = await _batch(client, sid, auth, 4)  # the phone goes on where it was
    assert r.status_code == 200, r.text
    assert r.json()["reinitialised"] is True
    async with app.state.runtime.read() as s:
        row = await s.get(SessionRecord, sid)
        assert row is not None
        assert row.last_active_at >= before - timedelta(seconds=1)  # alive as of the rebuild
    # past any version it had: no replica's cached copy passes for the rebuilt record
    assert (await app.state.runtime.store.get(sid)).version > old_version + 10**9
    assert r.json()["fixes"], "the rebuilt filter starts again from this batch's scan"
    again = await _batch(client, sid, auth, 4)  # a retry of that batch says so too
    assert again.json()["replayed"] is True
    assert again.json()["reinitialised"] is True
    r = await _batch(client, sid, auth, 5)
    assert r.status_code == 200, r.text
    assert r.json()["reinitialised"] is False
    info = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert info["last_seq"] == 5
    # another token still gets nothing
    wrong = {"Authorization": "Bearer wrong"}
    assert (await client.get(f"/v1/sessions/{sid}", headers=wrong)).status_code == 403


async def test_a_batch_before_the_rebuild_is_refused_by_name(
    client: httpx.AsyncClient, site: ToySite, app: FastAPI
) -> None:
    sid, auth = await open_session(client, site)
    assert (await _batch(client, sid, auth, 1)).status_code == 200
    await lose_the_store(app.state.runtime, sid)
    r = await _batch(client, sid, auth, 3)  # seq 2 was in flight when the store was lost
    assert r.json()["reinitialised"] is True
    r = await _batch(client, sid, auth, 2)
    assert r.status_code == 409, r.text
    assert "reinitialised at seq 3" in r.json()["message"]


async def test_a_session_idle_past_its_timeout_is_not_rebuilt(
    client: httpx.AsyncClient, site: ToySite, app: FastAPI
) -> None:
    rt = app.state.runtime
    sid, auth = await open_session(client, site)
    assert (await _batch(client, sid, auth, 1)).status_code == 200
    long_ago = datetime.now(UTC) - timedelta(seconds=2 * rt.settings.session_idle_s)
    async with rt.transaction() as s:
        await s.execute(
            update(SessionRecord).where(SessionRecord.id == sid).values(last_active_at=long_ago)
        )
    await lose_the_store(rt, sid)  # it expired, and then the store was lost as well
    assert (await _batch(client, sid, auth, 2)).status_code == 403


async def test_a_session_that_expired_or_ended_is_not_rebuilt(
    client: httpx.AsyncClient, site: ToySite, app: FastAPI
) -> None:
    expired, auth = await open_session(client, site)
    assert (await _batch(client, expired, auth, 1)).status_code == 200
    await lose_the_store(app.state.runtime, expired, new_epoch=False)  # its TTL ran out
    assert (await _batch(client, expired, auth, 2)).status_code == 403

    ended, auth = await open_session(client, site)
    assert (await client.delete(f"/v1/sessions/{ended}", headers=auth)).status_code == 204
    await lose_the_store(app.state.runtime, ended)
    assert (await _batch(client, ended, auth, 1)).status_code == 403
