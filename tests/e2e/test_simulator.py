"""Simulated walkers through the real server over HTTP and WebSocket (a short smoke run)."""

from __future__ import annotations

from client_sim.run import run_walkers
from tests.conftest import ADMIN_KEY


async def test_walkers_get_fixes_live_without_errors(live_url: str) -> None:
    summary = await run_walkers(live_url, ADMIN_KEY, walkers=3, duration_s=4.0, seed=1)
    result = summary.to_json_dict()
    assert list(result)[:6] == [
        "walkers",
        "fixes",
        "mean_error_m",
        "p95_error_m",
        "ws_messages",
        "errors",
    ]
    assert result["errors"] == 0, result.get("error_messages")
    assert result["walkers"] == 3
    assert result["fixes"] > 0
    assert result["ws_messages"] == result["fixes"]
    # a dense survey of the synthetic building: the filter stays within a few metres
    assert result["mean_error_m"] < 3.0
