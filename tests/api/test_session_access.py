"""Reading a session with a viewer key as well as its token, its bounded track, and the
batch answer naming the event kinds its engine ignored."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from server.config import Settings
from tests.support.toy_site import ToySite, build_toy_site, device_headers, rssi_at

T0 = 1_700_000_000_000
TRACK_LEN = 5


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


@pytest.fixture
def short_track(settings: Settings) -> Iterator[None]:
    original = settings.session_track_len
    settings.session_track_len = TRACK_LEN
    yield
    settings.session_track_len = original


async def _open(
    client: httpx.AsyncClient, site: ToySite, engine: str = "step_ekf"
) -> tuple[str, dict[str, str]]:
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, "engine": engine}, headers=site.device
    )
    assert r.status_code == 201, r.text
    return r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}


def _scan(t: int, x: float = 5.0, y: float = 5.0) -> dict[str, Any]:
    return {"type": "wifi", "t": t, "readings": rssi_at(x, y, 0)}


def _step(t: int) -> dict[str, Any]:
    return {"type": "step", "t": t, "length_m": 0.7, "heading_rad": math.pi / 2}


async def _batch(
    client: httpx.AsyncClient, sid: str, auth: dict[str, str], seq: int, events: list[Any]
) -> dict[str, Any]:
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": events}, headers=auth
    )
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


async def test_viewer_and_admin_keys_read_a_session_a_device_key_does_not(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    sid, auth = await _open(client, site)
    await _batch(client, sid, auth, 1, [_scan(T0)])
    own = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert own["last_seq"] == 1
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    maps_writer = await device_headers(client, admin, ("maps:write",))
    for headers in (admin, viewer, maps_writer):
        r = await client.get(f"/v1/sessions/{sid}", headers=headers)
        assert r.status_code == 200, r.text
        assert r.json() == own
    # a device key, even of the site, reads only the sessions it holds the tokens of;
    # another session's token, not this one; a viewer of another site hears of it what
    # it hears of a session that does not exist
    other = await build_toy_site(client, admin)
    stranger = await device_headers(client, admin, ("viewer",), other.site_id)
    _, other_auth = await _open(client, site)
    for headers in (site.device, other_auth):
        r = await client.get(f"/v1/sessions/{sid}", headers=headers)
        assert r.status_code == 403, r.text
        assert "authorization" in r.json()["message"]
        r = await client.get(f"/v1/sessions/{sid}/track", headers=headers)
        assert r.status_code == 403, r.text
    missing = "0" * 32
    for path in ("", "/track"):
        theirs = await client.get(f"/v1/sessions/{sid}{path}", headers=stranger)
        none = await client.get(f"/v1/sessions/{missing}{path}", headers=stranger)
        assert theirs.status_code == none.status_code == 404, theirs.text
        assert theirs.text.replace(sid, missing) == none.text
    # a key reads; it does not post batches or end the session
    batch = {"seq": 2, "events": [_step(T0 + 600)]}
    r = await client.post(f"/v1/sessions/{sid}/batches", json=batch, headers=admin)
    assert r.status_code == 403
    assert (await client.delete(f"/v1/sessions/{sid}", headers=admin)).status_code == 403
    # once ended: the token is refused as before, a viewer hears it is gone
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    assert (await client.get(f"/v1/sessions/{sid}", headers=auth)).status_code == 403
    r = await client.get(f"/v1/sessions/{sid}", headers=viewer)
    assert r.status_code == 404
    assert r.json()["detail"][0]["loc"] == ["session_id"]


async def test_the_track_holds_the_newest_fixes_up_to_its_bound(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite, short_track: None
) -> None:
    sid, auth = await _open(client, site)
    url = f"/v1/sessions/{sid}/track"
    empty = (await client.get(url, headers=auth)).json()
    assert empty == {"items": [], "count": 0, "max_fixes": TRACK_LEN}
    fixes = (await _batch(client, sid, auth, 1, [_scan(T0)]))["fixes"]
    for seq in range(2, 5):
        events = [_step(T0 + 600 * seq), _step(T0 + 600 * seq + 300)]
        fixes += (await _batch(client, sid, auth, seq, events))["fixes"]
    await _batch(client, sid, auth, 4, [_step(T0 + 2400), _step(T0 + 2700)])  # a retry
    assert len(fixes) == 7
    track = (await client.get(url, headers=auth)).json()
    assert track["count"] == TRACK_LEN
    assert track["items"] == fixes[-TRACK_LEN:]  # oldest first, the retry not twice
    assert (await client.get(url, params={"limit": 2}, headers=admin)).json()["items"] == fixes[-2:]
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    assert (await client.get(url, headers=viewer)).json() == track
    state = (await client.get(f"/v1/sessions/{sid}", headers=viewer)).json()
    assert state["last_fix"] == fixes[-1]
    for bad in (0, 5001, "x"):
        r = await client.get(url, params={"limit": bad}, headers=auth)
        assert r.status_code == 422
        assert r.json()["message"].startswith("limit:")
    # the track ends with its session
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    assert (await client.get(url, headers=admin)).status_code == 404


def _imu(t: int, *, accel: bool = False, pressure: bool = False) -> dict[str, Any]:
    """A block of raw samples: an accelerometer row and a barometer row, as asked."""
    block: dict[str, Any] = {"type": "imu", "t": t}
    if accel:
        block["accel"] = [[t, 0.0, 0.0, 9.81]]
    if pressure:
        block["pressure"] = [[t, 1013.2]]
    return block


@pytest.mark.parametrize(
    ("engine", "events", "not_used"),
    [
        # two_stage_ekf runs its own PDR on raw samples: phone-detected steps go unread
        ("two_stage_ekf", [_step(T0), _step(T0 + 500)], ["step"]),
        ("wknn", [_scan(T0), _step(T0 + 500)], ["step"]),
        ("step_ekf", [_scan(T0), _step(T0 + 500)], []),
        (
            "step_ekf",
            [
                _scan(T0),
                {"type": "gnss", "t": T0, "lat_deg": 41.0, "lon_deg": 2.0, "accuracy_m": 5},
            ],
            ["gnss"],
        ),
        # an engine reading steps reads the barometer of a block, not its motion rows
        ("step_ekf", [_step(T0), _imu(T0, pressure=True)], []),
        ("step_ekf", [_step(T0), _imu(T0, accel=True, pressure=True)], ["imu"]),
        ("wknn", [_scan(T0), _imu(T0, accel=True)], ["imu"]),
        ("two_stage_ekf", [_imu(T0, accel=True, pressure=True)], []),
    ],
)
async def test_the_answer_names_the_event_kinds_the_engine_ignored(
    client: httpx.AsyncClient,
    site: ToySite,
    engine: str,
    events: list[dict[str, Any]],
    not_used: list[str],
) -> None:
    sid, auth = await _open(client, site, engine)
    first = await _batch(client, sid, auth, 1, events)
    assert first["not_used"] == not_used
    if engine == "two_stage_ekf":
        assert first["fixes"] == []  # nothing it reads: no fix, and now it says why
    again = await _batch(client, sid, auth, 1, events)
    assert again["replayed"] is True
    assert again["not_used"] == not_used
