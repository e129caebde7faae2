"""uvicorn's HTTP protocol with a deadline for a request's headers.

uvicorn reads headers for as long as a client cares to send them, so a client that sends
a byte a second holds its connection (and a slot of the process) for good. Here a
request's headers must arrive whole within ``header_timeout_s`` of its first byte (the
first request's: of the connection's opening, so a connection that never sends a byte is
closed too); past that the client is answered 408 and the connection closes. The idle
time between two requests of a connection stays uvicorn's ``timeout_keep_alive``. The
body's own deadline is ``server.api.body_deadline``'s.

A connection whose answer went out before its request's body had all arrived (a 401 from
the headers, a 404) is closed after a lingering drain, as RFC 9112 section 9.6 asks and
nginx does (``lingering_close``): the server says it is done writing, then reads and drops
what still comes for as long as a body read would wait for it (``body_timeout_s`` and a
second more for each ``body_min_rate_bytes_s`` bytes, from the answer; at most
``LINGER_S``), and closes. Closed at once, the unread upload would make the kernel reset
the connection, and a client that sends its whole body before it reads (Python's
``http.client``, many phone HTTP stacks) would lose the answer; kept open, uvicorn would
read and ignore a dribbled rest for as long as it lasts. An answer that says
``connection: close`` (the 408 of a slow body, a 413) closes at once: uvicorn does that.

It is uvicorn's httptools protocol, the one uvicorn picks itself with ``uvicorn[standard]``
(a dependency): its parser calls back at a request's first byte and at the end of its
headers, which is all a deadline needs (uvicorn's h11 protocol has no first-byte hook).
"""

from __future__ import annotations

import asyncio
import functools
from typing import Any, cast

import orjson
from uvicorn.config import Config
from uvicorn.protocols.http.httptools_impl import STATUS_LINE, HttpToolsProtocol
from uvicorn.server import ServerState

from server.api.errors import problem
from server.config import Settings

LINGER_S = 30.0  # nginx's lingering_time


class HeaderDeadlineProtocol(HttpToolsProtocol):
    def __init__(
        self,
        config: Config,
        server_state: ServerState,
        app_state: dict[str, Any],
        _loop: asyncio.AbstractEventLoop | None = None,
        *,
        header_timeout_s: float,
        body_timeout_s: float,
        body_min_rate_bytes_s: int,
    ) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self.header_timeout_s = header_timeout_s
        self.body_timeout_s = body_timeout_s
        self.body_min_rate_bytes_s = body_min_rate_bytes_s
        # when the headers being read must be complete (None: none are being read), and
        # the timer that holds them to it
        self.headers_due: float | None = None
        self.headers_timer: asyncio.TimerHandle | None = None
        # while draining the rest of a body after an early answer: since when, how much,
        # and the timer that closes the connection
        self.linger_since: float | None = None
        self.linger_drained = 0
        self.linger_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self.headers_due = self.loop.time() + self.header_timeout_s
        self.headers_timer = self.loop.call_at(self.headers_due, self.headers_late)

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        if self.linger_timer is not None:
            self.linger_timer.cancel()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.linger_since is not None:
            self._linger(len(data))  # the rest of a body already answered: dropped
            return
        super().data_received(data)
        # armed only after the parse: headers that come in one piece (nearly all) begin and
        # end within it and need no timer
        due = self.headers_due
        if due is not None and self.headers_timer is None and not self.transport.is_closing():
            self.headers_timer = self.loop.call_at(due, self.headers_late)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self.headers_due is None:  # the first request's runs from the opening already
            self.headers_due = self.loop.time() + self.header_timeout_s

    def on_headers_complete(self) -> None:
        self.headers_due = None
        self._disarm()
        super().on_headers_complete()

    def on_response_complete(self) -> None:
        cycle = self.cycle
        early = cycle is not None and cycle.response_complete and cycle.more_body
        if not early or self.transport.is_closing():
            super().on_response_complete()
            return
        # answered before the whole body came: drain what still comes, then close
        self.server_state.total_requests += 1
        self.linger_since = self.loop.time()
        self.flow.resume_reading()
        if self.transport.can_write_eof():
            self.transport.write_eof()
        self._linger(0)

    def _linger(self, received: int) -> None:
        """Count ``received`` bytes drained and (re)arm the close of the connection when
        they stop coming at the rate a body must."""
        assert self.linger_since is not None
        self.linger_drained += received
        rate = self.body_min_rate_bytes_s
        earned = self.linger_drained / rate if rate else 0.0
        due = self.linger_since + min(self.body_timeout_s + earned, LINGER_S)
        if self.linger_timer is not None:
            self.linger_timer.cancel()
        self.linger_timer = self.loop.call_at(due, self.transport.close)

    def headers_late(self) -> None:
        self.headers_timer = None
        if self.transport.is_closing():
            return
        if self.cycle is not None and not self.cycle.response_complete:
            # an earlier request of the connection is still being answered, and uvicorn
            # reads no further meanwhile: the time is not the client's to answer for
            self.headers_due = self.loop.time() + self.header_timeout_s
            self.headers_timer = self.loop.call_at(self.headers_due, self.headers_late)
            return
        self.transport.write(self._timeout_response())
        self.transport.close()

    def _timeout_response(self) -> bytes:
        body = orjson.dumps(
            problem(
                "headers",
                f"the request's headers did not arrive within {self.header_timeout_s:g} s",
                "Timeout",
            )
        )
        head = [STATUS_LINE[408]]
        for name, value in self.server_state.default_headers:
            head += [name, b": ", value, b"\r\n"]
        head += [
            b"content-type: application/json\r\n",
            b"content-length: %d\r\n" % len(body),
            b"connection: close\r\n\r\n",
        ]
        return b"".join(head) + body

    def _disarm(self) -> None:
        if self.headers_timer is not None:
            self.headers_timer.cancel()
            self.headers_timer = None


def http_protocol(settings: Settings) -> type[asyncio.Protocol]:
    """uvicorn's ``http=`` for these settings. uvicorn only calls it as it would the class
    (``config=``, ``server_state=``, ``app_state=``, ``_loop=``) and, with several
    workers, pickles it into each worker process: a partial of a module-level class
    survives that, where a class made in a function would not."""
    made = functools.partial(
        HeaderDeadlineProtocol,
        header_timeout_s=settings.header_timeout_s,
        body_timeout_s=settings.body_timeout_s,
        body_min_rate_bytes_s=settings.body_min_rate_bytes_s,
    )
    return cast("type[asyncio.Protocol]", made)
