"""A session's log: a process that did not write a session's newest state reads the
snapshot and the batches logged since, steps the engine through them, and goes on exactly
as the writer would have (``services.batches``).

Forgetting the process's own copy of a session before each batch stands for a batch that
lands on another replica; ``tests/e2e/test_session_takeover.py`` does it with two."""

from __future__ import annotations

from typing import Any

import httpx
import numpy as np
import pytest
from fastapi import FastAPI

from server.positioning.engines.registry import get_engine
from server.services import batches, engine_settings, sessions
from server.services.maps import site_maps
from server.services.runtime import Runtime
from server.services.session_records import LogEntry, SessionMeta
from tests.support.toy_site import ToySite, build_toy_site, walk_batch

BATCHES = 2 * batches.SNAPSHOT_EVERY + 3  # two snapshots and a log behind the last one
ENGINES = ("pf_magnetic", "step_ekf")  # a cloud drawn from the random stream; a Kalman filter


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def open_session(client: httpx.AsyncClient, site: ToySite, engine: str) -> tuple[str, str]:
    r = await client.post(
        "/v1/sessions",
        json={"site_id": site.site_id, "engine": engine, "seed": 7},
        headers=site.device,
    )
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


async def walk(
    client: httpx.AsyncClient, rt: Runtime, sid: str, token: str, *, forget: bool
) -> list[Any]:
    answers = []
    for n in range(1, BATCHES + 1):
        if forget:
            rt.states.drop(sid)  # as if another process had written the session last
        r = await client.post(
            f"/v1/sessions/{sid}/batches",
            json={"seq": n, "events": walk_batch(n)},
            headers={"Authorization": f"Bearer {token}"},
        )
        assert r.status_code == 200, r.text
        answers.append(r.json()["fixes"])
    return answers


@pytest.mark.parametrize("engine", ENGINES)
async def test_a_session_read_from_its_log_goes_on_as_its_writer_would(
    app: FastAPI, client: httpx.AsyncClient, site: ToySite, engine: str
) -> None:
    rt: Runtime = app.state.runtime
    kept_id, kept_token = await open_session(client, site, engine)
    moved_id, moved_token = await open_session(client, site, engine)
    kept = await walk(client, rt, kept_id, kept_token, forget=False)
    moved = await walk(client, rt, moved_id, moved_token, forget=True)
    assert moved == kept
    assert sum(len(fixes) for fixes in kept) >= BATCHES
    # what a reader sees comes from the log alone, without stepping the engine
    rt.states.drop(moved_id)
    read = await client.get(
        f"/v1/sessions/{moved_id}", headers={"Authorization": f"Bearer {moved_token}"}
    )
    assert read.json()["last_seq"] == BATCHES
    assert read.json()["last_fix"] == kept[-1][-1]


@pytest.mark.parametrize("engine", ENGINES)
async def test_a_snapshot_and_its_log_rebuild_the_exact_state(
    app: FastAPI, client: httpx.AsyncClient, site: ToySite, engine: str
) -> None:
    rt: Runtime = app.state.runtime
    sid, token = await open_session(client, site, engine)
    await walk(client, rt, sid, token, forget=False)
    written = rt.states.current(sid)  # the state this process wrote last
    assert written is not None
    stored = await rt.store.get(sid)
    assert stored is not None
    assert len(stored.log) == BATCHES % batches.SNAPSHOT_EVERY  # entries since the snapshot

    rt.states.drop(sid)
    _, meta, state = await sessions.load_state(rt, sid, token)
    assert [entry.seq for entry in state.pending] == list(
        range(BATCHES - len(stored.log) + 1, BATCHES + 1)
    )
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, site.site_id)
    params = engine_settings.session_params(meta.engine, meta.params)
    rebuilt = batches.caught_up(state, meta, maps, params)
    spec = get_engine(engine)
    expected, found = spec.encode(written[2].engine_state), spec.encode(rebuilt)
    assert expected.keys() == found.keys()
    assert [k for k in expected if not np.array_equal(expected[k], found[k], equal_nan=True)] == []
    assert (state.last_seq, state.last_fix, state.replies) == (
        written[2].last_seq,
        written[2].last_fix,
        written[2].replies,
    )
    assert isinstance(meta, SessionMeta)


async def test_a_log_that_does_not_follow_its_snapshot_is_not_read(
    app: FastAPI, client: httpx.AsyncClient, site: ToySite
) -> None:
    """An entry the snapshot does not lead to (a gap; an older server's write) makes the
    record unreadable: the session goes on from a fresh state, as after a lost store, and
    its next write is a snapshot, so nothing is read behind the old one again."""
    rt: Runtime = app.state.runtime
    sid, token = await open_session(client, site, "step_ekf")
    auth = {"Authorization": f"Bearer {token}"}
    for n in (1, 2):
        r = await client.post(
            f"/v1/sessions/{sid}/batches", json={"seq": n, "events": walk_batch(n)}, headers=auth
        )
        assert r.status_code == 200, r.text
    stored = await rt.store.get(sid)
    assert stored is not None
    stray = LogEntry(9, b"\0" * 32, (), b"[]", b"", 0)
    ttl = rt.settings.session_idle_s
    assert await rt.store.compare_and_set(sid, stored.version, None, ttl, entry=stray.to_bytes())
    rt.states.drop(sid)
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 3, "events": walk_batch(3)}, headers=auth
    )
    assert r.status_code == 200, r.text
    assert r.json()["reinitialised"]
    after = await rt.store.get(sid)
    assert after is not None
    assert after.log == ()  # written as a snapshot
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 4, "events": walk_batch(4)}, headers=auth
    )
    assert r.status_code == 200, r.text
    assert not r.json()["reinitialised"]
