"""A service run in this process: uvicorn in a background thread, and a throw-away
embedded one for the simulator and the crowd replay."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import typer
import uvicorn

from server.app import create_app
from server.cli.http_protocol import http_protocol
from server.config import Settings, get_settings
from server.storage import db


def free_port(preferred: int) -> int:
    """A loopback port: ``preferred`` when it is free, else one the system picks."""
    with socket.socket() as sock:
        try:
            sock.bind(("127.0.0.1", preferred))
        except OSError:
            sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class ServerThread:
    """uvicorn in a background thread with its own event loop."""

    def __init__(self, port: int, settings: Settings | None = None) -> None:
        settings = settings or get_settings()
        config = uvicorn.Config(
            create_app(settings),
            host="127.0.0.1",
            port=port,
            log_level="warning",
            http=http_protocol(settings),
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def start(self, timeout_s: float = 60.0) -> None:
        self.thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise typer.Exit(code=1)
            time.sleep(0.05)

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)


@contextlib.contextmanager
def embedded_service() -> Iterator[tuple[str, str]]:
    """A throw-away embedded service (SQLite in a temporary directory, in-process worker)
    on a free loopback port; yields its URL and admin key."""
    import secrets
    import tempfile

    from pydantic import SecretStr

    key = secrets.token_urlsafe(24)
    with tempfile.TemporaryDirectory(prefix="indoorpos-crowd-") as data_dir:
        settings = Settings(
            data_dir=Path(data_dir),
            database_url=None,
            redis_url=None,
            admin_key=SecretStr(key),
            rate_limits=False,  # one local client opening many sessions on purpose
        )
        db.migrate(settings.resolved_database_url)
        port = free_port(0)
        server = ServerThread(port, settings)
        server.start()
        try:
            yield f"http://127.0.0.1:{port}", key
        finally:
            server.stop()
