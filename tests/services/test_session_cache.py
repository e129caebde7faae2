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
from server.positioning.events import Event
from server.services import session_records, sessions
from server.services.maps import MapCache
from server.services.runtime import Runtime
from server.services.session_cache import SessionCache
from tests.api.toy_site import build_toy_site, rssi_at

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
        got = await sessions.apply_batch(rt, alternating.id, alternating.token, seq, events)
        seen.append(decodes - before)
        want = await sessions.apply_batch(plain, reference.id, reference.token, seq, events)
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
