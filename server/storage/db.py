"""Database engines: URL normalisation, async engine and session factory, migrations."""

from __future__ import annotations

import contextlib
import os
import sys
import sysconfig
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import event, text
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncEngine, AsyncSession, async_sessionmaker
from sqlalchemy.ext.asyncio import create_async_engine as _create_async_engine


def _migrations_dir() -> Path:
    """The alembic scripts: the checkout's ``migrations/`` beside its ``alembic.ini`` (a
    source or editable install), else where the service's wheel put them: ``share/indoorpos/
    migrations`` under the install scheme's data path (the user scheme's, for ``--user``),
    or under the interpreter's prefix. The first that exists; the checkout's path when none
    does (``alembic_config`` says so)."""
    root = Path(__file__).resolve().parents[2]
    checkout = root / "migrations"
    if (root / "alembic.ini").is_file() and checkout.is_dir():
        return checkout
    schemes = [sysconfig.get_path("data")]
    with contextlib.suppress(KeyError):
        schemes.append(sysconfig.get_path("data", f"{os.name}_user"))
    for data in [*schemes, sys.prefix]:
        installed = Path(data) / "share" / "indoorpos" / "migrations"
        if (installed / "env.py").is_file():
            return installed
    return checkout


MIGRATIONS_DIR = _migrations_dir()


def async_url(url: str) -> str:
    """Pick the async driver for a plain URL (``postgresql://`` -> asyncpg, sqlite -> aiosqlite)."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        raise ValueError(f"not a database URL: {url!r}")
    if "+" in scheme:
        return url
    if scheme in {"postgresql", "postgres"}:
        return f"postgresql+asyncpg://{rest}"
    if scheme == "sqlite":
        return f"sqlite+aiosqlite://{rest}"
    raise ValueError(f"unsupported database scheme {scheme!r}")


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA busy_timeout=10000")
    cursor.close()


def create_engine(url: str) -> AsyncEngine:
    full = async_url(url)
    if full.startswith("sqlite"):
        path = full.split(":///", 1)[1] if ":///" in full else ""
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        engine = _create_async_engine(full)
        event.listen(engine.sync_engine, "connect", _sqlite_pragmas)
        return engine
    return _create_async_engine(full, pool_size=10, max_overflow=20, pool_pre_ping=True)


def session_factory(engine: AsyncEngine) -> async_sessionmaker[AsyncSession]:
    return async_sessionmaker(engine, expire_on_commit=False)


class Duplicate(Exception):
    """A write collided with a row that already exists (a unique constraint)."""


@asynccontextmanager
async def transaction(factory: async_sessionmaker[AsyncSession]) -> AsyncIterator[AsyncSession]:
    """A session in a transaction: commit on success, roll back on error."""
    try:
        async with factory() as session, session.begin():
            yield session
    except IntegrityError as exc:
        raise Duplicate(str(exc.orig)) from exc


async def ping(engine: AsyncEngine) -> None:
    async with engine.connect() as conn:
        await conn.execute(text("SELECT 1"))


def alembic_config(url: str) -> Any:
    from alembic.config import Config

    if not (MIGRATIONS_DIR / "env.py").is_file():
        raise RuntimeError(
            f"the database migrations are not at {MIGRATIONS_DIR}: install the service from "
            "its checkout or its wheel (which carries them under share/indoorpos/migrations)"
        )
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.set_main_option("sqlalchemy.url", async_url(url).replace("%", "%%"))
    return cfg


def migrate(url: str) -> None:
    """Bring the schema to the newest migration (``alembic upgrade head``)."""
    from alembic import command

    full = async_url(url)
    if full.startswith("sqlite") and ":///" in full:
        path = full.split(":///", 1)[1]
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    command.upgrade(alembic_config(url), "head")
