"""A ``pf_magnetic`` session through the API: a scan starts the particle cloud, the
phone's steps move it, and its state (3,000 particles) is stored between batches."""

from __future__ import annotations

import math

import httpx

from tests.support.toy_site import build_toy_site, rssi_at

T0 = 1_700_000_000_000


async def test_pf_magnetic_session_follows_steps(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    r = await client.post(
        "/v1/sessions",
        json={"site_id": site.site_id, "engine": "pf_magnetic"},
        headers=site.device,
    )
    assert r.status_code == 201, r.text
    sid, token = r.json()["id"], r.json()["token"]
    auth = {"Authorization": f"Bearer {token}"}
    url = f"/v1/sessions/{sid}/batches"
    start = {"type": "wifi", "t": T0, "readings": rssi_at(4.0, 5.0, 0)}
    r = await client.post(url, json={"seq": 1, "events": [start]}, headers=auth)
    assert r.status_code == 200, r.text
    (first,) = r.json()["fixes"]
    assert math.hypot(first["x_m"] - 4.0, first["y_m"] - 5.0) < 2.0
    for seq in range(2, 6):
        steps = [
            {
                "type": "step",
                "t": T0 + 1000 * seq + 500 * i,
                "length_m": 0.7,
                "heading_rad": math.pi / 2,
            }
            for i in range(2)
        ]
        r = await client.post(url, json={"seq": seq, "events": steps}, headers=auth)
        assert r.status_code == 200, r.text
        assert [f["source"] for f in r.json()["fixes"]] == ["step", "step"]
    last = r.json()["fixes"][-1]
    # eight steps east from wherever the cloud started
    assert last["x_m"] - first["x_m"] > 4.0
    assert last["engine"] == "pf_magnetic"
