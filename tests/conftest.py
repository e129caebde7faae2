"""Shared fixtures: settings for the mode under test, a migrated database, the app in-process,
the app on a real port, a Redis Cluster, and the ILC sample trace of the recorded datasets.

The suite runs twice (see the README): on the embedded defaults (SQLite file, in-memory
session store) and on the production shape when ``INDOORPOS_DATABASE_URL`` and
``INDOORPOS_REDIS_URL`` are set (real PostgreSQL and Redis); the core's tests, which touch
no store, run in the first only (the Makefile). The helpers behind these fixtures are in
``tests.support``.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import httpx
import pytest
from asgi_lifespan import LifespanManager
from fastapi import FastAPI
from pydantic import SecretStr

from server.app import create_app
from server.config import Settings
from server.storage import db
from server.storage.ilc_trace_format import IlcWalk, read_trace
from tests.support.admin_key import ADMIN_KEY
from tests.support.datasets import SAMPLE_ID, dataset_dir
from tests.support.live_server import serve
from tests.support.redis_cluster import start_cluster


def _reset_postgres(url: str) -> None:
    """Give the test run an empty schema on the test database."""
    import asyncio

    from sqlalchemy import text

    async def reset() -> None:
        engine = db.create_engine(url)
        async with engine.begin() as conn:
            await conn.execute(text("DROP SCHEMA IF EXISTS public CASCADE"))
            await conn.execute(text("CREATE SCHEMA public"))
        await engine.dispose()

    asyncio.run(reset())


@pytest.fixture(scope="session")
def settings(tmp_path_factory: pytest.TempPathFactory) -> Settings:
    data_dir = tmp_path_factory.mktemp("indoorpos")
    database_url = os.environ.get("INDOORPOS_DATABASE_URL") or None
    redis_url = os.environ.get("INDOORPOS_REDIS_URL") or None
    if database_url and not database_url.startswith("sqlite"):
        _reset_postgres(database_url)
    s = Settings(
        data_dir=Path(data_dir),
        database_url=database_url,
        redis_url=redis_url,
        admin_key=SecretStr(ADMIN_KEY),
        seq_wait_s=5.0,
        # the whole suite comes from one address; tests/api/test_rate_limits.py turns
        # them on in an app of its own
        rate_limits=False,
    )
    db.migrate(s.resolved_database_url)
    return s


@pytest.fixture(scope="session")
async def app(settings: Settings) -> AsyncIterator[FastAPI]:
    application = create_app(settings)
    async with LifespanManager(application):
        yield application


@pytest.fixture
async def client(app: FastAPI) -> AsyncIterator[httpx.AsyncClient]:
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
        yield c


@pytest.fixture
def admin() -> dict[str, str]:
    return {"Authorization": f"Bearer {ADMIN_KEY}"}


@pytest.fixture(scope="session")
def redis_cluster_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A 3-node Redis Cluster for the run (``tests.support.redis_cluster``); its URL."""
    yield from start_cluster(tmp_path_factory)


@pytest.fixture(scope="session")
def live_url(settings: Settings) -> Iterator[str]:
    """The app of ``settings`` on a loopback port, for WebSocket and simulator tests."""
    yield from serve(settings)


# the ILC sample trace, which the dataset readers', the walks' and the trace format's
# tests share (the UJI and IPIN fixtures: tests/lab/datasets/conftest.py)


@pytest.fixture(scope="session")
def ilc_dir() -> Path:
    return dataset_dir("ilc20-sample")


@pytest.fixture(scope="module")
def raw_path(ilc_dir: Path) -> Path:
    return ilc_dir / "sample_raw" / f"{SAMPLE_ID}.txt"


@pytest.fixture(scope="module")
def raw_lines(raw_path: Path) -> list[str]:
    return raw_path.read_text(encoding="utf-8").splitlines()


@pytest.fixture(scope="module")
def raw_trace(raw_path: Path) -> IlcWalk:
    return read_trace(raw_path)
