"""Load and accuracy run: simulated walkers posting their steps in real time to a deployed stack.

:func:`run_walkers` provisions one synthetic site (building, plans, survey) or reuses one
made before, then runs the walkers concurrently on one event loop. Walker ``i`` walks level
``levels[i % n_levels]``, takes a step every ``step_period_s`` on average (each step
jittered by ``N(0, STEP_JITTER_SD_S)``), starts ``i / walkers`` of a batch interval (or of
``ramp_s``) after the first, to spread the load, and creates a session. Every
``batch_steps`` steps it sends the events its phone produced since the last batch (the
steps with their magnetometer readings and the WiFi/BLE scans that fell between them) as
the next ``seq`` (1, 2, 3, ...), over HTTP or, with ``transport="ws"``, over the session's
live socket. With ``live_socket`` an HTTP walker also holds the live socket open and counts
the fixes pushed on it. For every fix in a batch answer it measures the horizontal error against the
walker's true position at the fix's ``t`` (linear between truths) and whether the floor
level is right. After ``duration_s`` it waits up to ``DRAIN_S`` for the socket to deliver
every fix the batch answers announced, deletes its session, and gives the server a moment
to close the socket.

Errors counted: non-2xx answers (error messages on the socket), transport failures and
other exceptions, unexpected closes of the socket. A batch whose fixes never arrive on the
socket is counted apart (``batches_missing_on_socket``), not as an error. A batch that
failed with a 5xx, 408 or 429, or over HTTP because of the transport, is sent again, with
the same ``seq`` and events, with the next batch (the server applies a ``seq`` once); one
refused with any other 4xx is dropped and its ``seq`` reused; 401, 403 and 404 end the
walker, and so does a live socket that failed or did not answer in time (``ws``).
Latency is from sending a batch to its answer; failed attempts are not in it.

Bounded: at most ``MAX_WALKERS`` walkers and ``MAX_DURATION_S`` seconds; walkers stop
producing at ``duration_s``; every request has a timeout, and a walker still busy
``DRAIN_S + 2 * REQUEST_TIMEOUT_S + 5`` s after that is cancelled (its session is still
deleted). Traffic goes to ``base_url`` only (HTTP and its WebSocket).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import ssl
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import httpx
import numpy as np

from client_sim.api import ApiClient, ApiError, BatchResult, LiveFixes, Session
from client_sim.seeding import sequence
from client_sim.site import ProvisionedSite, provision_site, reuse_site
from client_sim.walker import TimedEvent, TruthTrack, Walker, WalkerParams
from client_sim.world import SyntheticWorld, synthesize_world

Transport = Literal["http", "ws"]

STEP_PERIOD_S = 0.67  # Shao et al.'s step period (papers/001_*, section IV-B)
STEP_JITTER_SD_S = 0.03
MAX_WALKERS = 20_000
MAX_DURATION_S = 24 * 3600.0
MAX_EVENTS_PER_BATCH = 2000  # the server's limit per batch
REQUEST_TIMEOUT_S = 30.0
DELETE_TIMEOUT_S = 5.0
DRAIN_S = 2.0
SOCKET_CLOSE_WAIT_S = 1.0
MAX_ERROR_MESSAGES = 10
MAX_CONNECTIONS = 256
# an idle connection is dropped before the server's keep-alive timeout (uvicorn: 5 s) can
# close it under a request already on its way
KEEPALIVE_EXPIRY_S = 2.0
RETRYABLE_STATUS = frozenset({408, 429, 500, 502, 503, 504})
FATAL_STATUS = frozenset({401, 403, 404})


@dataclass(frozen=True)
class Summary:
    """What a run measured. ``to_json_dict`` starts with the ten headline figures."""

    users: int
    duration_s: float  # wall time from the first walker's start to the last one's end
    batches: int  # batches answered 2xx
    steps: int  # step events in those batches
    errors: int
    p50_ms: float | None  # batch latency: sent to answered
    p95_ms: float | None
    p99_ms: float | None
    fixes_per_s: float
    mean_error_m: float | None  # horizontal, over every fix in a batch answer
    fixes: int
    p95_error_m: float | None
    floor_hit_rate: float | None  # share of fixes on the true level
    ws_messages: int  # fix messages received on the live sockets
    batches_missing_on_socket: int
    sessions: int
    transport: str
    batch_steps: int
    engine: str
    site_id: str | None
    error_messages: tuple[str, ...]  # the first few
    # p99 batch latency of the batches sent in each minute of the run (soak tests)
    p99_ms_by_minute: tuple[float, ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["error_messages"] = list(self.error_messages)
        out["p99_ms_by_minute"] = list(self.p99_ms_by_minute)
        return out


@dataclass
class WalkerStats:
    """What one walker saw; filled in as it goes."""

    horizontal_errors_m: list[float] = field(default_factory=list)
    floor_hits: int = 0
    batches: int = 0
    steps: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    sent_s: list[float] = field(default_factory=list)  # when each batch was sent, in the run
    ws_messages: int = 0
    batches_missing_on_socket: int = 0
    sessions: int = 0
    errors: list[str] = field(default_factory=list)

    def add_fixes(self, result: BatchResult, track: TruthTrack) -> None:
        for fix in result.fixes:
            x, y, level = track.at(fix.t)
            self.horizontal_errors_m.append(math.hypot(fix.x_m - x, fix.y_m - y))
            self.floor_hits += fix.floor == level


def summarize(
    stats: Sequence[WalkerStats],
    *,
    users: int,
    engine: str,
    site_id: str | None,
    duration_s: float,
    transport: str = "http",
    batch_steps: int = 1,
) -> Summary:
    """Pool the walkers' figures."""
    errors_m = np.array([e for s in stats for e in s.horizontal_errors_m], dtype=np.float64)
    latencies = np.array([v for s in stats for v in s.latencies_ms], dtype=np.float64)
    sent = np.array([v for s in stats for v in s.sent_s], dtype=np.float64)
    messages = [m for s in stats for m in s.errors]

    def stat(values: np.ndarray, q: float | None = None) -> float | None:
        if values.size == 0:
            return None
        return float(np.mean(values) if q is None else np.percentile(values, q))

    return Summary(
        users=users,
        duration_s=duration_s,
        batches=sum(s.batches for s in stats),
        steps=sum(s.steps for s in stats),
        errors=len(messages),
        p50_ms=stat(latencies, 50),
        p95_ms=stat(latencies, 95),
        p99_ms=stat(latencies, 99),
        fixes_per_s=errors_m.size / duration_s if duration_s > 0 else 0.0,
        mean_error_m=stat(errors_m),
        fixes=int(errors_m.size),
        p95_error_m=stat(errors_m, 95),
        floor_hit_rate=(sum(s.floor_hits for s in stats) / errors_m.size)
        if errors_m.size
        else None,
        ws_messages=sum(s.ws_messages for s in stats),
        batches_missing_on_socket=sum(s.batches_missing_on_socket for s in stats),
        sessions=sum(s.sessions for s in stats),
        transport=transport,
        batch_steps=batch_steps,
        engine=engine,
        site_id=site_id,
        error_messages=tuple(messages[:MAX_ERROR_MESSAGES]),
        p99_ms_by_minute=_p99_by_minute(sent, latencies),
    )


def _p99_by_minute(sent_s: np.ndarray, latencies_ms: np.ndarray) -> tuple[float, ...]:
    """p99 latency of the batches sent in minute 0, 1, 2, ... of the run (skipping empty
    minutes); empty without send times."""
    if sent_s.size == 0 or sent_s.size != latencies_ms.size:
        return ()
    minute = np.floor(sent_s / 60.0).astype(np.int64)
    return tuple(
        float(np.percentile(latencies_ms[minute == m], 99)) for m in np.unique(minute).tolist()
    )


async def run_walkers(
    base_url: str,
    admin_key: str,
    walkers: int,
    duration_s: float,
    seed: int = 0,
    engine: str = "step_ekf",
    on_progress: Callable[[float], None] | None = None,
    batch_steps: int = 1,
    transport: Transport = "http",
    live_socket: bool = True,
    step_period_s: float = STEP_PERIOD_S,
    site_id: str | None = None,
    ramp_s: float | None = None,
) -> Summary:
    """Walk ``walkers`` simulated phones through a synthetic site at ``base_url`` for
    ``duration_s`` seconds of real time (module docstring).

    The site is the one ``site_id`` names (it must have been provisioned with the same
    ``seed``), else one provisioned now. The walkers' starts are spread evenly over
    ``ramp_s`` seconds (default: one batch interval). ``on_progress(elapsed_s)`` is called
    about once a second while the walkers walk. Provisioning failures raise
    :class:`ApiError` (or the transport's error); everything after that is counted in the
    summary instead.
    """
    if not 0 <= walkers <= MAX_WALKERS:
        raise ValueError(f"walkers must be in [0, {MAX_WALKERS}]")
    if not 0 < duration_s <= MAX_DURATION_S:
        raise ValueError(f"duration_s must be in (0, {MAX_DURATION_S:.0f}]")
    if batch_steps < 1 or not step_period_s > 0:
        raise ValueError("batch_steps must be >= 1 and step_period_s > 0")
    if ramp_s is not None and not 0 <= ramp_s < duration_s:
        raise ValueError("ramp_s must be in [0, duration_s)")
    if transport not in ("http", "ws"):
        raise ValueError("transport must be 'http' or 'ws'")
    world = synthesize_world(seed)
    pool = min(walkers, MAX_CONNECTIONS) + 4
    async with httpx.AsyncClient(
        base_url=base_url,
        timeout=httpx.Timeout(REQUEST_TIMEOUT_S),
        limits=httpx.Limits(
            max_connections=pool,
            max_keepalive_connections=pool,
            keepalive_expiry=KEEPALIVE_EXPIRY_S,
        ),
    ) as http:
        api = ApiClient(http, admin_key)
        if site_id is None:
            site = await provision_site(api, world.building, seed, world=world)
        else:
            site = await reuse_site(api, site_id, world)
        loop = asyncio.get_running_loop()
        start = loop.time()
        stats = [WalkerStats() for _ in range(walkers)]
        params = walker_params(step_period_s)
        tls = ssl.create_default_context()
        spread_s = batch_steps * step_period_s if ramp_s is None else ramp_s
        progress = asyncio.create_task(_report_progress(on_progress, start, duration_s))
        try:
            await asyncio.gather(
                *(
                    _guarded_walk(
                        _WalkPlan(
                            api=api,
                            base_url=base_url,
                            site=site,
                            world=world,
                            index=i,
                            seed=seed,
                            engine=engine,
                            run_start=start,
                            start=start + spread_s * i / max(walkers, 1),
                            end=start + duration_s,
                            batch_steps=batch_steps,
                            transport=transport,
                            live_socket=live_socket or transport == "ws",
                            params=params,
                            tls=tls,
                        ),
                        stats[i],
                    )
                    for i in range(walkers)
                )
            )
        finally:
            progress.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await progress
        elapsed = loop.time() - start
        if on_progress is not None:
            on_progress(min(elapsed, duration_s))
    return summarize(
        stats,
        users=walkers,
        engine=engine,
        site_id=site.site_id,
        duration_s=elapsed,
        transport=transport,
        batch_steps=batch_steps,
    )


async def _report_progress(
    on_progress: Callable[[float], None] | None, start: float, duration_s: float
) -> None:
    if on_progress is None:
        return
    loop = asyncio.get_running_loop()
    while True:
        on_progress(min(loop.time() - start, duration_s))
        await asyncio.sleep(1.0)


@dataclass(frozen=True)
class _WalkPlan:
    api: ApiClient
    base_url: str
    site: ProvisionedSite
    world: SyntheticWorld
    index: int
    seed: int
    engine: str
    run_start: float  # event-loop time the run started
    start: float  # event-loop time the walker starts
    end: float  # event-loop time every walker stops producing
    batch_steps: int
    transport: Transport
    live_socket: bool
    params: WalkerParams
    tls: ssl.SSLContext  # shared by the walkers' own connections


async def _guarded_walk(plan: _WalkPlan, stats: WalkerStats) -> None:
    """One walker, cancelled if it is still busy well after the end; never raises."""
    name = f"walker {plan.index}"
    try:
        async with asyncio.timeout_at(plan.end + DRAIN_S + 2 * REQUEST_TIMEOUT_S + 5.0):
            await _walk(plan, stats)
    except TimeoutError:
        stats.errors.append(f"{name}: still busy long after the end; cancelled")
    except Exception as exc:  # a bug or an unexpected failure: count it, keep the others
        stats.errors.append(f"{name}: {type(exc).__name__}: {exc}")


async def _walk(plan: _WalkPlan, stats: WalkerStats) -> None:
    loop = asyncio.get_running_loop()
    name = f"walker {plan.index}"
    await asyncio.sleep(max(0.0, plan.start - loop.time()))
    if loop.time() >= plan.end:
        return
    try:
        session = await plan.api.create_session(plan.site.site_id, plan.engine)
    except (ApiError, httpx.HTTPError) as exc:
        stats.errors.append(f"{name}: create session: {_describe(exc)}")
        return
    stats.sessions += 1
    deleted = False

    async def end_session() -> None:
        nonlocal deleted
        deleted = True
        try:
            await asyncio.wait_for(plan.api.delete_session(session), DELETE_TIMEOUT_S)
        except (ApiError, httpx.HTTPError, TimeoutError) as exc:
            stats.errors.append(f"{name}: delete session: {_describe(exc)}")

    try:
        async with contextlib.AsyncExitStack() as stack:
            live: LiveFixes | None = None
            if plan.live_socket:
                try:
                    live = await stack.enter_async_context(LiveFixes.open(plan.base_url, session))
                except Exception as exc:  # refused, unreachable, timed out
                    stats.errors.append(f"{name}: live socket: {type(exc).__name__}: {exc}")
                    if plan.transport == "ws":
                        return
            own = _own_connection(plan.base_url, plan.tls)
            phone = ApiClient(await stack.enter_async_context(own))
            expected = await _post_batches(plan, phone, session, stats, live)
            if live is not None:
                await live.wait_for(expected, DRAIN_S)
            await end_session()
            if live is not None:
                # the server closes the socket when the session ends; give it a moment
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(live.closed.wait(), SOCKET_CLOSE_WAIT_S)
                stats.ws_messages = live.fix_messages
                stats.batches_missing_on_socket = sum(
                    1 for s, n in expected.items() if live.fixes_by_seq[s] < n
                )
                stats.errors.extend(f"{name}: {e}" for e in live.errors)
    finally:
        if not deleted:
            await end_session()


def _own_connection(base_url: str, tls: ssl.SSLContext) -> httpx.AsyncClient:
    """A walker's own HTTP client, holding one connection as a phone does. (One pool
    shared by hundreds of walkers costs the simulator more than the server: the pool looks
    at each of its connections for every request.) ``tls`` is shared by all: a client
    making its own reads the CA bundle, some 20 ms of the simulator's loop each."""
    return httpx.AsyncClient(
        base_url=base_url,
        verify=tls,
        timeout=httpx.Timeout(REQUEST_TIMEOUT_S),
        limits=httpx.Limits(
            max_connections=1, max_keepalive_connections=1, keepalive_expiry=KEEPALIVE_EXPIRY_S
        ),
    )


async def _post_batches(
    plan: _WalkPlan,
    phone: ApiClient,
    session: Session,
    stats: WalkerStats,
    live: LiveFixes | None,
) -> dict[int, int]:
    """Post the walk in real time, over ``phone`` (the walker's own connection); the
    number of fixes each acknowledged ``seq`` carried."""
    loop = asyncio.get_running_loop()
    name = f"walker {plan.index}"
    walker = simulated_walker(
        plan.world, plan.seed, plan.index, int(time.time() * 1000), plan.params
    )
    walk_start = loop.time()
    walk_end_s = plan.end - walk_start  # seconds of walk this walker produces
    batches = step_batches(walker.events(), plan.batch_steps)
    track = TruthTrack()
    queue: deque[tuple[int, list[dict[str, Any]], int]] = deque()  # seq, events, steps
    next_seq = 1
    expected: dict[int, int] = {}
    while True:
        due_s, timed = next(batches)
        if due_s > walk_end_s:
            return expected
        await asyncio.sleep(max(0.0, walk_start + due_s - loop.time()))
        for item in timed:
            track.add(item.truth)
        produced = [item.event for item in timed]
        for i in range(0, len(produced), MAX_EVENTS_PER_BATCH):
            part = produced[i : i + MAX_EVENTS_PER_BATCH]
            queue.append((next_seq, part, sum(e["type"] == "step" for e in part)))
            next_seq += 1
        while queue:
            seq, batch, steps = queue[0]
            sent = loop.time()
            try:
                if plan.transport == "ws":
                    assert live is not None
                    result = await live.post_batch(seq, batch, REQUEST_TIMEOUT_S)
                else:
                    result = await phone.post_batch(session, seq, batch)
            except ApiError as exc:
                stats.errors.append(f"{name}: batch seq {seq}: {_describe(exc)}")
                if exc.status in RETRYABLE_STATUS:
                    break
                if exc.status in FATAL_STATUS:
                    return expected
                queue.popleft()  # refused as it is: drop it and give its seq to the next
                queue = deque((s - 1, b, n) for s, b, n in queue)
                next_seq -= 1
                continue
            except (httpx.HTTPError, OSError, TimeoutError) as exc:
                stats.errors.append(f"{name}: batch seq {seq}: {_describe(exc)}")
                if plan.transport == "ws":
                    return expected  # the socket is gone: nothing more can be sent
                break
            queue.popleft()
            stats.batches += 1
            stats.steps += steps
            stats.latencies_ms.append(1000.0 * (loop.time() - sent))
            stats.sent_s.append(sent - plan.run_start)
            stats.add_fixes(result, track)
            if result.fixes:
                expected[seq] = len(result.fixes)


def walker_params(step_period_s: float = STEP_PERIOD_S) -> WalkerParams:
    """Walkers stepping every ``step_period_s`` on average, each step jittered."""
    return WalkerParams(
        step_period_s=(step_period_s, step_period_s), step_period_sd_s=STEP_JITTER_SD_S
    )


def simulated_walker(
    world: SyntheticWorld, seed: int, index: int, t0_ms: int, params: WalkerParams
) -> Walker:
    """Walker ``index`` of a run with ``seed``: on level ``levels[index % n_levels]``."""
    levels = world.building.levels
    return Walker(
        world, levels[index % len(levels)], sequence(seed, "walker", index), t0_ms, params
    )


def step_batches(
    events: Iterator[TimedEvent], steps: int
) -> Iterator[tuple[float, list[TimedEvent]]]:
    """Cut the walk's events into batches of ``steps`` steps: each batch with when it is
    due (seconds into the walk: its last step, with that step's magnetometer reading)."""
    pending: list[TimedEvent] = []
    counted = 0
    due = math.inf
    for item in events:
        if item.sim_s > due:
            yield due, pending
            pending, counted, due = [], 0, math.inf
        pending.append(item)
        if item.event["type"] == "step":
            counted += 1
            if counted == steps:
                due = item.sim_s
    raise AssertionError("a walk has no end")


def _describe(exc: BaseException) -> str:
    if isinstance(exc, ApiError):
        return f"{exc.status} {exc.message}"
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
