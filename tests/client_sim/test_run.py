"""Summary and the API client's request shapes (through a mock transport, no server)."""

from __future__ import annotations

import json
from typing import Any

import httpx
import pytest

from client_sim.api import ApiClient, ApiError, BatchResult, Fix, Session, live_url
from client_sim.run import Summary, WalkerStats, step_batches, summarize
from client_sim.seeding import sequence
from client_sim.walker import TimedEvent, Truth, TruthTrack, Walker
from client_sim.world import synthesize_world

HEADLINE = [
    "users",
    "duration_s",
    "batches",
    "steps",
    "errors",
    "p50_ms",
    "p95_ms",
    "p99_ms",
    "fixes_per_s",
    "mean_error_m",
]
CREATED = {"id": "s1", "token": "t", "site_id": "site", "engine": "step_ekf", "idle_timeout_s": 60}
FIX = {"t": 5, "x_m": 1, "y_m": 2, "floor": None}
PLAN = {"type": "FeatureCollection", "features": []}
SESSION = Session(id="s1", token="tok/en+", site_id="site", engine="step_ekf", idle_timeout_s=60)


def fix(t: int, x_m: float, y_m: float, floor: int | None = 0) -> Fix:
    body = {"t": t, "x_m": x_m, "y_m": y_m, "floor": floor, "uncertainty_m": 1.0,
            "source": "wifi", "engine": "step_ekf"}  # fmt: skip
    return Fix.from_wire(body)


def test_summary_json_starts_with_the_headline_figures() -> None:
    stats = WalkerStats()
    track = TruthTrack()
    track.add(Truth(0, 0.0, 0.0, 0, 0.0))
    track.add(Truth(1000, 10.0, 0.0, 0, 0.0))
    result = BatchResult(1, False, (fix(500, 5.0, 3.0), fix(1000, 10.0, 4.0, floor=1)))
    stats.add_fixes(result, track)
    stats.latencies_ms += [10.0, 30.0]
    stats.sent_s += [5.0, 65.0]
    stats.batches, stats.steps, stats.ws_messages, stats.sessions = 2, 3, 2, 1
    stats.errors.append("walker 0: batch seq 3: 503 busy")
    other = WalkerStats(errors=[f"e{i}" for i in range(20)])
    summary = summarize([stats, other], users=2, engine="step_ekf", site_id="x", duration_s=5.0)
    out = summary.to_json_dict()
    assert list(out)[:10] == HEADLINE
    assert out["fixes"] == 2
    assert out["fixes_per_s"] == pytest.approx(0.4)
    assert out["steps"] == 3
    assert out["mean_error_m"] == pytest.approx(3.5)
    assert out["p95_error_m"] == pytest.approx(3.95)
    assert out["floor_hit_rate"] == 0.5
    assert out["p50_ms"] == pytest.approx(20.0)
    assert out["p99_ms"] == pytest.approx(29.8)
    assert out["p99_ms_by_minute"] == [10.0, 30.0]
    assert out["errors"] == 21
    assert out["error_messages"][0] == "walker 0: batch seq 3: 503 busy"
    assert len(out["error_messages"]) == 10
    json.dumps(out, allow_nan=False)


def test_summary_without_fixes_is_still_json() -> None:
    summary = summarize([WalkerStats()], users=1, engine="e", site_id=None, duration_s=1.0)
    assert isinstance(summary, Summary)
    out = summary.to_json_dict()
    assert out["fixes"] == 0
    assert out["mean_error_m"] is None
    assert out["p99_ms"] is None
    assert out["floor_hit_rate"] is None
    assert json.loads(json.dumps(out, allow_nan=False)) == out


def test_live_url_follows_the_base_url() -> None:
    assert live_url("http://h:8000", SESSION) == "ws://h:8000/v1/sessions/s1/live"
    assert live_url("https://h/api/?x=1", SESSION) == "wss://h/api/v1/sessions/s1/live"


async def test_client_sends_the_contract() -> None:
    seen: list[tuple[str, str, str | None, Any]] = []

    def handler(request: httpx.Request) -> httpx.Response:
        body = json.loads(request.content) if request.content else None
        seen.append((request.method, request.url.path, request.headers.get("authorization"), body))
        path = request.url.path
        if path == "/base/v1/sessions":
            return httpx.Response(201, json=CREATED)
        if path == "/base/v1/keys":
            return httpx.Response(201, json={"id": "k", "key": "dev"})
        if path.endswith("/batches"):
            assert body is not None
            if body["seq"] == 2:
                return httpx.Response(409, json={"detail": [], "message": "seq: out of order"})
            answer = {"session_id": "s1", "seq": 1, "replayed": False, "fixes": [FIX]}
            return httpx.Response(200, json=answer)
        if request.method == "DELETE":
            return httpx.Response(204)
        if path.endswith("/plan"):
            return httpx.Response(500, text="boom")
        return httpx.Response(201, json={"id": "new"})

    transport = httpx.MockTransport(handler)
    async with httpx.AsyncClient(transport=transport, base_url="http://test/base") as http:
        api = ApiClient(http, admin_key="adm")
        assert (await api.create_site("s"))["id"] == "new"
        await api.create_building("site", "b")
        await api.create_floor("bld", 1, "one")
        await api.post_survey("bld", {"points": []})
        with pytest.raises(ApiError) as plan_error:
            await api.put_plan("fl", PLAN)
        assert plan_error.value.status == 500
        assert plan_error.value.message == "boom"
        session = await api.create_session("site", "step_ekf")
        result = await api.post_batch(session, 1, [{"type": "wifi", "t": 5, "readings": []}])
        assert result.fixes[0].floor is None
        assert result.fixes[0].x_m == 1.0
        with pytest.raises(ApiError) as conflict:
            await api.post_batch(session, 2, [])
        assert conflict.value.status == 409
        assert conflict.value.message == "seq: out of order"
        await api.delete_session(session)
        with pytest.raises(ValueError, match="admin key"):
            await ApiClient(http).create_site("no key")
    assert seen == [
        ("POST", "/base/v1/sites", "Bearer adm", {"name": "s"}),
        ("POST", "/base/v1/sites/site/buildings", "Bearer adm", {"name": "b"}),
        ("POST", "/base/v1/buildings/bld/floors", "Bearer adm", {"level": 1, "name": "one"}),
        ("POST", "/base/v1/buildings/bld/survey", "Bearer adm", {"points": []}),
        ("PUT", "/base/v1/floors/fl/plan", "Bearer adm", PLAN),
        ("POST", "/base/v1/keys", "Bearer adm", {"name": "client simulator", "scopes": ["device"]}),
        ("POST", "/base/v1/sessions", "Bearer dev", {"site_id": "site", "engine": "step_ekf"}),
        ("POST", "/base/v1/sessions/s1/batches", "Bearer t",
         {"seq": 1, "events": [{"type": "wifi", "t": 5, "readings": []}]}),
        ("POST", "/base/v1/sessions/s1/batches", "Bearer t", {"seq": 2, "events": []}),
        ("DELETE", "/base/v1/sessions/s1", "Bearer t", None),
    ]  # fmt: skip


def test_batches_hold_b_steps_with_their_scans_and_are_due_at_the_last_step() -> None:
    world = synthesize_world(0)
    walker = Walker(world, world.building.levels[0], sequence(0, "walker", 0), t0_ms=0)
    batches = step_batches(walker.events(), 3)
    seen: list[TimedEvent] = []
    previous_due = -1.0
    for _ in range(20):
        due, items = next(batches)
        steps = [i for i in items if i.event["type"] == "step"]
        assert len(steps) == 3
        assert due == steps[-1].sim_s > previous_due
        # the last step's magnetometer reading comes with it; nothing later does
        assert items[-1].event["type"] == "mag"
        assert all(i.sim_s <= due for i in items)
        previous_due = due
        seen += items
    # cut without loss or repetition: the same events as the walk itself
    again = walker.events()
    assert [i.event for i in seen] == [next(again).event for _ in seen]
