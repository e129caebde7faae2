"""Structured logs: one JSON object per line, tagged with the session being served."""

from __future__ import annotations

import asyncio
import io
import json
import logging
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import connect

from server import logs
from server.services import batches as batch_service
from tests.support.admin_key import ADMIN_KEY
from tests.support.toy_site import build_toy_site


@pytest.fixture
def json_lines() -> Iterator[tuple[logging.Logger, io.StringIO]]:
    """A logger of its own writing through the JSON formatter into a buffer."""
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.setFormatter(logs.JsonFormatter())
    logger = logging.getLogger("tests.logs")
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    yield logger, out
    logger.removeHandler(handler)


def records(out: io.StringIO) -> list[dict[str, Any]]:
    lines = out.getvalue().splitlines()
    assert lines, "nothing was logged"
    return [json.loads(line) for line in lines]


def test_a_line_is_one_json_object_with_the_session_being_served(
    json_lines: tuple[logging.Logger, io.StringIO],
) -> None:
    logger, out = json_lines
    with logs.session_context("ab" * 16):
        logger.info("fix %d of %s", 3, "walk", extra={"seq": 7, "engine": "wknn", "bad": object()})
    logger.warning("outside")
    inside, outside = records(out)
    assert inside["message"] == "fix 3 of walk"
    assert inside["level"] == "INFO"
    assert inside["logger"] == "tests.logs"
    assert inside["session_id"] == "ab" * 16
    assert inside["seq"] == 7
    assert inside["engine"] == "wknn"
    assert "bad" not in inside  # not JSON: left out, the line still written
    assert "exc" not in inside
    assert inside["ts"].endswith("Z")
    ts = datetime.fromisoformat(inside["ts"].replace("Z", "+00:00"))
    assert ts.utcoffset() == UTC.utcoffset(None)
    assert abs((datetime.now(UTC) - ts).total_seconds()) < 60
    assert outside["level"] == "WARNING"
    assert "session_id" not in outside  # the context ended with the block


def test_an_exception_is_logged_with_its_traceback(
    json_lines: tuple[logging.Logger, io.StringIO],
) -> None:
    logger, out = json_lines
    try:
        raise ValueError("the engine diverged")
    except ValueError:
        with logs.session_context("cd" * 16):
            logger.exception("batch failed")
    (line,) = records(out)
    assert line["message"] == "batch failed"
    assert line["level"] == "ERROR"
    assert line["session_id"] == "cd" * 16
    assert line["exc"].startswith("Traceback")
    assert "ValueError: the engine diverged" in line["exc"]


def test_text_lines_name_the_session_too() -> None:
    record = logging.LogRecord("server.x", logging.INFO, __file__, 1, "hello %s", ("you",), None)
    assert logs.TextFormatter().format(record).endswith("INFO server.x hello you")
    with logs.session_context("ef" * 16):
        assert logs.TextFormatter().format(record).endswith(f"hello you session_id={'ef' * 16}")


@pytest.fixture
def restore_logging() -> Iterator[None]:
    root = logging.getLogger()
    names = logs.UVICORN_LOGGERS
    saved = (root.handlers[:], root.level)
    saved_uvicorn = [
        (lg.handlers[:], lg.propagate, lg.level, lg.filters[:])
        for lg in map(logging.getLogger, names)
    ]
    yield
    root.handlers[:], root.level = saved[0], saved[1]
    for lg, (handlers, propagate, level, filters) in zip(
        map(logging.getLogger, names), saved_uvicorn, strict=True
    ):
        lg.handlers[:], lg.propagate, lg.level, lg.filters[:] = handlers, propagate, level, filters


def test_configure_sends_uvicorn_lines_through_the_formatter(
    restore_logging: None, capsys: pytest.CaptureFixture[str]
) -> None:
    access = logging.getLogger("uvicorn.access")
    access.handlers = [logging.StreamHandler()]  # what uvicorn's own setup would leave
    access.propagate = False
    access.setLevel(logging.INFO)  # uvicorn sets its loggers to its --log-level
    logs.configure("json", "info")
    access.info('%s - "%s %s HTTP/%s" %d', "127.0.0.1:5000", "GET", "/healthz", "1.1", 200)
    logging.getLogger("server.anything").debug("below the level")
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1, lines
    line = json.loads(lines[0])
    assert line["logger"] == "uvicorn.access"
    assert line["message"] == '127.0.0.1:5000 - "GET /healthz HTTP/1.1" 200'


@pytest.mark.parametrize("level", ["info", "debug"])
def test_an_answered_batch_is_logged_at_debug_only(
    restore_logging: None, capsys: pytest.CaptureFixture[str], level: str
) -> None:
    logs.configure("json", level)
    access = logging.getLogger("uvicorn.access")
    access.setLevel(level.upper())  # uvicorn sets its loggers to its --log-level
    line = '%s - "%s %s HTTP/%s" %d'
    batches = f"/v1/sessions/{'ab' * 16}/batches"
    access.info(line, "127.0.0.1:5000", "POST", batches, "1.1", 200)
    access.info(line, "127.0.0.1:5000", "POST", batches, "1.1", 409)  # refused: kept
    access.info(line, "127.0.0.1:5000", "POST", "/v1/sessions", "1.1", 201)
    written = [json.loads(x) for x in capsys.readouterr().err.splitlines()]
    expected = [("INFO", 409), ("INFO", 201)]
    if level == "debug":
        expected.insert(0, ("DEBUG", 200))
    assert [(w["level"], int(w["message"][-3:])) for w in written] == expected


async def test_a_failed_batch_on_the_live_socket_is_logged_with_its_session(
    live_url: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.setFormatter(logs.JsonFormatter())
    live_logger = logging.getLogger("server.api.live")
    live_logger.addHandler(handler)
    admin = {"Authorization": f"Bearer {ADMIN_KEY}"}
    try:
        async with httpx.AsyncClient(base_url=live_url) as client:
            site = await build_toy_site(client, admin)
            r = await client.post(
                "/v1/sessions", json={"site_id": site.site_id}, headers=site.device
            )
            assert r.status_code == 201, r.text
        sid, token = r.json()["id"], r.json()["token"]

        async def diverges(*args: object) -> None:
            raise ArithmeticError("the filter diverged")

        monkeypatch.setattr(batch_service, "apply_batch", diverges)
        url = live_url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"
        async with connect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            assert json.loads(await asyncio.wait_for(ws.recv(), 10))["type"] == "ready"
            await ws.send(json.dumps({"type": "batch", "seq": 1, "events": []}))
            reply = json.loads(await asyncio.wait_for(ws.recv(), 10))
            assert reply["type"] == "error"
    finally:
        live_logger.removeHandler(handler)
    (line,) = records(out)
    assert line["message"] == "batch over the live socket failed"
    assert line["session_id"] == sid
    assert "ArithmeticError: the filter diverged" in line["exc"]


@pytest.mark.parametrize(
    ("line", "kept"),
    [
        ('127.0.0.1:1 - "WebSocket /v1/sessions/abc/live?token=SECRET" [accepted]', "?token="),
        ('"GET /v1/sites?limit=2&api_key=SECRET HTTP/1.1" 401', "limit=2&api_key="),
        ("< Authorization: Bearer SECRET", "Authorization: Bearer "),
        ("""< TEXT '{"type": "auth", "token": "SECRET"}' [40 bytes]""", '"token": "'),
    ],
)
def test_credentials_are_redacted_from_log_lines(line: str, kept: str) -> None:
    out = logs.redact(line)
    assert "SECRET" not in out
    assert kept + "[redacted]" in out
