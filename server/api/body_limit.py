"""Pure ASGI middleware: a request body larger than its route allows is answered 413
before the app reads past the limit.

A declared ``Content-Length`` over the limit is refused before a byte of the body is
read; a chunked or lying body is counted as it arrives and refused at the first chunk
that crosses the limit (the app sees the client disconnect and its answer is dropped).
Device routes (sessions, batches, locate) get ``json_max_bytes``; the bulk routes an
admin feeds (uploads, radio and magnetic surveys, floor plans) get ``upload_max_bytes``
when the request carries credentials at all (they are checked after the body is read).
The live socket's messages are bounded by the server's ``ws_max_size`` (``serve`` sets it
to ``json_max_bytes``).
"""

from __future__ import annotations

import re

import orjson
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.errors import problem

BULK_PATHS = re.compile(
    r"^/v1/(uploads$|buildings/[^/]+/survey$|floors/[^/]+/(magnetic-survey|plan)$)"
)


class BodyLimit:
    def __init__(self, app: ASGIApp, json_max_bytes: int, bulk_max_bytes: int) -> None:
        self.app = app
        self.json_max_bytes = json_max_bytes
        self.bulk_max_bytes = bulk_max_bytes

    def limit_for(self, path: str, has_credentials: bool) -> int:
        # the bulk size only with credentials: the framework reads a body before it checks
        # the key, and no one without one gets to make it parse 64 MiB
        bulk = has_credentials and BULK_PATHS.match(path)
        return self.bulk_max_bytes if bulk else self.json_max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        limit = self.limit_for(scope["path"], b"authorization" in headers)
        declared = headers.get(b"content-length", b"")
        if declared.isdigit() and int(declared) > limit:
            await _refuse(send, limit)
            return
        seen = 0
        refused = False

        async def counted_receive() -> Message:
            nonlocal seen, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    refused = True
                    await _refuse(send, limit)
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: Message) -> None:
            if not refused:  # after our 413 the app's own answer has nowhere to go
                await send(message)

        await self.app(scope, counted_receive, guarded_send)


async def _refuse(send: Send, limit: int) -> None:
    body = orjson.dumps(problem("body", f"the body is over {limit} bytes", "TooLarge"))
    await send(
        {
            "type": "http.response.start",
            "status": 413,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
