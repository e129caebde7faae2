"""Prometheus metrics of the service: the one place they are defined.

Every metric lives on prometheus_client's default registry:

- ``indoorpos_http_request_duration_seconds{method, route, status}`` (histogram): every
  HTTP request but ``/metrics``, labelled with the matched route *template*
  (``/v1/sessions/{session_id}/batches``; ``unmatched`` when no route matched), never
  the raw path, so session ids never become label values.
- ``indoorpos_batches_total{transport, outcome}``: batches answered over ``http`` or
  ``ws``, ``applied`` or ``replayed`` (a retried ``seq``).
- ``indoorpos_steps_total``, ``indoorpos_fixes_total``: step events in, fixes out, of
  applied batches (steps the server finds in raw samples are not counted).
- ``indoorpos_engine_step_seconds{engine}`` (histogram): one engine run over one batch,
  timed where it runs (on the event loop for small batches, else in a worker thread).
- ``indoorpos_active_sessions`` (gauge): sessions *this process* opened or served a
  batch for within ``session_idle_s``, less those ended with DELETE. Each process knows
  only its own sessions; a session served by two replicas counts in both.
- ``indoorpos_store_errors_total{store}``: failures talking to the ``session`` store,
  the ``sql`` database or the upload ``queue`` (see :func:`store_of`).

Multi-process: with ``PROMETHEUS_MULTIPROC_DIR`` set (to an empty directory, wiped before
the server starts) prometheus_client keeps values in files there and :func:`exposition`
gathers every process's through a ``MultiProcessCollector`` over a fresh registry (the
documented way); the process and platform collectors are then absent. The active-session
gauge is then the sum over live processes (``livesum``), each refreshing its value when
it sees a session and when it serves a scrape. That is also why the gauge is set rather
than computed by ``set_function`` or a custom collector: multi-process mode supports
neither.
"""

from __future__ import annotations

import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Literal, ParamSpec, Protocol, TypeVar

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    REGISTRY,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)
from prometheus_client import multiprocess as prometheus_multiprocess
from redis.exceptions import RedisError
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError

from server.positioning.model.events import Event, StepEvent


class Answered(Protocol):
    """What counting needs of an answered batch (``batches.BatchResult``)."""

    @property
    def replayed(self) -> bool: ...
    @property
    def made(self) -> int: ...


P = ParamSpec("P")
R = TypeVar("R")

Transport = Literal["http", "ws"]
Store = Literal["session", "sql", "queue"]
MULTIPROC_ENV = "PROMETHEUS_MULTIPROC_DIR"
UNMATCHED_ROUTE = "unmatched"

HTTP_REQUEST_SECONDS = Histogram(
    "indoorpos_http_request_duration_seconds",
    "Time to answer an HTTP request, by method, route template and status code.",
    ["method", "route", "status"],
    buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10),
)
BATCHES = Counter(
    "indoorpos_batches_total",
    "Session batches answered, by transport (http, ws) and outcome (applied, replayed).",
    ["transport", "outcome"],
)
STEPS = Counter("indoorpos_steps_total", "Step events in applied batches.")
FIXES = Counter("indoorpos_fixes_total", "Fixes made by applied batches.")
ENGINE_STEP_SECONDS = Histogram(
    "indoorpos_engine_step_seconds",
    "Wall time of one engine run over one batch.",
    ["engine"],
    buckets=(0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5),
)
ACTIVE_SESSIONS = Gauge(
    "indoorpos_active_sessions",
    "Sessions this process opened or served a batch for within the idle timeout.",
    multiprocess_mode="livesum",
)
STORE_ERRORS = Counter(
    "indoorpos_store_errors_total",
    "Failures talking to a store: session (Redis), sql (the database), queue (uploads).",
    ["store"],
)

# the label values known in advance start at 0, so a rate() has a series from the start
for _transport in ("http", "ws"):
    for _outcome in ("applied", "replayed"):
        BATCHES.labels(transport=_transport, outcome=_outcome)
for _store in ("session", "sql", "queue"):
    STORE_ERRORS.labels(store=_store)


class _ActiveSessions:
    """Session id -> monotonic time last seen, oldest first, for the active-session gauge.

    Touches come from the event loop, scrapes too, but a lock keeps it safe from any
    thread; pruning pops expired ids off the old end, so it costs O(1) per session.
    """

    def __init__(self) -> None:
        self._seen: OrderedDict[str, float] = OrderedDict()
        self._lock = threading.Lock()
        self.idle_s = 1800.0

    def touch(self, session_id: str, idle_s: float) -> None:
        with self._lock:
            self.idle_s = idle_s
            self._seen[session_id] = time.monotonic()
            self._seen.move_to_end(session_id)
            self._refresh()

    def forget(self, session_id: str) -> None:
        with self._lock:
            self._seen.pop(session_id, None)
            self._refresh()

    def refresh(self) -> int:
        with self._lock:
            return self._refresh()

    def _refresh(self) -> int:
        horizon = time.monotonic() - self.idle_s
        while self._seen and next(iter(self._seen.values())) < horizon:
            self._seen.popitem(last=False)
        ACTIVE_SESSIONS.set(len(self._seen))
        return len(self._seen)


_active = _ActiveSessions()


def touch_session(session_id: str, idle_s: float) -> None:
    """The session was opened, or a batch of it was served, just now."""
    _active.touch(session_id, idle_s)


def forget_session(session_id: str) -> None:
    """The session was ended."""
    _active.forget(session_id)


def active_sessions() -> int:
    """Sessions seen within the idle timeout (prunes the expired ones)."""
    return _active.refresh()


def count_batch(
    transport: Transport,
    events: Sequence[Event],
    result: Answered,
    *,
    session_id: str,
    idle_s: float,
) -> None:
    """Count one answered batch of ``events`` and keep its session active."""
    outcome = "replayed" if result.replayed else "applied"
    BATCHES.labels(transport=transport, outcome=outcome).inc()
    if not result.replayed:
        STEPS.inc(sum(isinstance(e, StepEvent) for e in events))
        FIXES.inc(result.made)
    touch_session(session_id, idle_s)


def timed_engine(engine: str, run: Callable[P, R]) -> Callable[P, R]:
    """``run`` observing its wall time in ``indoorpos_engine_step_seconds{engine}``."""
    histogram = ENGINE_STEP_SECONDS.labels(engine=engine)

    def timed(*args: P.args, **kwargs: P.kwargs) -> R:
        start = time.perf_counter()
        try:
            return run(*args, **kwargs)
        finally:
            histogram.observe(time.perf_counter() - start)

    return timed


def observe_request(method: str, route: str | None, status: int, seconds: float) -> None:
    HTTP_REQUEST_SECONDS.labels(
        method=method, route=route or UNMATCHED_ROUTE, status=str(status)
    ).observe(seconds)


# where a failure was raised tells which store it came from: the innermost frame of ours
_STORE_MODULES: tuple[tuple[str, Store], ...] = (
    ("server.storage.session_store", "session"),
    ("server.storage.redis_session_store", "session"),
    ("server.storage.memory_session_store", "session"),
    ("server.storage.upload_queue", "queue"),
    # the rate limits and the shared client live in the session store's Redis
    ("server.storage.rate_limits", "session"),
    ("server.storage.redis_client", "session"),
    ("server.storage", "sql"),  # db, repositories
)
_SQL_DRIVERS = ("sqlalchemy", "asyncpg", "aiosqlite", "sqlite3")
STORE_ERROR_TYPES: tuple[type[Exception], ...] = (RedisError, DBAPIError, OSError)


def store_of(exc: BaseException) -> Store | None:
    """The store a failure talking to it came from, or None for any other error.

    Redis errors (its ConnectionError and TimeoutError included) and ``OSError`` (a
    refused or reset connection) count when raised under a store's code (a Redis error
    is the ``session`` store's, which also holds the rate limits, unless the upload
    queue's code raised it); of the
    database's errors only those about the connection (``OperationalError``,
    ``InterfaceError``, an invalidated connection) do: the others (integrity, syntax)
    are answers of a working database.
    """
    if isinstance(exc, DBAPIError):
        lost = isinstance(exc, OperationalError | InterfaceError) or exc.connection_invalidated
        return "sql" if lost else None
    if not isinstance(exc, RedisError | OSError):
        return None
    modules: list[str] = []
    tb = exc.__traceback__
    while tb is not None:
        modules.append(tb.tb_frame.f_globals.get("__name__", ""))
        tb = tb.tb_next
    for module in reversed(modules):
        for prefix, store in _STORE_MODULES:
            if module == prefix or module.startswith(prefix + "."):
                return store
    if isinstance(exc, RedisError):
        return "session"
    return "sql" if any(m.split(".", 1)[0] in _SQL_DRIVERS for m in modules) else None


def count_store_error(exc: BaseException) -> Store | None:
    """Count ``exc`` in ``indoorpos_store_errors_total`` if it is a store failure; return
    the store (None, and nothing counted, for any other error)."""
    store = store_of(exc)
    if store is not None:
        STORE_ERRORS.labels(store=store).inc()
    return store


def multiprocess_mode() -> bool:
    return bool(os.environ.get(MULTIPROC_ENV))


def exposition() -> tuple[bytes, str]:
    """The text exposition of every metric (of every process in multi-process mode) and
    its content type."""
    _active.refresh()
    if multiprocess_mode():
        registry = CollectorRegistry()
        prometheus_multiprocess.MultiProcessCollector(registry)  # type: ignore[no-untyped-call]
        return generate_latest(registry), CONTENT_TYPE_LATEST
    return generate_latest(REGISTRY), CONTENT_TYPE_LATEST


def process_exited() -> None:
    """Drop this process's live gauges from the multi-process files (at shutdown)."""
    if multiprocess_mode():
        prometheus_multiprocess.mark_process_dead(os.getpid())  # type: ignore[no-untyped-call]
