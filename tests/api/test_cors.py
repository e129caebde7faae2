"""CORS: origins from the settings (none by default) may call the API from a browser; a
preflight from any other origin gets no CORS headers."""

from __future__ import annotations

from collections.abc import AsyncIterator

import httpx
import pytest
from asgi_lifespan import LifespanManager
from fastapi import FastAPI
from pydantic import ValidationError

from server.app import create_app
from server.config import Settings

ALLOWED = "https://console.example.com"
PREFLIGHT = {
    "Access-Control-Request-Method": "POST",
    "Access-Control-Request-Headers": "authorization, content-type",
}


@pytest.fixture
async def cors_app(settings: Settings) -> AsyncIterator[FastAPI]:
    application = create_app(settings.model_copy(update={"cors_origins": [ALLOWED]}))
    async with LifespanManager(application):
        yield application


@pytest.fixture
async def cors_client(cors_app: FastAPI) -> AsyncIterator[httpx.AsyncClient]:
    transport = httpx.ASGITransport(app=cors_app)
    async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
        yield c


async def test_a_preflight_from_an_allowed_origin_succeeds(
    cors_client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    r = await cors_client.options("/v1/sessions", headers={"Origin": ALLOWED, **PREFLIGHT})
    assert r.status_code == 200, r.text
    assert r.headers["access-control-allow-origin"] == ALLOWED
    assert "POST" in r.headers["access-control-allow-methods"]
    assert "authorization" in r.headers["access-control-allow-headers"].lower()
    # and the call itself carries the header, errors included
    r = await cors_client.get("/v1/sites", headers={"Origin": ALLOWED, **admin})
    assert r.status_code == 200
    assert r.headers["access-control-allow-origin"] == ALLOWED
    r = await cors_client.get("/v1/sites", headers={"Origin": ALLOWED})
    assert r.status_code == 401
    assert r.headers["access-control-allow-origin"] == ALLOWED


async def test_other_origins_get_no_cors_headers(
    cors_client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    for origin in ("https://evil.example.com", "http://console.example.com"):
        r = await cors_client.options("/v1/sessions", headers={"Origin": origin, **PREFLIGHT})
        assert r.status_code >= 400
        assert "access-control-allow-origin" not in r.headers
        r = await cors_client.get("/v1/sites", headers={"Origin": origin, **admin})
        assert "access-control-allow-origin" not in r.headers


async def test_no_origin_is_allowed_by_default(
    client: httpx.AsyncClient, settings: Settings
) -> None:
    assert settings.cors_origins == []
    r = await client.options("/v1/sessions", headers={"Origin": ALLOWED, **PREFLIGHT})
    assert r.status_code == 405
    assert "access-control-allow-origin" not in r.headers


def test_origins_come_comma_separated_and_are_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("INDOORPOS_CORS_ORIGINS", "https://A.example.com, http://localhost:5173")
    assert Settings().cors_origins == ["https://a.example.com", "http://localhost:5173"]
    monkeypatch.setenv("INDOORPOS_CORS_ORIGINS", "")
    assert Settings().cors_origins == []
    for bad in ("https://a.example.com/", "a.example.com", "https://a.example.com/console"):
        monkeypatch.setenv("INDOORPOS_CORS_ORIGINS", bad)
        with pytest.raises(ValidationError, match="cors_origins"):
            Settings()
