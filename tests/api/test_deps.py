"""Credentials and sites (``server.api.deps``): a key of one site learns nothing of
another site's things; it hears of them what it hears of things that were never made."""

from __future__ import annotations

import re
from typing import Any

import httpx
import pytest
from fastapi import FastAPI

from tests.support.toy_site import ToySite, build_toy_site, device_headers

T0 = 1_700_000_000_000
MISSING = "0123456789abcdef" * 2
# the path parameters naming a thing of a site; any other is filled with a plausible value
THINGS = ("site_id", "building_id", "floor_id", "upload_id", "session_id")
OTHER_PARAMS = {"version": "1", "name": "wknn"}


@pytest.fixture
async def mine(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def _things_of(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> dict[str, str]:
    """An id of each kind of thing of ``site``: itself, a building, a floor, an open
    session, an upload."""
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, "engine": "wknn"}, headers=site.device
    )
    assert r.status_code == 201, r.text
    walk = {
        "events": [{"type": "step", "t": T0, "length_m": 0.7, "heading_rad": 0.0}],
        "anchors": [{"t": T0, "x_m": 1.0, "y_m": 1.0}],
    }
    upload = await client.post(
        "/v1/uploads", params={"site_id": site.site_id}, json=walk, headers=admin
    )
    assert upload.status_code in (200, 202), upload.text
    return {
        "site_id": site.site_id,
        "building_id": site.building_id,
        "floor_id": site.floor_ids[0],
        "session_id": r.json()["id"],
        "upload_id": upload.json()["id"],
    }


def _routes(app: FastAPI) -> list[tuple[str, str]]:
    """Every (method, path) of the API whose path names a thing of a site."""
    paths = app.openapi()["paths"]
    return [
        (method.upper(), path)
        for path, methods in paths.items()
        for method in methods
        if any(f"{{{thing}}}" in path for thing in THINGS)
    ]


def _filled(path: str, ids: dict[str, str]) -> str:
    return re.sub(r"\{(\w+)\}", lambda m: ids.get(m[1], OTHER_PARAMS.get(m[1], "x")), path)


async def test_another_site_s_things_answer_as_missing_ones_on_every_route(
    client: httpx.AsyncClient, app: FastAPI, admin: dict[str, str], mine: ToySite
) -> None:
    theirs = await _things_of(client, admin, await build_toy_site(client, admin))
    missing = dict.fromkeys(theirs, MISSING)
    # a key of this site that may do everything there
    key = await device_headers(client, admin, ("admin",), mine.site_id)
    routes = _routes(app)
    assert len(routes) >= 20
    for method, path in routes:
        answers = []
        for ids in (theirs, missing):
            body: Any = {} if method in ("POST", "PUT") else None
            r = await client.request(method, _filled(path, ids), json=body, headers=key)
            text = r.text
            for thing_id in ids.values():
                text = text.replace(thing_id, "<id>")
            answers.append((r.status_code, text))
        assert answers[0] == answers[1], (method, path, answers)
        assert answers[0][0] in (403, 404), (method, path, answers)


async def test_a_key_of_every_site_still_reaches_every_site(
    client: httpx.AsyncClient, admin: dict[str, str], mine: ToySite
) -> None:
    r = await client.get(f"/v1/buildings/{mine.building_id}/floors", headers=admin)
    assert r.status_code == 200, r.text
    viewer = await device_headers(client, admin, ("viewer",))
    r = await client.get(f"/v1/floors/{mine.floor_ids[1]}", headers=viewer)
    assert r.status_code == 200, r.text
