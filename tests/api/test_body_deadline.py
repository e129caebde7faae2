"""The body deadline as ASGI sees it: a body that comes too slowly is answered 408 in the
app's place, one that keeps up is handed on whole, and a request without a body reaches
the app untouched (the real server's side: tests/e2e/test_read_timeouts.py)."""

from __future__ import annotations

from collections.abc import Awaitable, Callable

import anyio
import orjson
import pytest
from starlette.types import Message, Receive, Scope, Send

from server.api.body_deadline import BodyDeadline

TIMEOUT_S = 0.2
MIN_RATE_BYTES_S = 100


def scope(headers: list[tuple[bytes, bytes]]) -> Scope:
    return {"type": "http", "method": "POST", "path": "/v1/sessions", "headers": headers}


def arriving(chunks: list[bytes], every_s: float) -> Callable[[], Awaitable[Message]]:
    """A client's body: one chunk every ``every_s``."""
    left = list(chunks)

    async def receive() -> Message:
        await anyio.sleep(every_s)
        if not left:
            await anyio.sleep_forever()
        body = left.pop(0)
        return {"type": "http.request", "body": body, "more_body": bool(left)}

    return receive


class Echo:
    """An app that reads the whole body and answers its length."""

    def __init__(self) -> None:
        self.seen: list[Message] = []

    async def __call__(self, _scope: Scope, receive: Receive, send: Send) -> None:
        received = 0
        while True:
            message = await receive()
            self.seen.append(message)
            if message["type"] == "http.disconnect":
                break
            received += len(message["body"])
            if not message["more_body"]:
                break
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": str(received).encode()})


async def run(headers: list[tuple[bytes, bytes]], receive: Receive) -> tuple[Echo, list[Message]]:
    app, sent = Echo(), []

    async def send(message: Message) -> None:
        sent.append(message)

    await BodyDeadline(app, TIMEOUT_S, MIN_RATE_BYTES_S)(scope(headers), receive, send)
    return app, sent


async def test_a_body_that_stops_coming_is_answered_408() -> None:
    receive = arriving([b"{", b" ", b" ", b" "], every_s=0.1)  # 10 bytes a second
    app, sent = await run([(b"content-length", b"100")], receive)
    assert app.seen[-1] == {"type": "http.disconnect"}
    assert [m.get("status") for m in sent] == [408, None]  # the app's answer dropped
    assert (b"connection", b"close") in sent[0]["headers"]
    assert orjson.loads(sent[1]["body"])["detail"][0]["type"] == "Timeout"


async def test_a_body_that_keeps_up_is_read_whole() -> None:
    # 10 bytes every 0.05 s: 200 bytes a second, twice the rate asked, for 0.5 s
    receive = arriving([b"x" * 10] * 10, every_s=0.05)
    _, sent = await run([(b"transfer-encoding", b"chunked")], receive)
    assert [m.get("status") for m in sent] == [200, None]
    assert sent[1]["body"] == b"100"


@pytest.mark.parametrize("headers", [[], [(b"content-length", b"0")]])
async def test_a_request_without_a_body_reaches_the_app_untouched(
    headers: list[tuple[bytes, bytes]],
) -> None:
    async def receive() -> Message:
        return {"type": "http.request", "body": b"", "more_body": False}

    seen: list[Receive] = []

    async def app(scope: Scope, passed: Receive, send: Send) -> None:
        seen.append(passed)

    async def send(message: Message) -> None:
        raise AssertionError("nothing is answered")

    await BodyDeadline(app, TIMEOUT_S, MIN_RATE_BYTES_S)(scope(headers), receive, send)
    assert seen == [receive]


async def test_after_the_body_waiting_for_a_disconnect_is_not_timed() -> None:
    parts: list[Message] = [
        {"type": "http.request", "body": b"{}", "more_body": False},
        {"type": "http.disconnect"},
    ]

    async def receive() -> Message:
        if len(parts) == 1:  # the client goes only after twice the timeout
            await anyio.sleep(2 * TIMEOUT_S)
        return parts.pop(0)

    seen: list[Message] = []

    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        seen.extend([await receive(), await receive()])

    async def send(message: Message) -> None:
        raise AssertionError("nothing is answered")

    await BodyDeadline(app, TIMEOUT_S, MIN_RATE_BYTES_S)(
        scope([(b"content-length", b"2")]), receive, send
    )
    assert [m["type"] for m in seen] == ["http.request", "http.disconnect"]
