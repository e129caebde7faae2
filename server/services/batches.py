"""A batch of a session's events, applied exactly once (``services.sessions`` has the
session's record: its snapshot, its log and who may do what).

Batches apply strictly in ``seq`` order (1, 2, 3, ...). A batch that arrives before its
predecessor waits up to ``seq_wait_s`` for it, then is refused with 409. A retried ``seq``
gets the reply it got (from the replies the state keeps), without being applied again. A
batch whose event times stray more than ``max_event_skew_s`` from the session's newest so
far (or from each other) is refused whole, its seq still free (``check_event_times``).

Applying one is a read (this process's copy, when it wrote the session last, else the
store's snapshot and log), a decision by ``seq`` (replay, wait or apply), the engine's
step (after the logged steps this process has not taken, ``caught_up``), and one write:
the compare-and-set that takes the session's rate-limit token, appends the batch to the
log (or writes a snapshot) and publishes the fixes. A write that lost to another
replica's is read again and applied again.
"""

from __future__ import annotations

import enum
import hmac
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import anyio
import numpy as np
import orjson

from server.positioning.engines.registry import NEEDS_GRAPHS, get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model.events import (
    BleEvent,
    Event,
    Fix,
    GnssEvent,
    ImuEvent,
    MagEvent,
    StepEvent,
    WifiEvent,
)
from server.positioning.model.params import Params
from server.positioning.model.walk import trace_from_events
from server.positioning.plan import zone_presence
from server.services import engine_settings, limits, navigation_state, telemetry, webhooks
from server.services.device_offsets import on_common_level
from server.services.errors import Conflict, Invalid
from server.services.maps import site_maps, with_graphs
from server.services.runtime import Runtime
from server.services.session_records import (
    LogEntry,
    SessionMeta,
    SessionState,
    events_digest,
    fix_places,
    fix_to_wire,
    navigation_delta,
    presence_from_bytes,
    presence_to_bytes,
)
from server.services.sessions import load_state, no_session, now_ms, token_digest
from server.storage import trace_codec
from server.storage.repositories import sessions as repo
from server.storage.session_store import BucketEmpty

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
class BatchResult:
    seq: int
    replayed: bool
    fixes: bytes  # a JSON array of FixOut, encoded once for the answer, track and live
    reinitialised: bool = False  # the session was rebuilt before this batch
    not_used: tuple[str, ...] = ()  # event kinds of the batch the engine does not read
    made: int = 0  # fixes this batch made (a replay's were counted when they were made)


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
    would stretch every one's latency by the others' work (each awaits the store once or
    twice);
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
        version, meta, state = await load_state(rt, session_id, token)
    else:
        version, meta, state = trusted
        if not hmac.compare_digest(meta.token_digest, token_digest(token)):
            raise no_session()
    if charge is not None:
        limits.check_batch(rt, session_id, charge)
    spec = get_engine(meta.engine)
    not_used = not_read(spec.uses, events)
    rebuilt = state.last_seq < 0  # the first batch after a rebuild: its seq is the next one
    if trusted is not None and seq != state.last_seq + 1:
        rt.states.put(session_id, version, meta, state)  # no longer trusted: read it
        return _Retry.READ
    if seq <= state.last_seq:
        replayed = _replay(state, seq, digest, not_used)
        if webhooks.has_events(replayed.fixes):  # owed again: the first answer was lost
            await webhooks.owe_events(
                rt, meta.site_id, session_id, seq, orjson.loads(replayed.fixes)
            )
        return replayed
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
                lambda: trace_codec.encode_trace(trace_from_events(events))
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
    presence, in_zones = zone_presence.follow(
        presence_from_bytes(state.zones), fix_places(fixes), maps.zones, _dwell(rt)
    )
    navigation, guidance = await navigation_state.navigate(maps, state.navigation, fixes)
    wire = [fix_to_wire(f, maps, meta.engine, z) for f, z in zip(fixes, in_zones, strict=True)]
    for fix_wire, guide in zip(wire, guidance, strict=True):
        if guide is not None:
            fix_wire["navigation"] = guide
    each = [orjson.dumps(f) for f in wire]  # for the track; the reply is their list
    body = b"[" + b",".join(each) + b"]"
    now = now_ms()
    touch = now - state.touched_ms > 500 * rt.settings.session_idle_s  # half the timeout
    entry = LogEntry(
        seq,
        digest,
        tuple(events),
        body,
        each[-1] if each else b"",
        now if touch else state.touched_ms,
        presence_to_bytes(presence),
        navigation_delta(state.navigation, navigation),
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
        rt.history.record(session_id, seq, meta.site_id, wire, body)  # written within ~1 s
        # owed before the batch is answered
        if any(z.events for z in in_zones) or any(g and g["events"] for g in guidance):
            await webhooks.owe_events(rt, meta.site_id, session_id, seq, wire)
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


def _dwell(rt: Runtime) -> zone_presence.Dwell:
    return zone_presence.Dwell(rt.settings.zone_dwell_s, rt.settings.zone_dwell_m)


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
