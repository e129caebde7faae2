"""Pure ASGI middleware: a request body that arrives too slowly is answered 408.

The scheme of Apache's mod_reqtimeout ``body=20,MinRate=500``: from the end of the
headers a body has ``timeout_s``, and each ``min_rate_bytes_s`` bytes received buy one
more second, so at any time it must be within ``timeout_s + received / min_rate_bytes_s``
seconds of the headers' end. A phone uploading 64 MiB over a slow link keeps ahead of
that; a client sending a byte a second is cut off after ``timeout_s`` and a little. Then
the client is answered 408 (with ``connection: close``) unless the app has begun its own
answer, the app sees the client disconnect, and whatever it answers later is dropped.

Requests without a body (no ``Content-Length`` or 0, and not chunked) pass untouched.
The headers' own deadline is the HTTP protocol's (``server.cli.http_protocol``).
"""

from __future__ import annotations

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.errors import send_closing_problem


def has_body(scope: Scope) -> bool:
    for name, value in scope["headers"]:
        if name == b"content-length":
            return value.strip(b" \t") not in {b"0", b""}
        if name == b"transfer-encoding":
            return True
    return False


class BodyDeadline:
    def __init__(self, app: ASGIApp, timeout_s: float, min_rate_bytes_s: int) -> None:
        self.app = app
        self.timeout_s = timeout_s
        self.min_rate_bytes_s = min_rate_bytes_s

    def due(self, start: float, received: int) -> float:
        """When the body must be whole, after ``received`` bytes of it (anyio's clock)."""
        earned = received / self.min_rate_bytes_s if self.min_rate_bytes_s else 0.0
        return start + self.timeout_s + earned

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not has_body(scope):
            await self.app(scope, receive, send)
            return
        start = anyio.current_time()
        received = 0
        whole = False  # the last part of the body came
        late = False
        answering = False  # the app has begun its answer
        refused = False  # we answered 408 in its place

        async def timed_receive() -> Message:
            nonlocal received, whole, late, refused
            if late:
                return {"type": "http.disconnect"}
            if whole:  # what follows the body (a disconnect) may take its time
                return await receive()
            with anyio.CancelScope(deadline=self.due(start, received)):
                message = await receive()
                if message["type"] == "http.request":
                    received += len(message.get("body", b""))
                    whole = not message.get("more_body", False)
                return message
            late = True
            if not answering:
                refused = True
                await _refuse(send, self.timeout_s, self.min_rate_bytes_s)
            return {"type": "http.disconnect"}

        async def guarded_send(message: Message) -> None:
            nonlocal answering
            if refused:  # after our 408 the app's answer has nowhere to go
                return
            answering = True
            await send(message)

        await self.app(scope, timed_receive, guarded_send)


async def _refuse(send: Send, timeout_s: float, min_rate_bytes_s: int) -> None:
    rate = f" and a second more for each {min_rate_bytes_s} bytes" if min_rate_bytes_s else ""
    msg = f"the body did not arrive within {timeout_s:g} s{rate}"
    await send_closing_problem(send, 408, "body", msg, "Timeout")
