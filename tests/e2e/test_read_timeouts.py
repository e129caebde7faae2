"""Read timeouts on a real server: headers or a body sent a byte at a time are cut off
(``server.cli.http_protocol``, ``server.api.body_deadline``), a slow but steady body is
not, and other clients are served meanwhile. The server runs with timeouts of half a
second so that each test takes a second or two."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import orjson
import pytest

from lab.cli.embedded import ServerThread, free_port
from server.config import Settings
from tests.support.admin_key import ADMIN_KEY

HEADER_TIMEOUT_S = 0.5
BODY_TIMEOUT_S = 0.5
MIN_RATE_BYTES_S = 20
# what a cut-off may take past its due time: a dribbled byte's period and some slack
LATE_S = 0.5

SLOW_HEADERS = b"GET /healthz HTTP/1.1\r\nHost: test\r\n"
SLOW_BODY = (
    b"POST /v1/sessions HTTP/1.1\r\nHost: test\r\n"
    b"Authorization: Bearer " + ADMIN_KEY.encode() + b"\r\n"
    b"Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n"
)


@pytest.fixture(scope="module")
def port(settings: Settings) -> Iterator[int]:
    quick = settings.model_copy(
        update={
            "header_timeout_s": HEADER_TIMEOUT_S,
            "body_timeout_s": BODY_TIMEOUT_S,
            "body_min_rate_bytes_s": MIN_RATE_BYTES_S,
        }
    )
    number = free_port(0)
    server = ServerThread(number, quick)
    server.start()
    yield number
    server.stop()


@dataclass
class Outcome:
    answer: bytes  # all the server wrote before it closed the connection
    closed_after_s: float  # from the connection's opening

    @property
    def status(self) -> int | None:
        line = self.answer.split(b"\r\n", 1)[0].split()
        return int(line[1]) if len(line) > 1 else None

    @property
    def json(self) -> dict[str, object]:
        body: dict[str, object] = orjson.loads(self.answer.split(b"\r\n\r\n", 1)[1])
        return body


def dribble(
    port: int,
    head: bytes,
    rest: bytes,
    step: int = 1,
    every_s: float = 0.2,
    until_refused: bool = False,
) -> Outcome:
    """Open a connection, send ``head``, then ``step`` bytes of ``rest`` every ``every_s``
    (nothing once it runs out) until the server closes the connection, 10 s at most.
    With ``until_refused``, the end of the server's writing (its answer sent, the
    connection half closed) does not count: only a send the server refuses does."""
    start = time.monotonic()
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(head)
        sock.settimeout(every_s)
        answer = b""
        writing = True  # the server may still write
        while time.monotonic() - start < 10:
            try:
                chunk = sock.recv(65536) if writing else b""
                if not writing:
                    time.sleep(every_s)
                    raise TimeoutError
            except TimeoutError:
                # the server may have closed already: what it wrote is still there to read
                try:
                    sock.sendall(rest[:step])
                except OSError:
                    if not writing:
                        break  # refused after the answer: the server has closed
                rest = rest[step:]
                continue
            except ConnectionResetError:
                break
            if not chunk:
                if until_refused:
                    writing = False
                    continue
                break
            answer += chunk
        return Outcome(answer, time.monotonic() - start)


def answer_of(sock: socket.socket) -> bytes:
    """One whole answer with a Content-Length, read from a kept-alive connection."""
    sock.settimeout(5)
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(65536)
    head, body = data.split(b"\r\n\r\n", 1)
    length = next(
        int(line.split(b":")[1])
        for line in head.lower().split(b"\r\n")
        if b"content-length" in line
    )
    while len(body) < length:
        body += sock.recv(65536)
    return head


def test_headers_sent_a_byte_at_a_time_are_cut_off(port: int) -> None:
    outcome = dribble(port, SLOW_HEADERS, b"X-Slow: " + b"a" * 100)
    assert outcome.status == 408
    assert outcome.json["message"] == (
        f"headers: the request's headers did not arrive within {HEADER_TIMEOUT_S:g} s"
    )
    assert HEADER_TIMEOUT_S <= outcome.closed_after_s < HEADER_TIMEOUT_S + LATE_S


def test_a_connection_that_sends_nothing_is_closed(port: int) -> None:
    outcome = dribble(port, b"", b"")
    assert outcome.status == 408
    assert HEADER_TIMEOUT_S <= outcome.closed_after_s < HEADER_TIMEOUT_S + LATE_S


def test_a_body_sent_a_byte_at_a_time_is_answered_408(port: int) -> None:
    outcome = dribble(port, SLOW_BODY, b"{" + b" " * 999)
    assert outcome.status == 408
    assert b"connection: close" in outcome.answer.lower()
    assert outcome.json["detail"] == [
        {
            "loc": ["body"],
            "msg": f"the body did not arrive within {BODY_TIMEOUT_S:g} s and a second more "
            f"for each {MIN_RATE_BYTES_S} bytes",
            "type": "Timeout",
        }
    ]
    # 5 bytes a second earn a quarter of a second each second: due at about 0.67 s
    assert BODY_TIMEOUT_S <= outcome.closed_after_s < BODY_TIMEOUT_S + LATE_S + 0.2


def test_a_slow_but_steady_body_is_read_whole(port: int) -> None:
    # 50 bytes a second, over the 20 the server asks for, for 2 s: four times the timeout
    body = b"{" + b" " * 98 + b"}"
    head = SLOW_BODY.replace(b"Content-Length: 1000", b"Content-Length: 100\r\nConnection: close")
    outcome = dribble(port, head, body, step=5, every_s=0.1)
    assert outcome.status == 422, outcome.answer  # read and judged: no site_id
    assert outcome.json["message"] == "site_id: Field required"
    assert 4 * BODY_TIMEOUT_S <= outcome.closed_after_s < 4 * BODY_TIMEOUT_S + LATE_S


def test_others_are_served_while_slow_clients_are_held(port: int) -> None:
    outcomes: list[Outcome] = []

    def slow(head: bytes, rest: bytes) -> None:
        outcomes.append(dribble(port, head, rest))

    clients = [
        threading.Thread(target=slow, args=(SLOW_HEADERS, b"X-Slow: " + b"a" * 100))
        for _ in range(10)
    ] + [threading.Thread(target=slow, args=(SLOW_BODY, b"{" + b" " * 999)) for _ in range(10)]
    for client in clients:
        client.start()
    time.sleep(0.2)  # all of them connected and dribbling
    start = time.monotonic()
    assert httpx.get(f"http://127.0.0.1:{port}/healthz").status_code == 200
    assert time.monotonic() - start < 0.2
    for client in clients:
        client.join()
    assert [o.status for o in outcomes] == [408] * 20
    assert max(o.closed_after_s for o in outcomes) < BODY_TIMEOUT_S + LATE_S + 0.2


def test_a_kept_alive_connection_times_each_request_from_its_first_byte(port: int) -> None:
    request = b"GET /healthz HTTP/1.1\r\nHost: test\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(request)
        assert answer_of(sock).startswith(b"HTTP/1.1 200")
        # idle past the header timeout: between requests uvicorn's keep-alive (5 s) counts
        time.sleep(HEADER_TIMEOUT_S + 0.3)
        for half in (request[:20], request[20:]):
            sock.sendall(half)
            time.sleep(HEADER_TIMEOUT_S * 0.6)  # the two halves: within the timeout
        assert answer_of(sock).startswith(b"HTTP/1.1 200")


def test_an_answer_before_the_body_drains_it_as_long_as_a_body_read_would(port: int) -> None:
    # no such route: answered without reading the body; the dribbled rest is drained for
    # as long as a body read would wait for it, then the connection closes
    head = SLOW_BODY.replace(b"/v1/sessions", b"/v1/nothing-here")
    outcome = dribble(port, head, b"{" + b" " * 999, until_refused=True)
    assert outcome.status == 404
    # 5 bytes a second earn a quarter of a second each second: closed at about 0.67 s,
    # and the send after it is the one refused
    assert BODY_TIMEOUT_S <= outcome.closed_after_s < BODY_TIMEOUT_S + LATE_S + 0.4
