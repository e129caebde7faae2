"""Positioning sessions: create, apply a batch of events exactly once, read, end, follow live.

A session is one record in the session store: immutable meta (site, engine, token digest,
RNG entropy) and a state blob holding the engine state, the last applied ``seq``, the
replies of the last few batches (so a retried ``seq`` gets the same answer) and the last
fix. Writes are compare-and-set on the record's version, so two replicas applying batches
to one session at once never overwrite each other: the loser re-reads and re-applies.

Batches apply strictly in ``seq`` order (1, 2, 3, ...). A batch that arrives before its
predecessor waits up to ``seq_wait_s`` for it, then is refused with 409.

Each session is also a row in SQL (``SessionRecord``) with the store's epoch it lives in.
When the store lost its data (a Redis restarted without it: a new epoch), the next call
of the session rebuilds its record from the row: a fresh engine state that takes the next
batch's ``seq`` as it comes, answered ``reinitialised: true``. A session missing at the
epoch it was made in, ended, or idle longer than ``REBUILD_IDLE_FACTOR`` idle timeouts by
its row's ``last_active_at`` (refreshed by a batch at most every half idle timeout)
expired, and stays gone.
"""

from __future__ import annotations

import contextlib
import enum
import hashlib
import hmac
import logging
import secrets
import time
import uuid
from collections.abc import AsyncIterator, Mapping, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import anyio
import numpy as np
import orjson

from server.positioning.engines import NEEDS_GRAPHS, get_engine
from server.positioning.events import Event, ImuEvent, StepEvent
from server.positioning.sitemaps import SiteMaps
from server.services import engine_settings, limits, telemetry, traces, uploads
from server.services.device_offsets import on_common_level
from server.services.errors import Conflict, Forbidden, Invalid
from server.services.maps import site_maps, with_graphs
from server.services.runtime import Runtime
from server.services.session_records import (
    Reply,
    SessionMeta,
    SessionState,
    StaleEngineState,
    events_digest,
    fix_to_wire,
)
from server.storage.models import SessionRecord, utcnow
from server.storage.repositories import sessions as repo
from server.storage.session_store import SessionExists, StoredSession

logger = logging.getLogger(__name__)
# a row's last_active_at lags the last batch by up to half an idle timeout: a session is
# rebuilt only if that is at most 1.5 idle timeouts ago (never refusing a live one)
REBUILD_IDLE_FACTOR = 1.5
SEQ_POLL_S = 0.01
INLINE_MAX_STEPS = 2  # batches with more steps, or any raw samples, run in a worker thread
INLINE_MAX_EVENTS = 32


@dataclass(frozen=True)
class CreatedSession:
    id: str
    token: str
    site_id: str
    engine: str
    idle_timeout_s: int


@dataclass(frozen=True)
class BatchResult:
    seq: int
    replayed: bool
    fixes: list[dict[str, Any]]
    reinitialised: bool = False  # the session was rebuilt before this batch


@dataclass(frozen=True)
class SessionInfo:
    id: str
    site_id: str
    engine: str
    last_seq: int
    last_fix: dict[str, Any] | None
    idle_timeout_s: int


def _digest(secret: str) -> str:
    return hashlib.sha256(secret.encode()).hexdigest()


async def create_session(
    rt: Runtime,
    site_id: str,
    engine: str,
    *,
    contribute: bool = False,
    device_model: str | None = None,
    params: Mapping[str, Any] | None = None,
) -> CreatedSession:
    """Open a session. With ``contribute`` its batches are kept, and when it ends they
    become one upload for the map builder (``services.uploads``). ``params`` override the
    engine's parameters, over the site's settings (``services.engine_settings``)."""
    spec = engine_settings.engine_of(engine)
    token = secrets.token_urlsafe(32)
    session_id = uuid.uuid4().hex
    epoch = await rt.store.epoch()
    async with rt.transaction() as s:
        await site_maps(s, rt.maps, site_id)
        overrides = await engine_settings.for_new_session(s, site_id, engine, params)
        meta = SessionMeta(
            site_id,
            engine,
            _digest(token),
            secrets.randbits(128),
            contribute,
            device_model or "",
            overrides,
        )
        await repo.create_session_record(s, _record(session_id, meta, epoch))
    state = _fresh_state(meta, last_seq=0)
    ttl = rt.settings.session_idle_s
    await rt.store.create(session_id, meta.to_bytes(), state.to_bytes(spec), ttl)
    return CreatedSession(session_id, token, site_id, engine, ttl)


def _fresh_state(meta: SessionMeta, last_seq: int) -> SessionState:
    """A session state with the engine's initial state under the session's parameters
    (``last_seq`` -1: rebuilt, the next batch's seq is taken as it comes)."""
    spec = get_engine(meta.engine)
    start = spec.start(engine_settings.session_params(meta.engine, meta.params))
    return SessionState(last_seq, start, (), b"", 0, _now_ms())


def _now_ms() -> int:
    return time.time_ns() // 1_000_000


def _record(session_id: str, meta: SessionMeta, epoch: str) -> SessionRecord:
    return SessionRecord(
        id=session_id,
        site_id=meta.site_id,
        engine=meta.engine,
        token_digest=meta.token_digest,
        entropy=f"{meta.entropy:032x}",
        contribute=meta.contribute,
        device_model=meta.device_model,
        params=orjson.loads(meta.params),
        epoch=epoch,
    )


async def _rebuild(rt: Runtime, session_id: str, token: str) -> bool:
    """Re-create a session's store record from its SQL row when the store lost it (module
    docstring); False when the session is not one to rebuild (unknown, ended, another
    token, or missing at the epoch it lives in: it expired)."""
    epoch = await rt.store.epoch()
    async with rt.read() as s:
        row = await repo.get_session_record(s, session_id)
        if row is None or row.ended_at is not None or row.epoch == epoch:
            return False
        idle = (utcnow() - row.last_active_at).total_seconds()
        if idle > REBUILD_IDLE_FACTOR * rt.settings.session_idle_s:
            return False  # it expired before the store lost it
        if not hmac.compare_digest(row.token_digest, _digest(token)):
            return False
        meta = SessionMeta(
            row.site_id,
            row.engine,
            row.token_digest,
            int(row.entropy, 16),
            row.contribute,
            row.device_model,
            engine_settings.canonical(row.params or {}),
        )
    spec = get_engine(meta.engine)
    state = _fresh_state(meta, last_seq=-1)
    # versions start past any the session had (microseconds since the epoch; a session
    # makes far fewer writes), so no replica's cached copy passes for the rebuilt record
    with contextlib.suppress(SessionExists):  # another replica rebuilt it first
        await rt.store.create(
            session_id,
            meta.to_bytes(),
            state.to_bytes(spec),
            rt.settings.session_idle_s,
            version=time.time_ns() // 1000,
        )
    async with rt.transaction() as s:
        await repo.set_session_epoch(s, session_id, epoch)
    logger.warning("session %s rebuilt: the session store had lost it", session_id)
    return True


def _no_session() -> Forbidden:
    """One answer for a wrong token and for a session that does not exist (any more), so
    that session ids cannot be probed."""
    return Forbidden(
        "this token opens no live session of this id (wrong token, or the session ended "
        "or expired)",
        field="authorization",
    )


async def _load(rt: Runtime, session_id: str, token: str) -> tuple[StoredSession, SessionMeta]:
    stored = await rt.store.get(session_id)
    if stored is None and await _rebuild(rt, session_id, token):
        stored = await rt.store.get(session_id)
    if stored is None:
        raise _no_session()
    meta = SessionMeta.from_bytes(stored.meta)
    if not hmac.compare_digest(meta.token_digest, _digest(token)):
        raise _no_session()
    return stored, meta


async def _load_decoded(
    rt: Runtime, session_id: str, token: str
) -> tuple[int, SessionMeta, SessionState]:
    """The session's version, meta and decoded state; from this process's cache when the
    store still holds the version it has (``services.session_cache``)."""
    cached = rt.states.get(session_id)
    if cached is None:
        stored: StoredSession | int | None = await rt.store.get(session_id)
    else:
        stored = await rt.store.get_changed(session_id, cached[0])
    if stored is None:
        rt.states.drop(session_id)
        if await _rebuild(rt, session_id, token):
            stored = await rt.store.get(session_id)
        if stored is None:
            raise _no_session()
    if isinstance(stored, int):
        assert cached is not None
        version, meta, state = cached
    else:
        meta = SessionMeta.from_bytes(stored.meta)
        version = stored.version
        try:
            state = SessionState.from_bytes(stored.state, get_engine(meta.engine))
        except StaleEngineState as e:
            # written by an older server (or not a state of this engine): go on from a
            # fresh engine state, as after a rebuild (the next batch is answered
            # reinitialised; a retry of an earlier batch is applied again)
            logger.warning("session %s: engine state not readable (%s), restarted", session_id, e)
            state = _fresh_state(meta, last_seq=-1)
        rt.states.put(session_id, version, meta, state)
    if not hmac.compare_digest(meta.token_digest, _digest(token)):
        raise _no_session()
    return version, meta, state


async def authorize(rt: Runtime, session_id: str, token: str) -> SessionMeta:
    return (await _load(rt, session_id, token))[1]


async def apply_batch(
    rt: Runtime,
    session_id: str,
    token: str,
    seq: int,
    events: Sequence[Event],
    address: str | None = None,
) -> BatchResult:
    """Apply batch ``seq`` once (module docstring). At most ``batch_concurrency`` batches
    are worked on at a time in a process: interleaving many of them on the event loop
    would stretch every one's latency by the others' work (each awaits the store twice);
    a batch waiting for its predecessor, or for its site's maps to be read from SQL (a
    new map version rebuilds the plans: up to seconds), does not hold a turn either.
    With ``address``, the batch counts against the session's and the address's rate
    limits once the token is known good (``services.limits``)."""
    digest = events_digest(events)
    deadline = time.monotonic() + rt.settings.seq_wait_s
    maps: SiteMaps | None = None
    charge = address
    while True:
        async with rt.batch_gate:
            outcome = await _attempt(
                rt, session_id, token, seq, events, digest, deadline, maps, charge
            )
        charge = None
        if isinstance(outcome, BatchResult):
            return outcome
        if isinstance(outcome, _NeedMaps):
            async with rt.transaction() as s:
                maps = await site_maps(s, rt.maps, outcome.site_id)
        elif outcome is _Retry.WAIT:
            await anyio.sleep(SEQ_POLL_S)


@dataclass(frozen=True)
class _NeedMaps:
    site_id: str


class _Retry(enum.Enum):
    WAIT = "the predecessor seq is not applied yet"
    LOST = "another writer changed the session first"


async def _attempt(
    rt: Runtime,
    session_id: str,
    token: str,
    seq: int,
    events: Sequence[Event],
    digest: bytes,
    deadline: float,
    known_maps: SiteMaps | None,
    charge: str | None = None,
) -> BatchResult | _Retry | _NeedMaps:
    """One read-compute-write of the batch; ``known_maps``: the site's maps as the caller
    read them since the last attempt; ``charge``: the address to count the batch against
    (the first attempt only)."""
    version, meta, state = await _load_decoded(rt, session_id, token)
    if charge is not None:
        await limits.check_batch(rt, session_id, charge)
    spec = get_engine(meta.engine)
    rebuilt = state.last_seq < 0  # the first batch after a rebuild: its seq is the next one
    if seq <= state.last_seq:
        return _replay(state, seq, digest)
    if seq > state.last_seq + 1 and not rebuilt:
        if time.monotonic() >= deadline:
            raise Conflict(
                f"seq {seq} arrived before seq {state.last_seq + 1}; send that one first",
                field="seq",
            )
        return _Retry.WAIT
    maps = rt.maps.fresh(meta.site_id) or known_maps  # no SQL while the cached set is fresh
    if maps is None and not meta.contribute:
        return _NeedMaps(meta.site_id)  # read outside the turn
    if maps is None or meta.contribute:
        if meta.contribute:  # CPU work (compression): off the event loop
            walk = await anyio.to_thread.run_sync(
                lambda: traces.encode_trace(traces.trace_from_events(events))
            )
        async with rt.transaction() as s:
            maps = await site_maps(s, rt.maps, meta.site_id)
            if meta.contribute:  # kept before the batch is acknowledged
                await repo.keep_session_batch(s, session_id, seq, walk)
    if meta.engine in NEEDS_GRAPHS:
        maps = await with_graphs(maps)
    rng = np.random.default_rng(np.random.SeedSequence(meta.entropy, spawn_key=(seq,)))
    params = engine_settings.session_params(meta.engine, meta.params)
    scans_level = maps.device_offsets.get(meta.device_model)
    run = telemetry.timed_engine(meta.engine, spec.step)
    args = (state.engine_state, on_common_level(events, scans_level), maps, params, rng)
    try:
        if _runs_inline(events):
            new_engine_state, fixes = run(*args)
        else:
            new_engine_state, fixes = await anyio.to_thread.run_sync(run, *args)
    except BaseException:
        rt.states.drop(session_id)  # never reuse a state an engine failed on
        raise
    wire = [fix_to_wire(f, maps, meta.engine) for f in fixes]
    body = orjson.dumps(wire)
    replies = (*state.replies, Reply(seq, digest, body))[-rt.settings.replay_window :]
    now_ms = _now_ms()
    touch = now_ms - state.touched_ms > 500 * rt.settings.session_idle_s  # half the timeout
    new_state = SessionState(
        last_seq=seq,
        engine_state=new_engine_state,
        replies=replies,
        last_fix=orjson.dumps(wire[-1]) if wire else state.last_fix,
        rebuilt_seq=seq if rebuilt else state.rebuilt_seq,
        touched_ms=now_ms if touch else state.touched_ms,
    )
    live = orjson.dumps({"seq": seq, "fixes": wire}) if wire else None
    ok = await rt.store.compare_and_set(
        session_id, version, new_state.to_bytes(spec), rt.settings.session_idle_s, live
    )
    if ok:
        rt.states.put(session_id, version + 1, meta, new_state)
        if touch:  # the row says the session is alive, should the store lose it
            async with rt.transaction() as s:
                await repo.touch_session_record(s, session_id)
        return BatchResult(seq, False, wire, reinitialised=rebuilt)
    return _Retry.LOST  # another writer got there first: read the new state and try again


def _runs_inline(events: Sequence[Event]) -> bool:
    """Whether the engine runs on the event loop rather than in a worker thread: for a
    small batch without raw samples (a step or two and their scans, about a millisecond per
    step at N = 3000), the hop to a thread and back costs more than it spares the loop."""
    if len(events) > INLINE_MAX_EVENTS or any(isinstance(e, ImuEvent) for e in events):
        return False
    return sum(isinstance(e, StepEvent) for e in events) <= INLINE_MAX_STEPS


def _replay(state: SessionState, seq: int, digest: bytes) -> BatchResult:
    if seq < state.rebuilt_seq:
        raise Conflict(
            f"the session was reinitialised at seq {state.rebuilt_seq} (the server had "
            f"lost its state); seq {seq} and earlier batches were not applied: go on after "
            f"seq {state.last_seq}",
            field="seq",
        )
    for reply in state.replies:
        if reply.seq == seq:
            if reply.digest != digest:
                raise Conflict(f"seq {seq} was already applied with different events", field="seq")
            reinitialised = seq == state.rebuilt_seq
            return BatchResult(seq, True, orjson.loads(reply.body), reinitialised)
    raise Conflict(
        f"seq {seq} was applied long ago and its reply is no longer kept; "
        f"the session is at seq {state.last_seq}",
        field="seq",
    )


async def get_session(rt: Runtime, session_id: str, token: str) -> SessionInfo:
    _, meta, state = await _load_decoded(rt, session_id, token)
    return SessionInfo(
        id=session_id,
        site_id=meta.site_id,
        engine=meta.engine,
        last_seq=max(state.last_seq, 0),
        last_fix=orjson.loads(state.last_fix) if state.last_fix else None,
        idle_timeout_s=rt.settings.session_idle_s,
    )


async def end_session(rt: Runtime, session_id: str, token: str) -> str | None:
    """End a session; for a contributing one, its kept batches become one upload first
    (its id is returned; None when nothing was kept)."""
    _, meta, state = await _load_decoded(rt, session_id, token)
    upload_id = None
    if meta.contribute:
        upload_id = await _offer_walk(rt, session_id, meta, state)
    async with rt.transaction() as s:
        await repo.end_session_record(s, session_id)
    rt.states.drop(session_id)
    await rt.store.delete(session_id)
    await rt.store.publish(session_id, orjson.dumps({"closed": True}))
    return upload_id


async def _offer_walk(
    rt: Runtime, session_id: str, meta: SessionMeta, state: SessionState
) -> str | None:
    last_fix = orjson.loads(state.last_fix) if state.last_fix else {}
    async with rt.transaction() as s:
        kept = await repo.take_session_batches(s, session_id)
        if not kept:
            return None
        payload = await anyio.to_thread.run_sync(
            lambda: traces.encode_trace(traces.join_traces([traces.decode_trace(b) for b in kept]))
        )
        new = uploads.NewUpload(
            site_id=meta.site_id,
            building_id=last_fix.get("building_id"),
            floor_level=last_fix.get("floor"),
            device_model=meta.device_model or None,
            content_type=traces.CONTENT_TYPE,
            payload=payload,
            idempotency_key=f"session:{session_id}",
        )
        try:
            row, _ = await uploads.create_upload(s, new)
        except Invalid:  # nothing in it a map could use (no records)
            return None
        upload_id = row.id
    await rt.uploads.publish(upload_id)  # a lost publish is found by the worker's rescan
    return upload_id


@asynccontextmanager
async def follow(rt: Runtime, session_id: str) -> AsyncIterator[AsyncIterator[dict[str, Any]]]:
    """Live messages of a session: ``{"seq", "fixes"}`` per applied batch, ``{"closed"}`` at
    the end. The caller must have authorised the reader first."""
    async with rt.store.subscribe(session_id) as raw:

        async def messages() -> AsyncIterator[dict[str, Any]]:
            async for data in raw:
                message: dict[str, Any] = orjson.loads(data)
                yield message

        yield messages()
