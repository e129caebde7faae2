"""Decoded session states cached per process: used only while the store still holds the
version the process knows, so batches alternating between two processes stay exact."""

from __future__ import annotations

import dataclasses
import math

import httpx
import pytest
from fastapi import FastAPI

from server.api.convert import to_events
from server.api.schemas.sessions import BatchIn
from server.positioning.model.events import Event
from server.services import batches, session_records, sessions
from server.services.maps import MapCache
from server.services.runtime import Runtime
from server.services.session_cache import SessionCache
from tests.support.toy_site import build_toy_site, rssi_at

T0 = 1_700_000_000_000


def _batches() -> list[list[Event]]:
    """A scan, then steps east with a scan now and then."""
    out: list[list[Event]] = []
    for k in range(6):
        t = T0 + 600 * (k + 1)
        events = [{"type": "step", "t": t, "length_m": 0.7, "heading_rad": math.pi / 2}]
        if k % 2 == 0:
            scan = {"type": "wifi", "t": t - 599, "readings": rssi_at(3 + 0.7 * k, 5, 0)}
            events.insert(0, scan)
        out.append(to_events(BatchIn.model_validate({"seq": k + 1, "events": events}).events))
    return out


def _process(rt: Runtime, cache_size: int) -> Runtime:
    """Another api process on the same stores: its own map and session caches."""
    return dataclasses.replace(rt, maps=MapCache(4), states=SessionCache(cache_size))


async def test_alternating_processes_see_each_others_writes(
    app: FastAPI, client: httpx.AsyncClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    site = await build_toy_site(client, admin)
    base: Runtime = app.state.runtime
    a, b, plain = _process(base, 16), _process(base, 16), _process(base, 0)
    decodes = 0
    decode = session_records.SessionState.from_bytes

    def counting(data: bytes, spec: object) -> session_records.SessionState:
        nonlocal decodes
        decodes += 1
        return decode(data, spec)  # type: ignore[arg-type]

    monkeypatch.setattr(session_records.SessionState, "from_bytes", staticmethod(counting))
    alternating = await sessions.create_session(a, site.site_id, "step_ekf")
    reference = await sessions.create_session(plain, site.site_id, "step_ekf")
    order = [a, a, b, a, b, b]
    seen = []
    for seq, (events, rt) in enumerate(zip(_batches(), order, strict=True), start=1):
        before = decodes
        got = await batches.apply_batch(rt, alternating.id, alternating.token, seq, events)
        seen.append(decodes - before)
        want = await batches.apply_batch(plain, reference.id, reference.token, seq, events)
        assert got.fixes == want.fixes  # step_ekf is deterministic: same state, same fixes
    # a decodes its first read; its second batch finds its own write; b reads a's write;
    # a then finds b's write (a new version); b and b again: its own write
    assert seen == [1, 0, 1, 1, 1, 0]
    assert a.states.get(alternating.id) is not None
    # ending a session forgets it
    await sessions.end_session(b, alternating.id, alternating.token)
    assert b.states.get(alternating.id) is None


def test_cache_keeps_the_most_recently_used() -> None:
    cache: SessionCache[str, str] = SessionCache(2)
    cache.put("x", 1, "m", "s1")
    cache.put("y", 1, "m", "s1")
    assert cache.get("x") == (1, "m", "s1")  # x is now the most recent
    cache.put("z", 1, "m", "s1")
    assert cache.get("y") is None
    assert len(cache) == 2
    off: SessionCache[str, str] = SessionCache(0)
    off.put("x", 1, "m", "s")
    assert off.get("x") is None


async def test_batches_to_the_process_that_wrote_last_skip_the_read(
    app: FastAPI, client: httpx.AsyncClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """One round trip per batch (the compare-and-set) while a session's batches reach one
    process; a copy another process's write made stale is noticed, and the fixes stay
    exact."""
    site = await build_toy_site(client, admin)
    base: Runtime = app.state.runtime
    a, b, plain = _process(base, 16), _process(base, 16), _process(base, 0)
    reads: list[str] = []
    store = base.store
    for name in ("get", "get_changed"):
        real = getattr(store, name)

        async def counted(*args: object, _real: object = real, _name: str = name) -> object:
            reads.append(_name)
            return await _real(*args)  # type: ignore[operator]

        monkeypatch.setattr(store, name, counted)
    session = await sessions.create_session(a, site.site_id, "step_ekf")
    per_batch, fixes = [], []
    for seq, (events, rt) in enumerate(zip(_batches(), [a, a, a, b, a, a], strict=True), start=1):
        before = len(reads)
        got = await batches.apply_batch(rt, session.id, session.token, seq, events)
        per_batch.append(len(reads) - before)
        fixes.append(got.fixes)
    # a reads once, then goes on from its own writes; b reads a's write (and once more
    # after reading the site's maps); a's copy is then stale, which seq 5 shows (it does
    # not follow a's last seq 3): a asks the store, and goes on from its own writes again
    assert per_batch == [1, 0, 0, 2, 1, 0]
    reference = await sessions.create_session(plain, site.site_id, "step_ekf")
    for seq, events in enumerate(_batches(), start=1):
        want = await batches.apply_batch(plain, reference.id, reference.token, seq, events)
        assert want.fixes == fixes[seq - 1]
    # a retried batch is answered as a replay after the store's word
    again = await batches.apply_batch(a, session.id, session.token, 6, _batches()[5])
    assert again.replayed
    assert again.fixes == fixes[5]
