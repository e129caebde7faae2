"""A webhook receiver on a loopback port, for the tests of zone events: it records every
delivery and can refuse the first attempts of each (``fail_first``) or all of them."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any


@dataclass
class Received:
    headers: dict[str, str]
    body: bytes
    accepted: bool

    @property
    def json(self) -> dict[str, Any]:
        parsed: dict[str, Any] = json.loads(self.body)
        return parsed


@dataclass
class Receiver:
    url: str
    fail_first: int  # attempts of each delivery answered 500 (-1: every attempt)
    received: list[Received] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def accepted(self) -> list[Received]:
        with self.lock:
            return [r for r in self.received if r.accepted]

    def attempts_of(self, delivery_id: str) -> int:
        with self.lock:
            return sum(r.headers.get("x-indoorpos-delivery") == delivery_id for r in self.received)


@contextmanager
def webhook_receiver(fail_first: int = 0) -> Iterator[Receiver]:
    """A receiver served in a thread until the block ends."""
    receiver: Receiver

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            headers = {k.lower(): v for k, v in self.headers.items()}
            delivery = headers.get("x-indoorpos-delivery", "")
            with receiver.lock:
                earlier = sum(
                    r.headers.get("x-indoorpos-delivery") == delivery for r in receiver.received
                )
                accept = receiver.fail_first >= 0 and earlier >= receiver.fail_first
                receiver.received.append(Received(headers, body, accept))
            self.send_response(204 if accept else 500)
            self.end_headers()

        def log_message(self, format: str, *args: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    receiver = Receiver(f"http://127.0.0.1:{server.server_address[1]}/hook", fail_first)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield receiver
    finally:
        server.shutdown()
        server.server_close()
