"""Sessions: exactly-once batches, ordering under concurrency, isolation, validation."""

from __future__ import annotations

import asyncio
import json
import math
from typing import Any

import httpx
import pytest

from server.api.schemas.sessions import BatchOut
from tests.support.sessions import open_session, scan, step
from tests.support.toy_site import ToySite, build_toy_site

T0 = 1_700_000_000_000


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def test_first_batch_gives_a_fix_near_the_truth(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth
    )
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/json"
    # the answer is written by hand: it must be exactly the documented BatchOut
    assert BatchOut.model_validate_json(r.content).session_id == sid
    fixes = r.json()["fixes"]
    assert len(fixes) == 1
    fix = fixes[0]
    assert math.hypot(fix["x_m"] - 5, fix["y_m"] - 5) < 1.0
    assert fix["floor"] == 0
    assert fix["floor_id"] == site.floor_ids[0]
    assert fix["engine"] == "step_ekf"
    assert fix["uncertainty_m"] > 0


async def test_same_seq_twice_is_applied_once(client: httpx.AsyncClient, site: ToySite) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth)
    batch = {"seq": 2, "events": [step(T0 + 600), step(T0 + 1200)]}
    first = await client.post(url, json=batch, headers=auth)
    again = await client.post(url, json=batch, headers=auth)
    assert first.status_code == again.status_code == 200
    assert first.json()["replayed"] is False
    assert again.json()["replayed"] is True
    assert again.json()["fixes"] == first.json()["fixes"]
    state = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert state["last_seq"] == 2
    assert state["last_fix"] == first.json()["fixes"][-1]
    # the next step continues from two steps, not four
    r = await client.post(url, json={"seq": 3, "events": [step(T0 + 1800)]}, headers=auth)
    start_x = first.json()["fixes"][0]["x_m"] - 0.7
    assert r.json()["fixes"][0]["x_m"] == pytest.approx(start_x + 3 * 0.7, abs=0.2)


async def test_reused_seq_with_other_events_is_a_conflict(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth)
    r = await client.post(url, json={"seq": 1, "events": [scan(T0, 9, 9)]}, headers=auth)
    assert r.status_code == 409
    assert "seq" in r.json()["message"]


async def test_concurrent_batches_both_apply_in_order(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth)
    # seq 3 is sent first and must wait for seq 2; both land, neither is lost
    east = {"seq": 2, "events": [step(T0 + 600, math.pi / 2), step(T0 + 1200, math.pi / 2)]}
    north = {"seq": 3, "events": [step(T0 + 1800, 0.0), step(T0 + 2400, 0.0)]}
    r3, r2 = await asyncio.gather(
        client.post(url, json=north, headers=auth), client.post(url, json=east, headers=auth)
    )
    assert r2.status_code == 200, r2.text
    assert r3.status_code == 200, r3.text
    assert r2.json()["replayed"] is False
    assert r3.json()["replayed"] is False
    start = r2.json()["fixes"][0]
    last = r3.json()["fixes"][-1]
    # two steps east then two north from where seq 2 began
    assert last["y_m"] - start["y_m"] == pytest.approx(2 * 0.7, abs=0.3)
    assert last["x_m"] - start["x_m"] == pytest.approx(0.7, abs=0.3)
    state = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert state["last_seq"] == 3


async def test_many_concurrent_batches_none_lost(client: httpx.AsyncClient, site: ToySite) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    await client.post(url, json={"seq": 1, "events": [scan(T0, 2, 5)]}, headers=auth)
    batches = [{"seq": n, "events": [step(T0 + 600 * n, math.pi / 2, 0.5)]} for n in range(2, 12)]
    responses = await asyncio.gather(*(client.post(url, json=b, headers=auth) for b in batches))
    assert [r.status_code for r in responses] == [200] * len(batches)
    state = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert state["last_seq"] == 11
    first_fix = responses[0].json()["fixes"][0]
    assert state["last_fix"]["x_m"] - first_fix["x_m"] == pytest.approx(9 * 0.5, abs=0.3)


async def test_seq_gap_times_out_with_409(
    client: httpx.AsyncClient, site: ToySite, settings: Any
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    original = settings.seq_wait_s
    settings.seq_wait_s = 0.2
    try:
        r = await client.post(url, json={"seq": 5, "events": [step(T0)]}, headers=auth)
    finally:
        settings.seq_wait_s = original
    assert r.status_code == 409
    assert r.json()["detail"][0]["loc"] == ["seq"]


async def test_other_sessions_token_is_forbidden(client: httpx.AsyncClient, site: ToySite) -> None:
    sid_a, auth_a = await open_session(client, site)
    sid_b, auth_b = await open_session(client, site)
    batch = {"seq": 1, "events": [scan(T0, 5, 5)]}
    assert (
        await client.post(f"/v1/sessions/{sid_a}/batches", json=batch, headers=auth_b)
    ).status_code == 403
    assert (await client.get(f"/v1/sessions/{sid_a}", headers=auth_b)).status_code == 403
    assert (await client.delete(f"/v1/sessions/{sid_a}", headers=auth_b)).status_code == 403
    assert (await client.get(f"/v1/sessions/{sid_a}")).status_code == 401
    # b's own session is readable with its own token, and a is untouched
    assert (await client.get(f"/v1/sessions/{sid_b}", headers=auth_b)).status_code == 200
    assert (await client.get(f"/v1/sessions/{sid_a}", headers=auth_a)).json()["last_seq"] == 0


@pytest.mark.parametrize(
    ("event", "field"),
    [
        ({"type": "step", "t": T0, "heading_rad": 0.0}, "events.1.length_m"),
        ({"type": "step", "t": T0, "length_m": -0.5, "heading_rad": 0.0}, "events.1.length_m"),
        (
            {"type": "step", "t": T0, "length_m": 0.7, "heading_rad": float("nan")},
            "events.1.heading_rad",
        ),
        ({"type": "teleport", "t": T0}, "events.1.type"),
        (
            {"type": "wifi", "t": T0, "readings": [{"bssid": "aa", "rssi_dbm": float("nan")}]},
            "events.1.readings.0.rssi_dbm",
        ),
        ({"type": "wifi", "readings": []}, "events.1.t"),
        (
            {"type": "wifi", "t": T0, "readings": [{"bssid": "aa", "rssi_dbm": -60, "age_ms": -1}]},
            "events.1.readings.0.age_ms",
        ),
        (
            {"type": "ble", "t": T0, "readings": [{"id": "b", "rssi_dbm": -60, "age_ms": 10**9}]},
            "events.1.readings.0.age_ms",
        ),
        ({"type": "mag", "t": T0}, "events.1"),
        ({"type": "step", "t": 2**63, "length_m": 0.7, "heading_rad": 0.0}, "events.1.t"),
        (
            {"type": "ble", "t": T0, "readings": [{"id": "a\u0000", "rssi_dbm": -60}]},
            "events.1.readings.0.id",
        ),
        # no phone's magnetometer reads more than ±4900 µT on an axis
        ({"type": "mag", "t": T0, "field_ut": [1e308, 0.0, 0.0]}, "events.1.field_ut.0"),
        ({"type": "mag", "t": T0, "field_ut": [20.0, 0.0, -5000.5]}, "events.1.field_ut.2"),
        # an azimuth is at most one turn either way
        ({"type": "step", "t": T0, "length_m": 0.7, "heading_rad": 1e308}, "events.1.heading_rad"),
        ({"type": "step", "t": T0, "length_m": 0.7, "heading_rad": -6.3}, "events.1.heading_rad"),
    ],
)
async def test_malformed_events_get_422_naming_the_field(
    client: httpx.AsyncClient, site: ToySite, event: dict[str, Any], field: str
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth)
    before = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    # a valid step first: the whole batch is refused, not just the bad event
    body = json.dumps({"seq": 2, "events": [step(T0 + 600), event]})  # NaN as a bare token
    r = await client.post(url, content=body, headers={**auth, "content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert field in r.json()["message"]
    after = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert after == before


async def test_unknown_engine_and_site_are_rejected(
    client: httpx.AsyncClient, site: ToySite, admin: dict[str, str]
) -> None:
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, "engine": "nope"}, headers=site.device
    )
    assert r.status_code == 422
    assert "engine" in r.json()["message"]
    r = await client.post("/v1/sessions", json={"site_id": "0" * 32}, headers=admin)
    assert r.status_code == 404
    assert "site_id" in r.json()["message"]


async def test_deleted_session_is_gone(client: httpx.AsyncClient, site: ToySite) -> None:
    sid, auth = await open_session(client, site)
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    assert (await client.get(f"/v1/sessions/{sid}", headers=auth)).status_code == 403


async def test_the_extremes_of_the_plausible_ranges_are_accepted(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    events = [
        scan(T0, 5, 5),
        {"type": "mag", "t": T0 + 1, "field_ut": [5000.0, -5000.0, 0.0]},
        step(T0 + 600, heading_rad=2 * math.pi),
        step(T0 + 1200, heading_rad=-2 * math.pi),
    ]
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": events}, headers=auth
    )
    assert r.status_code == 200, r.text


DAY_MS = 86_400_000  # the default max_event_skew_s


@pytest.mark.parametrize(
    ("events", "field"),
    [
        # the session's newest event is at T0 + 600
        ([step(T0 + 1200), step(T0 + 600 + DAY_MS + 1)], "events.1.t"),
        ([step(T0 + 600 - DAY_MS - 1)], "events.0.t"),
        ([step(T0 + 2**40)], "events.0.t"),
        # each within a day of the session's clock, but more than a day apart
        ([step(T0 + 600 - DAY_MS // 2 - 1), step(T0 + 600 + DAY_MS // 2 + 1)], "events.1.t"),
    ],
)
async def test_event_times_far_from_the_sessions_clock_are_refused_whole(
    client: httpx.AsyncClient, site: ToySite, events: list[dict[str, Any]], field: str
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    first = [scan(T0, 5, 5), step(T0 + 600)]
    r = await client.post(url, json={"seq": 1, "events": first}, headers=auth)
    assert r.status_code == 200, r.text
    before = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    r = await client.post(url, json={"seq": 2, "events": events}, headers=auth)
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith(f"{field}: "), r.json()
    assert (await client.get(f"/v1/sessions/{sid}", headers=auth)).json() == before
    # nothing was applied and seq 2 is still free: the corrected batch goes in as new
    r = await client.post(url, json={"seq": 2, "events": [step(T0 + 1200)]}, headers=auth)
    assert r.status_code == 200, r.text
    assert r.json()["replayed"] is False
    start_x = before["last_fix"]["x_m"]
    assert r.json()["fixes"][-1]["x_m"] == pytest.approx(start_x + 0.7, abs=0.2)


async def test_the_sessions_clock_is_its_own_newest_event(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    """Times are checked against the session's own events, not the server's clock (a
    replay posts a recorded walk's times, years old); the newest time accepted so far is
    the session's clock, a day either way."""
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    recorded = 1_370_000_000_000  # 2013
    r = await client.post(
        url,
        json={"seq": 1, "events": [scan(recorded, 5, 5), step(recorded + DAY_MS + 1)]},
        headers=auth,
    )
    assert r.status_code == 422, r.text  # one batch spans at most a day
    assert r.json()["message"].startswith("events.1.t: "), r.json()
    accepted = [
        [scan(recorded, 5, 5)],
        [step(recorded + DAY_MS)],  # a day on: still in
        # a day from the newest time so far, not from the first; the batch's last event
        # is not its newest
        [step(recorded + 2 * DAY_MS), step(recorded + 2 * DAY_MS - 1000)],
    ]
    for seq, events in enumerate(accepted, start=1):
        r = await client.post(url, json={"seq": seq, "events": events}, headers=auth)
        assert r.status_code == 200, r.text
    # more than a day before the newest
    late = {"seq": 4, "events": [step(recorded + DAY_MS - 1)]}
    r = await client.post(url, json=late, headers=auth)
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("events.0.t: "), r.json()
    # a retry of a batch the session applied is answered from its record, however far
    # the session's clock has moved on since
    first = {"seq": 1, "events": accepted[0]}
    r = await client.post(url, json=first, headers=auth)
    assert r.status_code == 200, r.text
    assert r.json()["replayed"] is True


@pytest.mark.parametrize(
    ("content", "content_type", "error"),
    [
        (b"", "application/json", "missing"),  # no body at all
        (b'{"seq": 1, "events": [', "application/json", "json_invalid"),
        (b'{"seq": 1, "events": [\xff]}', "application/json", None),  # not UTF-8: 400
        (b'{"seq": 1, "events": []}', None, "model_type"),  # JSON only when it says so
        (b'{"seq": 1, "events": []}', "text/plain", "model_type"),
        (b'{"seq": 0, "events": []}', "application/vnd.indoorpos+json", "greater_than_equal"),
    ],
)
async def test_a_batch_body_is_read_as_json_only_under_a_json_content_type(
    client: httpx.AsyncClient,
    site: ToySite,
    content: bytes,
    content_type: str | None,
    error: str | None,
) -> None:
    sid, auth = await open_session(client, site)
    headers = auth if content_type is None else {**auth, "content-type": content_type}
    r = await client.post(f"/v1/sessions/{sid}/batches", content=content, headers=headers)
    if error is None:
        assert r.status_code == 400, r.text
    else:
        assert r.status_code == 422, r.text
        (detail,) = r.json()["detail"]
        assert detail["loc"][0] == "body"
        assert detail["type"] == error
        if error == "json_invalid":  # where, as the framework says it
            assert r.json()["message"].endswith("at character 22)")
    r = await client.post(
        f"/v1/sessions/{sid}/batches",
        content=b'{"seq": 1, "events": []}',
        headers={**auth, "content-type": "application/json; charset=utf-8"},
    )
    assert r.status_code == 200, r.text
