"""Simulated walkers through the real server over HTTP and WebSocket (short smoke runs)."""

from __future__ import annotations

import pytest

from client_sim.run import run_walkers
from tests.support.admin_key import ADMIN_KEY


@pytest.mark.slow
async def test_walkers_over_http_get_fixes_live_without_errors(live_url: str) -> None:
    summary = await run_walkers(
        live_url, ADMIN_KEY, walkers=3, duration_s=4.0, seed=1, batch_steps=2
    )
    result = summary.to_json_dict()
    assert result["errors"] == 0, result.get("error_messages")
    assert result["users"] == 3
    assert result["transport"] == "http"
    assert result["fixes"] > 0
    assert result["ws_messages"] == result["fixes"]
    # whole batches of two steps each, a step every 0.67 s: about 4 s / 0.67 s per walker
    assert result["steps"] == 2 * result["batches"]
    assert 3 * 4 <= result["steps"] <= 3 * 7
    assert result["p50_ms"] <= result["p95_ms"] <= result["p99_ms"]
    # a dense survey of the synthetic building: the filter stays within a few metres
    assert result["mean_error_m"] < 3.0


@pytest.mark.slow
async def test_walkers_post_over_the_socket_on_a_reused_site(live_url: str) -> None:
    first = await run_walkers(live_url, ADMIN_KEY, walkers=1, duration_s=1.5, seed=2)
    assert first.errors == 0, first.error_messages
    summary = await run_walkers(
        live_url,
        ADMIN_KEY,
        walkers=3,
        duration_s=4.0,
        seed=2,
        transport="ws",
        engine="pf_magnetic",
        site_id=first.site_id,
    )
    assert summary.errors == 0, summary.error_messages
    assert summary.site_id == first.site_id
    assert summary.transport == "ws"
    assert summary.batches == summary.steps >= 3 * 4
    assert summary.fixes > 0
    # each fix of a batch answered on the socket was also pushed as a fix message
    assert summary.ws_messages == summary.fixes
    assert summary.batches_missing_on_socket == 0
    assert summary.mean_error_m is not None
    assert summary.mean_error_m < 5.0


@pytest.mark.slow
async def test_walkers_on_a_redis_cluster(cluster_live_url: str) -> None:
    """Sessions in a 3-node Redis Cluster: batches over the socket, each fix pushed live
    from the shard that owns the session."""
    summary = await run_walkers(
        cluster_live_url, ADMIN_KEY, walkers=3, duration_s=3.0, seed=4, transport="ws"
    )
    assert summary.errors == 0, summary.error_messages
    assert summary.fixes > 0
    assert summary.ws_messages == summary.fixes
    assert summary.batches_missing_on_socket == 0
