"""Positioning sessions: create, apply a batch of events exactly once, read, end, follow live.

A session is one record in the session store: immutable meta (site, engine, token digest,
RNG entropy), a snapshot of its state (the engine state, the last applied ``seq``, the
replies of the last few batches, so a retried ``seq`` gets the same answer, and the last
fix) and the log of the batches applied since (``session_records``). A batch's write
appends the batch and its answer to the log (a few hundred bytes); every
``SNAPSHOT_EVERY``-th ``seq`` writes a snapshot instead, which empties the log. A process
holding the session's newest state (it wrote it) steps on from it; any other reads the
snapshot and the log and steps the engine through the logged batches first, with the
session's random stream, so it goes on from the state the writer had. Writes are
compare-and-set on the record's version, so two replicas applying batches to one session
at once never overwrite each other: the loser re-reads and re-applies.

Batches apply strictly in ``seq`` order (1, 2, 3, ...). A batch that arrives before its
predecessor waits up to ``seq_wait_s`` for it, then is refused with 409. A batch whose
event times stray more than ``max_event_skew_s`` from the session's newest so far (or
from each other) is refused whole, its seq still free (``check_event_times``).

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
import enum
import hashlib
import hmac
import logging
import secrets
import time
import uuid
from collections.abc import AsyncIterator, Mapping, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

import anyio
import numpy as np
import orjson

from server.positioning.engines import NEEDS_GRAPHS, get_engine
from server.positioning.events import (
    BleEvent,
    Event,
    Fix,
    GnssEvent,
    ImuEvent,
    MagEvent,
    StepEvent,
    WifiEvent,
)
from server.positioning.params import Params
from server.positioning.sitemaps import SiteMaps
from server.services import auth, engine_settings, limits, telemetry, traces, uploads
from server.services.device_offsets import on_common_level
from server.services.errors import Conflict, Forbidden, Invalid, NotFound
from server.services.maps import site_maps, with_graphs
from server.services.runtime import Runtime
from server.services.session_records import (
    REBUILD_IDLE_FACTOR,
    LogEntry,
    SessionMeta,
    SessionState,
    StaleEngineState,
    active_since,
    events_digest,
    fix_to_wire,
)
from server.storage.codec import CodecError
from server.storage.models import SessionRecord, utcnow
from server.storage.repositories import sessions as repo
from server.storage.repositories.pages import Key, Page
from server.storage.session_store import BucketEmpty, SessionExists, StoredSession

logger = logging.getLogger(__name__)
SEQ_POLL_S = 0.01
INLINE_MAX_STEPS = 2  # batches with more steps, or any raw samples, run in a worker thread
INLINE_MAX_EVENTS = 32
# a snapshot of the state at every seq divisible by this (else a log entry): a process that
# takes a session over steps the engine through at most this many logged batches first
SNAPSHOT_EVERY = 16
# the wire's name of each event kind (what an engine's ``uses`` holds)
EVENT_KINDS: dict[type, str] = {
    StepEvent: "step",
    WifiEvent: "wifi",
    BleEvent: "ble",
    MagEvent: "mag",
    ImuEvent: "imu",
    GnssEvent: "gnss",
}


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
    fixes: bytes  # a JSON array of FixOut, encoded once for the answer, track and live
    reinitialised: bool = False  # the session was rebuilt before this batch
    not_used: tuple[str, ...] = ()  # event kinds of the batch the engine does not read
    made: int = 0  # fixes this batch made (a replay's were counted when they were made)


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
            _digest(token),
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
            raise _no_session() if token is not None else _not_live(session_id)
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
    if token is not None and not hmac.compare_digest(meta.token_digest, _digest(token)):
        raise _no_session()
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
        await _load_decoded(rt, session_id, token)
    elif not hmac.compare_digest(cached[1].token_digest, _digest(token)):
        raise _no_session()


def _not_live(session_id: str) -> NotFound:
    return NotFound(f"no live session {session_id} (it ended or expired)", field="session_id")


async def _viewer_key(rt: Runtime, session_id: str, secret: str) -> SessionMeta:
    """The session's meta for an API key that may view the session's site; Forbidden for
    anything else (a device key reads only the sessions it holds the tokens of)."""
    async with rt.read() as s:
        principal = await auth.authenticate(s, rt.settings, secret)
    if principal is None:
        raise _no_session()
    principal.require("viewer")
    stored = await rt.store.get(session_id)
    if stored is None:
        raise _not_live(session_id)
    meta = SessionMeta.from_bytes(stored.meta)
    principal.require("viewer", meta.site_id, missing=_not_live(session_id))
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
    With ``address``, the batch counts against the address's rate limit once the token
    is known good, and against the session's by the write that applies it (a refused
    batch is not applied; ``services.limits``)."""
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
    READ = "this process's copy of the session needs the store's word"


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
    # one round trip to the store where this process wrote the session last: the
    # compare-and-set below refuses a stale version (then _Retry.LOST reads it again);
    # anything answered without a write (a replay, a wait) asks the store first
    trusted = rt.states.current(session_id)
    if trusted is None:
        version, meta, state = await _load_decoded(rt, session_id, token)
    else:
        version, meta, state = trusted
        if not hmac.compare_digest(meta.token_digest, _digest(token)):
            raise _no_session()
    if charge is not None:
        limits.check_batch(rt, session_id, charge)
    spec = get_engine(meta.engine)
    not_used = not_read(spec.uses, events)
    rebuilt = state.last_seq < 0  # the first batch after a rebuild: its seq is the next one
    if trusted is not None and seq != state.last_seq + 1:
        rt.states.put(session_id, version, meta, state)  # no longer trusted: read it
        return _Retry.READ
    if seq <= state.last_seq:
        return _replay(state, seq, digest, not_used)
    if seq > state.last_seq + 1 and not rebuilt:
        if time.monotonic() >= deadline:
            raise Conflict(
                f"seq {seq} arrived before seq {state.last_seq + 1}; send that one first",
                field="seq",
            )
        return _Retry.WAIT
    check_event_times(events, state.last_event_ms, 1000 * rt.settings.max_event_skew_s)
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
    params = engine_settings.session_params(meta.engine, meta.params)
    scans_level = maps.device_offsets.get(meta.device_model)
    run = telemetry.timed_engine(meta.engine, spec.step)

    def step() -> tuple[object, Sequence[Fix]]:
        engine_state = caught_up(state, meta, maps, params)
        return run(
            engine_state, on_common_level(events, scans_level), maps, params, _rng(meta, seq)
        )

    try:
        if _runs_inline(events) and not state.pending:
            new_engine_state, fixes = step()
        else:
            new_engine_state, fixes = await anyio.to_thread.run_sync(step)
    except BaseException:
        rt.states.drop(session_id)  # never reuse a state an engine failed on
        raise
    wire = [fix_to_wire(f, maps, meta.engine) for f in fixes]
    each = [orjson.dumps(f) for f in wire]  # for the track; the reply is their list
    body = b"[" + b",".join(each) + b"]"
    now_ms = _now_ms()
    touch = now_ms - state.touched_ms > 500 * rt.settings.session_idle_s  # half the timeout
    entry = LogEntry(
        seq,
        digest,
        tuple(events),
        body,
        each[-1] if each else b"",
        now_ms if touch else state.touched_ms,
    )
    # step() stepped through the logged batches: the new state holds them
    new_state = replace(state, pending=()).applied(
        entry, rt.settings.replay_window, new_engine_state
    )
    live = orjson.dumps({"seq": seq, "fixes": orjson.Fragment(body)}) if wire else None
    # a snapshot every SNAPSHOT_EVERY seqs; and at once after a restart (the log behind the
    # old snapshot is not this state's) or after stepping through a log (so that a session
    # going back and forth between processes is not stepped through it again and again)
    snapshot = rebuilt or bool(state.pending) or seq % SNAPSHOT_EVERY == 0
    try:
        ok = await rt.store.compare_and_set(
            session_id,
            version,
            new_state.to_bytes(spec) if snapshot else None,
            rt.settings.session_idle_s,
            live,
            track=each,
            track_len=rt.settings.session_track_len,
            allowance=limits.batch_allowance(rt),
            entry=None if snapshot else entry.to_bytes(),
        )
    except BucketEmpty as e:  # not applied: the seq stays free
        raise limits.session_bucket_empty(rt, session_id, e.wait_s) from None
    if ok:
        rt.states.put(session_id, version + 1, meta, new_state, written=True)
        if touch:  # the row says the session is alive, should the store lose it
            async with rt.transaction() as s:
                await repo.touch_session_record(s, session_id)
        return BatchResult(
            seq, False, body, reinitialised=rebuilt, not_used=not_used, made=len(wire)
        )
    rt.states.drop(session_id)
    return _Retry.LOST  # another writer got there first: read the new state and try again


def check_event_times(events: Sequence[Event], last_event_ms: int, skew_ms: float) -> None:
    """Refuse a batch (Invalid naming ``events.N.t``, before anything of it is applied)
    with an event more than ``skew_ms`` either way from the newest event time the session
    has accepted (``last_event_ms``; 0: none yet), or whose events span more than
    ``skew_ms``: a clock that jumps by days is a client's bug, not a walk, and the engines
    would take the jump for one time step.

    The server's clock bounds nothing here: replays of recorded logs (``indoorpos evaluate
    --via-http``, ``client_sim``) post their original times, years ago. The wire keeps
    every time in 2000-2099 (``api.schemas.common.TimestampMs``)."""
    times = [e.t_ms for e in events]
    lo = hi = times[0] if times else 0
    for i, t in enumerate(times):
        if last_event_ms and abs(t - last_event_ms) > skew_ms:
            side = "before" if t < last_event_ms else "after"
            raise Invalid(
                f"{t} lies {abs(t - last_event_ms) / 1000:g} s {side} the newest event time "
                f"the session has accepted ({last_event_ms}); at most {skew_ms / 1000:g} s",
                field=f"events.{i}.t",
            )
        lo, hi = min(lo, t), max(hi, t)
        if hi - lo > skew_ms:
            raise Invalid(
                f"the batch's events up to this one span {(hi - lo) / 1000:g} s "
                f"({lo} to {hi}); at most {skew_ms / 1000:g} s",
                field=f"events.{i}.t",
            )


def caught_up(state: SessionState, meta: SessionMeta, maps: SiteMaps, params: Params) -> object:
    """The engine state after the logged batches ``state`` holds that its engine has not
    been stepped through (``state.pending``), each with its own random stream."""
    spec = get_engine(meta.engine)
    scans_level = maps.device_offsets.get(meta.device_model)
    engine_state = state.engine_state
    for entry in state.pending:
        events = on_common_level(entry.events, scans_level)
        engine_state, _ = spec.step(engine_state, events, maps, params, _rng(meta, entry.seq))
    return engine_state


def _rng(meta: SessionMeta, seq: int) -> np.random.Generator:
    """The random stream of batch ``seq`` of the session: the same in every process."""
    return np.random.default_rng(np.random.SeedSequence(meta.entropy, spawn_key=(seq,)))


def _runs_inline(events: Sequence[Event]) -> bool:
    """Whether the engine runs on the event loop rather than in a worker thread: for a
    small batch without raw motion samples (a step or two and their scans, about a
    millisecond per step at N = 3000; the barometer's few rows cost little), the hop to a
    thread and back costs more than it spares the loop."""
    if len(events) > INLINE_MAX_EVENTS or any(
        isinstance(e, ImuEvent) and e.has_motion for e in events
    ):
        return False
    return sum(isinstance(e, StepEvent) for e in events) <= INLINE_MAX_STEPS


def not_read(uses: frozenset[str], events: Sequence[Event]) -> tuple[str, ...]:
    """The kinds of ``events`` an engine that reads ``uses`` ignores, sorted (for
    ``auto``: what none of the engines it may pick reads)."""
    kinds = set()
    for e in events:
        if isinstance(e, ImuEvent):  # a block's motion rows and its barometer's apart
            kinds |= {"imu"} if e.has_motion else set()
            kinds |= {"pressure"} if e.pressure.shape[0] else set()
        else:
            kinds.add(EVENT_KINDS.get(type(e), type(e).__name__))
    return tuple(sorted(kinds - uses))


def _replay(
    state: SessionState, seq: int, digest: bytes, not_used: tuple[str, ...] = ()
) -> BatchResult:
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
            return BatchResult(seq, True, reply.body, reinitialised, not_used)
    raise Conflict(
        f"seq {seq} was applied long ago and its reply is no longer kept; "
        f"the session is at seq {state.last_seq}",
        field="seq",
    )


async def get_session(rt: Runtime, session_id: str, secret: str) -> SessionInfo:
    """The session as its token, or a key that may view its site, sees it (module
    docstring)."""
    try:
        _, meta, state = await _load_decoded(rt, session_id, secret)
    except Forbidden:
        await _viewer_key(rt, session_id, secret)
        _, meta, state = await _load_decoded(rt, session_id, None)
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
