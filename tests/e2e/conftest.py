"""Real servers on loopback ports for the end-to-end tests, beside the suite's
``live_url`` (``tests/conftest.py``): with the worker in their process, on a Redis
Cluster, a second replica."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from server.config import Settings
from tests.support.live_server import serve


@pytest.fixture(scope="module")
def worker_live_url(settings: Settings) -> Iterator[str]:
    """The server with the worker in its process (in the production shape a process of
    its own): what builds a survey's maps. For a module only, so that its worker does not
    take other modules' uploads from a shared queue."""
    yield from serve(settings.model_copy(update={"in_process_worker": True}))


@pytest.fixture(scope="session")
def cluster_live_url(settings: Settings, redis_cluster_url: str) -> Iterator[str]:
    """The same server with its sessions, uploads and rate limits in a Redis Cluster."""
    yield from serve(settings.model_copy(update={"redis_url": redis_cluster_url}))


@pytest.fixture(scope="module")
def replica_url(settings: Settings) -> Iterator[str]:
    """One more api replica beside ``live_url``, on the same PostgreSQL and Redis.
    Skipped when embedded: an in-memory session store is its process's own, so two
    embedded servers are not replicas of one service."""
    if settings.redis_url is None:
        pytest.skip("embedded mode runs one process: no second replica shares its store")
    yield from serve(settings)
