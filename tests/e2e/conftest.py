"""A real server on a loopback port, for WebSocket and simulator tests."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest
import uvicorn

from server.app import create_app
from server.cli.http_protocol import http_protocol
from server.config import Settings


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="session")
def live_url(settings: Settings) -> Iterator[str]:
    yield from _serve(settings)


@pytest.fixture(scope="module")
def worker_live_url(settings: Settings) -> Iterator[str]:
    """The server with the worker in its process (in the production shape a process of
    its own): what builds a survey's maps. For a module only, so that its worker does not
    take other modules' uploads from a shared queue."""
    yield from _serve(settings.model_copy(update={"in_process_worker": True}))


def _serve(settings: Settings) -> Iterator[str]:
    port = _free_port()
    server = uvicorn.Server(
        uvicorn.Config(
            create_app(settings),
            host="127.0.0.1",
            port=port,
            log_level="warning",
            # as `indoorpos serve` runs it
            http=http_protocol(settings),
            **settings.proxy_options(),
        )
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive(), "server thread died"
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=10)


@pytest.fixture(scope="session")
def cluster_live_url(settings: Settings, redis_cluster_url: str) -> Iterator[str]:
    """The same server with its sessions, uploads and rate limits in a Redis Cluster."""
    yield from _serve(settings.model_copy(update={"redis_url": redis_cluster_url}))


@pytest.fixture(scope="module")
def replica_url(settings: Settings) -> Iterator[str]:
    """One more api replica beside ``live_url``, on the same PostgreSQL and Redis.
    Skipped when embedded: an in-memory session store is its process's own, so two
    embedded servers are not replicas of one service."""
    if settings.redis_url is None:
        pytest.skip("embedded mode runs one process: no second replica shares its store")
    yield from _serve(settings)
