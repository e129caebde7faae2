"""A session whose batches land on two api replicas in turn (a proxy that lost its
affinity, a replica restarted mid-walk) gives the fixes one replica alone gives: each
replica reads what the other wrote (a snapshot and the batches logged since) and steps
the engine through it with the session's random stream."""

from __future__ import annotations

import httpx
import pytest

from tests.support.admin_key import ADMIN_KEY
from tests.support.toy_site import ToySite, build_toy_site, walk_batch

ADMIN = {"Authorization": f"Bearer {ADMIN_KEY}"}
BATCHES = 40


async def _walk(clients: list[httpx.AsyncClient], site: ToySite, engine: str) -> list[object]:
    """Open a session (seeded) and post the walk, batch ``n`` to ``clients[n % len]``."""
    r = await clients[0].post(
        "/v1/sessions",
        json={"site_id": site.site_id, "engine": engine, "seed": 11},
        headers=site.device,
    )
    assert r.status_code == 201, r.text
    sid, auth = r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}
    answers = []
    for n in range(1, BATCHES + 1):
        client = clients[n % len(clients)]
        r = await client.post(
            f"/v1/sessions/{sid}/batches", json={"seq": n, "events": walk_batch(n)}, headers=auth
        )
        assert r.status_code == 200, r.text
        assert not r.json()["reinitialised"]
        answers.append(r.json()["fixes"])
    return answers


@pytest.mark.parametrize("engine", ["pf_magnetic", "step_ekf"])
async def test_a_session_moved_between_replicas_gives_the_fixes_of_one(
    live_url: str, replica_url: str, engine: str
) -> None:
    async with (
        httpx.AsyncClient(base_url=live_url, timeout=30) as a,
        httpx.AsyncClient(base_url=replica_url, timeout=30) as b,
    ):
        site = await build_toy_site(a, ADMIN)
        alone = await _walk([a], site, engine)
        taking_turns = await _walk([a, b], site, engine)
        # a few batches on one, then the other, and back
        in_runs = await _walk([a, a, a, b, b, b, b, b], site, engine)
    assert taking_turns == alone
    assert in_runs == alone
