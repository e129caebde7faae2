"""Positioning sessions: create, read, end, follow live (a batch: ``services.batches``).

A session is one record in the session store: immutable meta (site, engine, token digest,
RNG entropy), a snapshot of its state (the engine state, the last applied ``seq``, the
replies of the last few batches, so a retried ``seq`` gets the same answer, and the last
fix) and the log of the batches applied since (``session_records``). A batch's write
appends the batch and its answer to the log (a few kilobytes); every
``SNAPSHOT_EVERY``-th ``seq`` writes a snapshot instead, which empties the log. A process
holding the session's newest state (it wrote it) steps on from it; any other reads the
snapshot and the log and steps the engine through the logged batches first, with the
session's random stream, so it goes on from the state the writer had. Writes are
compare-and-set on the record's version, so two replicas applying batches to one session
at once never overwrite each other: the loser re-reads and re-applies.

Each session is also a row in SQL (``SessionRecord``) with the store's epoch it lives in.
When the store lost its data (a Redis restarted without it: a new epoch), the next call
of the session rebuilds its record from the row: a fresh engine state that takes the next
batch's ``seq`` as it comes, answered ``reinitialised: true``. A session missing at the
epoch it was made in, ended, or idle longer than ``REBUILD_IDLE_FACTOR`` idle timeouts by
its row's ``last_active_at`` (refreshed by a batch at most every half idle timeout)
expired, and stays gone.

Who may do what: the session's own token applies batches, reads, follows and ends it; an
API key with the ``viewer`` scope for the session's site (``admin`` and ``maps:write``
imply it) reads and follows it, and its track: the newest fixes, kept in the store beside
the state (``session_track_len`` of them) by the write that applies each batch.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import logging
import secrets
import time
import uuid
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import anyio
import orjson

from server.positioning.engines.registry import get_engine
from server.positioning.model.walk import join_traces
from server.services import auth, engine_settings, uploads, webhooks
from server.services.errors import Forbidden, Invalid, NotFound
from server.services.maps import site_maps
from server.services.runtime import Runtime
from server.services.session_records import (
    REBUILD_IDLE_FACTOR,
    LogEntry,
    SessionMeta,
    SessionState,
    StaleEngineState,
    active_since,
    exits_at_end,
)
from server.storage import trace_codec
from server.storage.codec import CodecError
from server.storage.models import SessionRecord, utcnow
from server.storage.repositories import sessions as repo
from server.storage.repositories.pages import Key, Page
from server.storage.session_store import SessionExists, StoredSession

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CreatedSession:
    id: str
    token: str
    site_id: str
    engine: str
    idle_timeout_s: int


@dataclass(frozen=True)
class SessionInfo:
    id: str
    site_id: str
    engine: str
    last_seq: int
    last_fix: dict[str, Any] | None
    idle_timeout_s: int


def token_digest(secret: str) -> str:
    """What a session keeps of its token."""
    return hashlib.sha256(secret.encode()).hexdigest()


async def create_session(
    rt: Runtime,
    site_id: str,
    engine: str,
    *,
    contribute: bool = False,
    device_model: str | None = None,
    params: Mapping[str, Any] | None = None,
    seed: int | None = None,
) -> CreatedSession:
    """Open a session. With ``contribute`` its batches are kept, and when it ends they
    become one upload for the map builder (``services.uploads``). ``params`` override the
    engine's parameters, over the site's settings (``services.engine_settings``). ``seed``
    is the entropy of the session's random stream (fresh 128 bits by default): a replay
    given the seed of an in-process run draws the same numbers."""
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
            token_digest(token),
            secrets.randbits(128) if seed is None else seed,
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
    return SessionState(last_seq, start, (), b"", 0, now_ms())


def now_ms() -> int:
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
        if not hmac.compare_digest(row.token_digest, token_digest(token)):
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


def no_session() -> Forbidden:
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
        raise no_session()
    meta = SessionMeta.from_bytes(stored.meta)
    if not hmac.compare_digest(meta.token_digest, token_digest(token)):
        raise no_session()
    return stored, meta


async def load_state(
    rt: Runtime, session_id: str, token: str | None
) -> tuple[int, SessionMeta, SessionState]:
    """The session's version, meta and decoded state; from this process's cache when the
    store still holds the version it has (``services.session_cache``). ``token`` None:
    for a reader whose key the caller checked (no rebuild then, and no token check)."""
    cached = rt.states.get(session_id)
    if cached is None:
        stored: StoredSession | int | None = await rt.store.get(session_id)
    else:
        stored = await rt.store.get_changed(session_id, cached[0])
    if stored is None:
        rt.states.drop(session_id)
        if token is not None and await _rebuild(rt, session_id, token):
            stored = await rt.store.get(session_id)
        if stored is None:
            raise no_session() if token is not None else _not_live(session_id)
    if isinstance(stored, int):
        assert cached is not None
        version, meta, state = cached
    else:
        meta = SessionMeta.from_bytes(stored.meta)
        version = stored.version
        try:
            state = SessionState.from_bytes(stored.state, get_engine(meta.engine))
            for data in stored.log:  # the engine's steps wait for the next batch
                state = _followed(state, LogEntry.from_bytes(data), rt.settings.replay_window)
        except (StaleEngineState, CodecError) as e:
            # written by an older server (or not a state of this engine): go on from a
            # fresh engine state, as after a rebuild (the next batch is answered
            # reinitialised; a retry of an earlier batch is applied again)
            logger.warning("session %s: engine state not readable (%s), restarted", session_id, e)
            state = _fresh_state(meta, last_seq=-1)
        rt.states.put(session_id, version, meta, state)
    if token is not None and not hmac.compare_digest(meta.token_digest, token_digest(token)):
        raise no_session()
    return version, meta, state


def _followed(state: SessionState, entry: LogEntry, replay_window: int) -> SessionState:
    """``state`` after a logged batch, whose engine step is left pending. Entries follow
    their snapshot seq by seq; anything else (an entry the snapshot already holds, a gap)
    is a log this server did not write, refused as unreadable."""
    if state.last_seq >= 0 and entry.seq != state.last_seq + 1:
        raise CodecError(f"log entry of seq {entry.seq} after a state at seq {state.last_seq}")
    return state.applied(entry, replay_window)


async def check_token(rt: Runtime, session_id: str, token: str) -> None:
    """Refuse a token that opens no live session of this id before anything else of a
    request is read: from this process's copy of the session where it holds one (a
    session's token never changes: no I/O), else from the store (the decoded copy is kept;
    the batch that follows still asks the store whether it changed)."""
    cached = rt.states.get(session_id)
    if cached is None:
        await load_state(rt, session_id, token)
    elif not hmac.compare_digest(cached[1].token_digest, token_digest(token)):
        raise no_session()


def _not_live(session_id: str) -> NotFound:
    return NotFound(f"no live session {session_id} (it ended or expired)", field="session_id")


async def _viewer_key(rt: Runtime, session_id: str, secret: str) -> SessionMeta:
    """The session's meta for an API key that may view the session's site; Forbidden for
    anything else (a device key reads only the sessions it holds the tokens of)."""
    return await site_key(rt, session_id, secret, "viewer")


async def site_key(rt: Runtime, session_id: str, secret: str, scope: str) -> SessionMeta:
    """The session's meta for an API key with ``scope`` for the session's site; Forbidden
    for anything else."""
    async with rt.read() as s:
        principal = await auth.authenticate(s, rt.settings, secret)
    if principal is None:
        raise no_session()
    principal.require(scope)
    stored = await rt.store.get(session_id)
    if stored is None:
        raise _not_live(session_id)
    meta = SessionMeta.from_bytes(stored.meta)
    principal.require(scope, meta.site_id, missing=_not_live(session_id))
    return meta


async def authorize_reader(rt: Runtime, session_id: str, secret: str) -> bool:
    """Let a reader of the session in: True for the session's own token (which may apply
    batches too), False for an API key with the ``viewer`` scope for the session's site
    (which reads and follows only); Forbidden (or NotFound, for such a key and a session
    that is not live) otherwise."""
    try:
        await _load(rt, session_id, secret)
    except Forbidden:
        await _viewer_key(rt, session_id, secret)
        return False
    return True


async def get_session(rt: Runtime, session_id: str, secret: str) -> SessionInfo:
    """The session as its token, or a key that may view its site, sees it (module
    docstring)."""
    try:
        _, meta, state = await load_state(rt, session_id, secret)
    except Forbidden:
        await _viewer_key(rt, session_id, secret)
        _, meta, state = await load_state(rt, session_id, None)
    return SessionInfo(
        id=session_id,
        site_id=meta.site_id,
        engine=meta.engine,
        last_seq=max(state.last_seq, 0),
        last_fix=orjson.loads(state.last_fix) if state.last_fix else None,
        idle_timeout_s=rt.settings.session_idle_s,
    )


async def get_track(rt: Runtime, session_id: str, secret: str, limit: int) -> list[dict[str, Any]]:
    """The session's newest ``limit`` fixes (at most ``session_track_len`` are kept),
    oldest first, for its token or a key that may view its site."""
    await authorize_reader(rt, session_id, secret)
    return [orjson.loads(fix) for fix in await rt.store.track(session_id, limit)]


@dataclass(frozen=True)
class SessionSummary:
    """A session as its SQL row has it (what is known of it without its live state)."""

    id: str
    site_id: str
    engine: str
    contribute: bool
    device_model: str | None
    created_at: datetime
    last_active_at: datetime
    ended_at: datetime | None
    active: bool  # not ended, and active within the last REBUILD_IDLE_FACTOR idle timeouts


async def list_sessions(
    rt: Runtime,
    site_id: str | None,
    active: bool | None,
    after: Key | None,
    limit: int,
) -> Page[SessionSummary]:
    """Sessions newest first (of one site when given; only active or only inactive ones
    with ``active``). An active session is not ended and was active recently enough to be
    live still (``session_records.active_since``)."""
    since = active_since(rt.settings.session_idle_s)
    async with rt.read() as s:
        page = await repo.session_page(s, site_id, since, active, after, limit)
        rows = [
            SessionSummary(
                id=r.id,
                site_id=r.site_id,
                engine=r.engine,
                contribute=r.contribute,
                device_model=r.device_model or None,
                created_at=r.created_at,
                last_active_at=r.last_active_at,
                ended_at=r.ended_at,
                active=r.ended_at is None and r.last_active_at >= since,
            )
            for r in page.rows
        ]
    return Page(rows, page.next_key)


async def end_session(rt: Runtime, session_id: str, token: str) -> str | None:
    """End a session; for a contributing one, its kept batches become one upload first
    (its id is returned; None when nothing was kept)."""
    _, meta, state = await load_state(rt, session_id, token)
    upload_id = None
    if meta.contribute:
        upload_id = await _offer_walk(rt, session_id, meta, state)
    exits = await _leave_zones(rt, session_id, meta, state)
    async with rt.transaction() as s:
        await repo.end_session_record(s, session_id)
    rt.states.drop(session_id)
    await rt.store.delete(session_id)
    if exits:
        message = {"seq": state.last_seq, "fixes": [], "zone_events": exits}
        await rt.store.publish(session_id, orjson.dumps(message))
    await rt.store.publish(session_id, orjson.dumps({"closed": True}))
    return upload_id


async def _leave_zones(
    rt: Runtime, session_id: str, meta: SessionMeta, state: SessionState
) -> list[dict[str, Any]]:
    """The exits of the zones the session ends in, owed to the site's webhooks."""
    if not state.zones:
        return []
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, meta.site_id)
    ended_ms = state.last_event_ms or now_ms()
    exits = exits_at_end(state, maps, ended_ms)
    last_fix = orjson.loads(state.last_fix) if state.last_fix else {}
    await webhooks.owe_events(
        rt, meta.site_id, session_id, state.last_seq, [{**last_fix, "zone_events": exits}]
    )
    return exits


async def _offer_walk(
    rt: Runtime, session_id: str, meta: SessionMeta, state: SessionState
) -> str | None:
    last_fix = orjson.loads(state.last_fix) if state.last_fix else {}
    async with rt.transaction() as s:
        kept = await repo.take_session_batches(s, session_id)
        if not kept:
            return None
        payload = await anyio.to_thread.run_sync(
            lambda: trace_codec.encode_trace(
                join_traces([trace_codec.decode_trace(b) for b in kept])
            )
        )
        new = uploads.NewUpload(
            site_id=meta.site_id,
            building_id=last_fix.get("building_id"),
            floor_level=last_fix.get("floor"),
            device_model=meta.device_model or None,
            content_type=trace_codec.CONTENT_TYPE,
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
