"""Whose X-Forwarded-For names the client: only the proxies ``trusted_proxies`` lists (by
default none; uvicorn alone would believe any loopback client). The server runs with the
options ``indoorpos serve`` gives uvicorn (``Settings.proxy_options``); what the app sees
as the client is ``deps.client_address``, so a one-route app answering it stands in for
ours here."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import httpx
import pytest
import uvicorn
from pydantic import ValidationError
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import PlainTextResponse
from starlette.routing import Route

from server.api.deps import client_address
from server.config import Settings


async def _address(request: Request) -> PlainTextResponse:
    return PlainTextResponse(client_address(request))


APP = Starlette(routes=[Route("/address", _address)])


@contextmanager
def serving(settings: Settings) -> Iterator[str]:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = int(sock.getsockname()[1])
    config = uvicorn.Config(
        APP, host="127.0.0.1", port=port, log_level="warning", **settings.proxy_options()
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not server.started:
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def seen(url: str) -> str:
    r = httpx.get(f"{url}/address", headers={"X-Forwarded-For": "203.0.113.7"})
    assert r.status_code == 200
    return r.text


def test_a_loopback_client_cannot_name_another_address_by_default() -> None:
    with serving(Settings()) as url:
        assert seen(url) == "127.0.0.1"


@pytest.mark.parametrize("proxies", ["127.0.0.1", "127.0.0.0/8, 10.0.0.0/8"])
def test_a_listed_proxy_names_the_client(proxies: str) -> None:
    with serving(Settings(trusted_proxies=proxies)) as url:
        assert seen(url) == "203.0.113.7"


def test_an_unlisted_proxy_is_not_believed() -> None:
    with serving(Settings(trusted_proxies="10.0.0.0/8")) as url:
        assert seen(url) == "127.0.0.1"


def test_a_proxy_that_is_no_address_is_refused() -> None:
    with pytest.raises(ValidationError, match="trusted_proxies"):
        Settings(trusted_proxies="proxy.example.com")
