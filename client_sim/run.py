"""Load and accuracy run: simulated walkers posting batches in real time to a deployed stack.

:func:`run_walkers` provisions one synthetic site (building, plans, survey), then runs the
walkers concurrently. Walker ``i`` walks level ``levels[i % n_levels]``, starts
``i / walkers`` of a batch period after the first (to spread the load), creates a session,
opens its live socket and, every ``batch_period_s``, posts the events its phone produced
in that wall-clock interval as the next ``seq`` (1, 2, 3, ...). For every fix in a batch
answer it measures the horizontal error against the walker's true position at the fix's
``t`` (linear between truths) and whether the floor level is right. After
``duration_s`` it waits up to ``DRAIN_S`` for the socket to deliver every fix the batch
answers announced, deletes its session, and gives the server a moment to close the socket.

Errors counted: non-2xx answers, transport failures and other exceptions, error messages
and unexpected closes on the socket. A batch whose fixes never arrive on the socket is
counted apart (``batches_missing_on_socket``), not as an error. A batch that failed
because of the transport, a 5xx, 408 or 429 is sent again, with the same ``seq`` and
events, at the next period (the server applies a ``seq`` once); one refused with any other
4xx is dropped and its ``seq`` reused; 401, 403 and 404 end the walker.

Bounded: walkers stop producing at ``duration_s``; every request has a timeout, and a
walker still busy ``DRAIN_S + 2 * REQUEST_TIMEOUT_S + 5`` s after that is cancelled
(its session is still deleted).
Traffic goes to ``base_url`` only (HTTP and its WebSocket).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import httpx
import numpy as np

from client_sim.api import ApiClient, ApiError, BatchResult, LiveFixes, Session
from client_sim.seeding import sequence
from client_sim.site import ProvisionedSite, provision_site
from client_sim.walker import TimedEvent, TruthTrack, Walker
from client_sim.world import SyntheticWorld, synthesize_world

MAX_EVENTS_PER_BATCH = 2000  # the server's limit per batch
REQUEST_TIMEOUT_S = 30.0
DELETE_TIMEOUT_S = 5.0
DRAIN_S = 2.0
SOCKET_CLOSE_WAIT_S = 1.0
MAX_ERROR_MESSAGES = 10
MAX_CONNECTIONS = 256
RETRYABLE_STATUS = frozenset({408, 429, 500, 502, 503, 504})
FATAL_STATUS = frozenset({401, 403, 404})


@dataclass(frozen=True)
class Summary:
    """What a run measured. ``to_json_dict`` starts with the six headline figures."""

    walkers: int
    fixes: int
    mean_error_m: float | None  # horizontal, over every fix in a batch answer
    p95_error_m: float | None
    ws_messages: int  # fix messages received on the live sockets
    errors: int
    batches: int  # batches answered 2xx
    floor_hit_rate: float | None  # share of fixes on the true level
    batch_latency_p50_ms: float | None
    batch_latency_p95_ms: float | None
    batches_missing_on_socket: int
    sessions: int
    duration_s: float  # wall time from the first walker's start to the last one's end
    engine: str
    site_id: str | None
    error_messages: tuple[str, ...]  # the first few

    def to_json_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["error_messages"] = list(self.error_messages)
        return out


@dataclass
class WalkerStats:
    """What one walker saw; filled in as it goes."""

    horizontal_errors_m: list[float] = field(default_factory=list)
    floor_hits: int = 0
    batches: int = 0
    latencies_ms: list[float] = field(default_factory=list)
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
    walkers: int,
    engine: str,
    site_id: str | None,
    duration_s: float,
) -> Summary:
    """Pool the walkers' figures."""
    errors_m = np.array([e for s in stats for e in s.horizontal_errors_m], dtype=np.float64)
    latencies = np.array([v for s in stats for v in s.latencies_ms], dtype=np.float64)
    messages = [m for s in stats for m in s.errors]

    def stat(values: np.ndarray, q: float | None = None) -> float | None:
        if values.size == 0:
            return None
        return float(np.mean(values) if q is None else np.percentile(values, q))

    return Summary(
        walkers=walkers,
        fixes=int(errors_m.size),
        mean_error_m=stat(errors_m),
        p95_error_m=stat(errors_m, 95),
        ws_messages=sum(s.ws_messages for s in stats),
        errors=len(messages),
        batches=sum(s.batches for s in stats),
        floor_hit_rate=(sum(s.floor_hits for s in stats) / errors_m.size)
        if errors_m.size
        else None,
        batch_latency_p50_ms=stat(latencies, 50),
        batch_latency_p95_ms=stat(latencies, 95),
        batches_missing_on_socket=sum(s.batches_missing_on_socket for s in stats),
        sessions=sum(s.sessions for s in stats),
        duration_s=duration_s,
        engine=engine,
        site_id=site_id,
        error_messages=tuple(messages[:MAX_ERROR_MESSAGES]),
    )


async def run_walkers(
    base_url: str,
    admin_key: str,
    walkers: int,
    duration_s: float,
    seed: int = 0,
    engine: str = "step_ekf",
    on_progress: Callable[[float], None] | None = None,
    batch_period_s: float = 1.0,
) -> Summary:
    """Provision a synthetic site at ``base_url`` and walk ``walkers`` simulated phones
    through it for ``duration_s`` seconds of real time (module docstring).

    ``on_progress(elapsed_s)`` is called about once a second while the walkers walk.
    Provisioning failures raise :class:`ApiError` (or the transport's error); everything
    after that is counted in the summary instead.
    """
    if walkers < 0 or not duration_s > 0 or not batch_period_s > 0:
        raise ValueError("walkers must be >= 0, duration_s and batch_period_s > 0")
    world = synthesize_world(seed)
    pool = min(walkers, MAX_CONNECTIONS) + 4
    async with httpx.AsyncClient(
        base_url=base_url,
        timeout=httpx.Timeout(REQUEST_TIMEOUT_S),
        limits=httpx.Limits(max_connections=pool, max_keepalive_connections=pool),
    ) as http:
        api = ApiClient(http, admin_key)
        site = await provision_site(api, world.building, seed, world=world)
        loop = asyncio.get_running_loop()
        start = loop.time()
        stats = [WalkerStats() for _ in range(walkers)]
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
                            start=start + batch_period_s * i / max(walkers, 1),
                            end=start + duration_s,
                            batch_period_s=batch_period_s,
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
        stats, walkers=walkers, engine=engine, site_id=site.site_id, duration_s=elapsed
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
    start: float  # event-loop time the walker starts
    end: float  # event-loop time every walker stops producing
    batch_period_s: float


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
            try:
                live = await stack.enter_async_context(LiveFixes.open(plan.base_url, session))
            except Exception as exc:  # refused, unreachable, timed out: walk on without it
                stats.errors.append(f"{name}: live socket: {type(exc).__name__}: {exc}")
            expected = await _post_batches(plan, session, stats)
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


async def _post_batches(plan: _WalkPlan, session: Session, stats: WalkerStats) -> dict[int, int]:
    """Post the walk in real time; the number of fixes each acknowledged ``seq`` carried."""
    loop = asyncio.get_running_loop()
    name = f"walker {plan.index}"
    levels = plan.world.building.levels
    walker = Walker(
        plan.world,
        levels[plan.index % len(levels)],
        sequence(plan.seed, "walker", plan.index),
        t0_ms=int(time.time() * 1000),
    )
    walk_start = loop.time()
    walk_end_s = plan.end - walk_start  # seconds of walk this walker produces
    events = _Peekable(walker.events())
    track = TruthTrack()
    queue: deque[tuple[int, list[dict[str, Any]]]] = deque()
    next_seq = 1
    expected: dict[int, int] = {}
    tick = 0
    while True:
        tick += 1
        upto_s = min(tick * plan.batch_period_s, walk_end_s)
        await asyncio.sleep(max(0.0, walk_start + upto_s - loop.time()))
        produced: list[dict[str, Any]] = []
        while events.peek().sim_s <= upto_s:
            timed = events.pop()
            track.add(timed.truth)
            produced.append(timed.event)
        for i in range(0, len(produced), MAX_EVENTS_PER_BATCH):
            queue.append((next_seq, produced[i : i + MAX_EVENTS_PER_BATCH]))
            next_seq += 1
        while queue:
            seq, batch = queue[0]
            sent = loop.time()
            try:
                result = await plan.api.post_batch(session, seq, batch)
            except ApiError as exc:
                stats.errors.append(f"{name}: batch seq {seq}: {_describe(exc)}")
                if exc.status in RETRYABLE_STATUS:
                    break
                if exc.status in FATAL_STATUS:
                    return expected
                queue.popleft()  # refused as it is: drop it and give its seq to the next
                queue = deque((s - 1, b) for s, b in queue)
                next_seq -= 1
                continue
            except httpx.HTTPError as exc:
                stats.errors.append(f"{name}: batch seq {seq}: {_describe(exc)}")
                break
            queue.popleft()
            stats.batches += 1
            stats.latencies_ms.append(1000.0 * (loop.time() - sent))
            stats.add_fixes(result, track)
            if result.fixes:
                expected[seq] = len(result.fixes)
        if upto_s >= walk_end_s:
            return expected


class _Peekable:
    def __init__(self, it: Iterator[TimedEvent]) -> None:
        self._it = it
        self._next = next(it)

    def peek(self) -> TimedEvent:
        return self._next

    def pop(self) -> TimedEvent:
        out, self._next = self._next, next(self._it)
        return out


def _describe(exc: BaseException) -> str:
    if isinstance(exc, ApiError):
        return f"{exc.status} {exc.message}"
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
