"""Pure ASGI middleware: a request body larger than its route allows is answered 413
before the app reads past the limit.

A declared ``Content-Length`` over the limit is refused before a byte of the body is
read; a chunked or lying body is counted as it arrives and refused at the first chunk
that crosses the limit (the app sees the client disconnect and its answer is dropped).
Device routes (sessions, batches, locate) get ``json_max_bytes``; the bulk routes an
admin feeds (uploads, radio and magnetic surveys, floor plans) get ``upload_max_bytes``
once the key has been found good for the route (``server.api.gated_route`` checks it
before the body is read, and marks the request ``admitted``): a body past the device
limit on a bulk route is therefore judged when the route starts reading it.
The live socket's messages are bounded by the server's ``ws_max_size`` (``serve`` sets it
to ``json_max_bytes``).
"""

from __future__ import annotations

import re

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.errors import send_closing_problem

BULK_PATHS = re.compile(
    r"^/v1/(uploads$|buildings/[^/]+/survey$|floors/[^/]+/(magnetic-survey|plan)$)"
)


class BodyLimit:
    def __init__(self, app: ASGIApp, json_max_bytes: int, bulk_max_bytes: int) -> None:
        self.app = app
        self.json_max_bytes = json_max_bytes
        self.bulk_max_bytes = bulk_max_bytes

    def limit_for(self, scope: Scope) -> int:
        # the bulk size only for a key the route let in: no one without one gets to make
        # the server read 64 MiB
        bulk = BULK_PATHS.match(scope["path"]) and "admitted" in scope.get("state", {})
        return self.bulk_max_bytes if bulk else self.json_max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length", b"")
        # a bulk route may allow more once its key is checked: judged at the first read
        most = self.bulk_max_bytes if BULK_PATHS.match(scope["path"]) else self.json_max_bytes
        if declared.isdigit() and int(declared) > most:
            await _refuse(send, most)
            return
        scope.setdefault("state", {})  # one dict for the route's request.state and us
        limit: int | None = None
        seen = 0
        refused = False

        async def counted_receive() -> Message:
            nonlocal seen, refused, limit
            if refused:
                return {"type": "http.disconnect"}
            if limit is None:
                limit = self.limit_for(scope)
                if declared.isdigit() and int(declared) > limit:
                    refused = True
                    await _refuse(send, limit)
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
    await send_closing_problem(send, 413, "body", f"the body is over {limit} bytes", "TooLarge")
