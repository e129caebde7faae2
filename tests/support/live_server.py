"""A real server on a loopback port, as ``indoorpos serve`` runs it, in a thread of the
test process (the fixtures on it: ``live_url`` in ``tests/conftest.py``, its variants in
``tests/e2e/conftest.py``)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import uvicorn

from server.app import create_app
from server.cli.http_protocol import http_protocol
from server.config import Settings


def free_port() -> int:
    """A loopback port nothing listens on now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def serve(settings: Settings) -> Iterator[str]:
    """The app of ``settings`` served until the generator is closed; its base URL."""
    port = free_port()
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
