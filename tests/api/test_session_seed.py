"""A session's random stream: fresh by default, the given one with ``seed`` (a replay of
an in-process run draws what the run drew)."""

from __future__ import annotations

import math
from typing import Any

import httpx

from tests.support.toy_site import build_toy_site, rssi_at

T0 = 1_700_000_000_000


def _batches() -> list[list[dict[str, Any]]]:
    out: list[list[dict[str, Any]]] = [
        [{"type": "wifi", "t": T0, "readings": rssi_at(4.0, 5.0, 0)}]
    ]
    for seq in range(2, 5):
        out.append(
            [
                {
                    "type": "step",
                    "t": T0 + 1000 * seq + 500 * i,
                    "length_m": 0.7,
                    "heading_rad": math.pi / 2,
                }
                for i in range(2)
            ]
        )
    return out


async def _walk(
    client: httpx.AsyncClient, site_id: str, device: dict[str, str], seed: int | None
) -> list[tuple[float, float]]:
    body: dict[str, Any] = {"site_id": site_id, "engine": "pf_magnetic"}
    if seed is not None:
        body["seed"] = seed
    r = await client.post("/v1/sessions", json=body, headers=device)
    assert r.status_code == 201, r.text
    auth = {"Authorization": f"Bearer {r.json()['token']}"}
    url = f"/v1/sessions/{r.json()['id']}/batches"
    fixes = []
    for seq, events in enumerate(_batches(), start=1):
        answer = await client.post(url, json={"seq": seq, "events": events}, headers=auth)
        assert answer.status_code == 200, answer.text
        fixes += [(f["x_m"], f["y_m"]) for f in answer.json()["fixes"]]
    return fixes


async def test_sessions_of_one_seed_draw_the_same_and_fresh_ones_do_not(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    first = await _walk(client, site.site_id, site.device, seed=7)
    again = await _walk(client, site.site_id, site.device, seed=7)
    fresh = await _walk(client, site.site_id, site.device, seed=None)
    assert len(first) == len(again) == len(fresh) > 1
    assert first == again
    assert first != fresh  # the particles' steps are drawn: another stream moves them


async def test_a_seed_out_of_range_is_refused_naming_it(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    for seed in (-1, 2**128, "7"):
        r = await client.post(
            "/v1/sessions",
            json={"site_id": site.site_id, "engine": "pf_magnetic", "seed": seed},
            headers=site.device,
        )
        assert r.status_code == 422, r.text
        assert "seed" in r.text
