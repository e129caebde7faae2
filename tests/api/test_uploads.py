"""Uploads through the API: a recorded ILC trace becomes map versions through the worker;
idempotency keys, malformed and oversized traces, walks the server cannot place."""

from __future__ import annotations

import asyncio
import lzma
import math
import time
from collections.abc import AsyncIterator
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi import FastAPI
from sqlalchemy import func, select

from server import worker
from server.storage.models import SurveyPoint, Upload
from tests.support.datasets import DATA_DIR
from tests.support.toy_site import device_headers

TRACES = DATA_DIR / "ilc20-sample" / "site2" / "F4" / "path_data_files"
needs_data = pytest.mark.skipif(not TRACES.is_dir(), reason="../shared/data is not beside us")
SETTLE_TIMEOUT_S = 60.0


@pytest.fixture
async def upload_worker(app: FastAPI) -> AsyncIterator[None]:
    """A worker on the app's queue when the app runs none itself (Redis configured)."""
    rt = app.state.runtime
    if rt.settings.runs_worker_in_process:
        yield
        return
    import anyio

    stop = anyio.Event()
    task = asyncio.create_task(worker.run(rt, "test-worker", stop))
    yield
    stop.set()
    await asyncio.wait_for(task, timeout=10)


async def _site(client: httpx.AsyncClient, admin: dict[str, str], levels: list[int]) -> str:
    r = await client.post("/v1/sites", json={"name": "crowd"}, headers=admin)
    site_id: str = r.json()["id"]
    r = await client.post(f"/v1/sites/{site_id}/buildings", json={"name": "mall"}, headers=admin)
    building_id = r.json()["id"]
    for level in levels:
        r = await client.post(
            f"/v1/buildings/{building_id}/floors", json={"level": level}, headers=admin
        )
        assert r.status_code == 201, r.text
    return site_id


def _trace_text(name: str = "5dd3a33227889b0006b76d2d") -> bytes:
    return lzma.decompress((TRACES / f"{name}.txt.xz").read_bytes())


async def _settled(client: httpx.AsyncClient, admin: dict[str, str], upload_id: str) -> Any:
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    while time.monotonic() < deadline:
        r = await client.get(f"/v1/uploads/{upload_id}", headers=admin)
        assert r.status_code == 200, r.text
        if r.json()["status"] not in ("queued", "processing"):
            return r.json()
        await asyncio.sleep(0.1)
    pytest.fail(f"upload {upload_id} did not settle in {SETTLE_TIMEOUT_S} s")


@needs_data
async def test_a_labelled_trace_is_folded_into_the_maps(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, upload_worker: None
) -> None:
    site_id = await _site(client, admin, [3])
    text = _trace_text()
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "device_model": "Pixel 4"},
        content=lzma.compress(text),
        headers={**admin, "content-type": "text/plain", "content-encoding": "xz"},
    )
    assert r.status_code == 202, r.text
    assert r.json()["status"] == "queued"
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "done", upload
    report = upload["report"]
    assert report["scans"] > 10
    assert report["magnetic_samples"] > 100
    assert report["radio_map_version"] == 1
    assert report["magnetic_map_version"] == 1
    assert upload["attempts"] == 1
    # the header names the floor F4: level 3, the only floor of the building
    r = await client.get(f"/v1/sites/{site_id}/buildings", headers=admin)
    building_id = r.json()["items"][0]["id"]
    r = await client.get(f"/v1/buildings/{building_id}/floors", headers=admin)
    floor_id = r.json()["items"][0]["id"]
    r = await client.get(f"/v1/floors/{floor_id}/magnetic-maps", headers=admin)
    (magnetic,) = r.json()["items"]
    assert magnetic["source"] == "upload"
    assert magnetic["n_samples"] == report["magnetic_samples"]
    async with app.state.runtime.transaction() as s:
        stmt = select(func.count()).where(SurveyPoint.upload_id == upload["id"])
        assert await s.scalar(stmt) == report["scans"]


@needs_data
async def test_the_same_key_makes_one_upload(
    client: httpx.AsyncClient, admin: dict[str, str], upload_worker: None
) -> None:
    site_id = await _site(client, admin, [3])
    headers = {**admin, "content-type": "text/plain", "idempotency-key": f"k-{site_id}"}
    text = _trace_text()
    first = await client.post(
        "/v1/uploads", params={"site_id": site_id}, content=text, headers=headers
    )
    again = await client.post(
        "/v1/uploads", params={"site_id": site_id}, content=text, headers=headers
    )
    assert first.status_code == 202, first.text
    assert again.status_code == 200, again.text
    assert again.json()["id"] == first.json()["id"]
    other = await client.post(
        "/v1/uploads", params={"site_id": site_id}, content=text + b"\n", headers=headers
    )
    assert other.status_code == 409
    assert "idempotency-key" in other.json()["message"]
    await _settled(client, admin, first.json()["id"])


async def _count_uploads(app: FastAPI) -> int:
    async with app.state.runtime.transaction() as s:
        return int(await s.scalar(select(func.count()).select_from(Upload)) or 0)


@pytest.mark.parametrize(
    ("record", "says"),
    [
        ("1574140000100\tTYPE_WIFI\tnet\taa:bb:cc:dd:ee:ff\t500\t2412\t1574140000000", "rssi 500"),
        ("1574140000100\tTYPE_WIFI\tnet\t" + "a" * 300 + "\t-60\t2412\t1574140000000", "bssid"),
        ("1574140000100\tTYPE_WIFI\tnet\taa bb\t-60\t2412\t1574140000000", "bssid"),
        ("1574140000100\tTYPE_BEACON\tu\t1\t2\t-59\t-300\t1.0\tmac\t0", "rssi -300"),
        ("1574140000100\tTYPE_WAYPOINT\tnan\t2.0", "TYPE_WAYPOINT"),
        ("1574140000100\tTYPE_WAYPOINT\t1e9\t2.0", "TYPE_WAYPOINT"),
        ("1574140000100\tTYPE_ACCELEROMETER\tinf\t0\t9.8\t3", "TYPE_ACCELEROMETER"),
    ],
)
async def test_implausible_values_in_an_ilc_upload_are_refused_with_their_line(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, record: str, says: str
) -> None:
    site_id = await _site(client, admin, [0])
    before = await _count_uploads(app)
    text = f"#\tSiteID:x\n1574140000000\tTYPE_WAYPOINT\t1.0\t2.0\n{record}\n".encode()
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id},
        content=text,
        headers={**admin, "content-type": "text/plain"},
    )
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("body: line 3: "), r.json()
    assert says in r.json()["message"]
    assert await _count_uploads(app) == before


async def test_malformed_and_huge_traces_are_refused_without_rows(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> None:
    site_id = await _site(client, admin, [0])
    before = await _count_uploads(app)
    headers = {**admin, "content-type": "text/plain"}
    bad = b"#\tSiteID:x\n1574140000000\tTYPE_WAYPOINT\t1.0\t2.0\n1574140000100\tTYPE_WIFI\tonly\n"
    r = await client.post("/v1/uploads", params={"site_id": site_id}, content=bad, headers=headers)
    assert r.status_code == 422, r.text
    assert "line 3" in r.json()["message"]
    assert "TYPE_WIFI" in r.json()["message"]
    # 70 MB of text compresses to a few kB: refused once the decompressed size passes the limit
    bomb = lzma.compress(b"0" * (app.state.runtime.settings.upload_max_bytes + 1))
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id},
        content=bomb,
        headers={**admin, "content-type": "application/x-xz"},
    )
    assert r.status_code == 413, r.text
    assert "body" in r.json()["message"]
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id},
        content=b"\xfd7zXZ",
        headers=headers | {"content-encoding": "xz"},
    )
    assert r.status_code == 422
    r = await client.post(
        "/v1/uploads", params={"site_id": "0" * 32}, content=bad[:60], headers=headers
    )
    assert r.status_code == 404
    assert "site_id" in r.json()["message"]
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id},
        content=b"<walk/>",
        headers={**admin, "content-type": "application/xml"},
    )
    assert r.status_code == 422
    assert "content-type" in r.json()["message"]
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id},
        content=b"\x78\x9c",
        headers={**admin, "content-type": "application/vnd.indoorpos.trace"},
    )
    assert r.status_code == 422  # the stored shape is never taken from a client
    assert "content-type" in r.json()["message"]
    assert await _count_uploads(app) == before
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id},
        content=bad[:60],
        headers={"content-type": "text/plain"},
    )
    assert r.status_code == 401


@needs_data
async def test_a_walk_without_waypoints_is_rejected_with_the_reason(
    client: httpx.AsyncClient, admin: dict[str, str], upload_worker: None
) -> None:
    site_id = await _site(client, admin, [3])
    lines = _trace_text().decode().splitlines(keepends=True)
    unlabelled = "".join(line for line in lines if "TYPE_WAYPOINT" not in line).encode()
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "floor": 3},
        content=unlabelled,
        headers={**admin, "content-type": "text/plain"},
    )
    assert r.status_code == 202, r.text
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "rejected"
    assert "waypoints" in upload["report"]["reason"]
    # a floor the building does not have
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "floor": 7},
        content=_trace_text(),
        headers={**admin, "content-type": "text/plain"},
    )
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "rejected"
    assert "floor level 7" in upload["report"]["reason"]


WALK_T0 = 1_700_000_000_000
WALK_S, STEP_HZ, STEP_M, WALK_Y = 12, 2.0, 0.7, 5.0
BEACONS = {"beac:1:1": (2.0, WALK_Y), "beac:1:2": (2.0 + WALK_S * STEP_HZ * STEP_M, WALK_Y)}


def _walk_events() -> list[dict[str, Any]]:
    """A phone walking east along y = 5 m from x = 2 m (raw IMU, ``client_sim.imu``), a
    WiFi scan every 2 s and a BLE scan every 0.5 s hearing two beacons at the ends."""
    from client_sim.imu import Gait, blocks, synthesize_walk
    from tests.support.toy_site import rssi_at

    trace = synthesize_walk(
        lambda t_s: np.full_like(t_s, math.pi / 2),  # east all the way
        WALK_S + 2,
        np.random.default_rng(3),
        walking=[(1.0, 1.0 + WALK_S)],
        gait=Gait(cadence_hz=STEP_HZ, step_length_m=STEP_M, bounce_ms2=2.0),
        t0_ms=WALK_T0,
    )
    events: list[dict[str, Any]] = [b.event() for b in blocks(trace)]
    for k in range(2 * (WALK_S + 2)):
        t_s = k / 2
        x = 2.0 + STEP_M * STEP_HZ * min(max(t_s - 1.0, 0.0), WALK_S)
        readings = [
            {"id": key, "rssi_dbm": -55.0 - 20 * math.log10(max(abs(x - bx), 0.5))}
            for key, (bx, _) in BEACONS.items()
        ]
        events.append({"type": "ble", "t": WALK_T0 + 500 * k, "readings": readings})
        if k % 4 == 0:
            events.append(
                {"type": "wifi", "t": WALK_T0 + 500 * k, "readings": rssi_at(x, WALK_Y, 0)}
            )
    return events


async def _beacon_site(client: httpx.AsyncClient, admin: dict[str, str]) -> tuple[str, str]:
    """A one-floor site whose plan marks the two beacons at the ends of the walk; its id
    and its building's."""
    site_id = await _site(client, admin, [0])
    r = await client.get(f"/v1/sites/{site_id}/buildings", headers=admin)
    building_id: str = r.json()["items"][0]["id"]
    r = await client.get(f"/v1/buildings/{building_id}/floors", headers=admin)
    floor_id = r.json()["items"][0]["id"]
    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"anchor": "entrance", "beacon": key},
                "geometry": {"type": "Point", "coordinates": list(xy)},
            }
            for key, xy in BEACONS.items()
        ],
    }
    r = await client.put(f"/v1/floors/{floor_id}/plan", json=plan, headers=admin)
    assert r.status_code == 200, r.text
    return site_id, building_id


async def test_a_walk_of_our_events_is_placed_by_the_plans_beacons(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, upload_worker: None
) -> None:
    site_id, _ = await _beacon_site(client, admin)
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "floor": 0},
        json={"events": _walk_events()},
        headers=admin,
    )
    assert r.status_code == 202, r.text
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "done", upload
    report = upload["report"]
    assert report["anchor_source"] == "beacons"
    assert report["anchors"] == 2
    assert report["placement"] == "steps between anchors"
    assert report["scans"] >= 5
    # each scan where the walker was
    async with app.state.runtime.transaction() as s:
        rows = (
            await s.scalars(select(SurveyPoint).where(SurveyPoint.upload_id == upload["id"]))
        ).all()
    for p in rows:
        t_s = (p.t_ms - WALK_T0) / 1000
        x = 2.0 + STEP_M * STEP_HZ * min(max(t_s - 1.0, 0.0), WALK_S)
        assert math.hypot(p.x_m - x, p.y_m - WALK_Y) < 2.5, (t_s, p.x_m, p.y_m)


async def test_a_walk_of_the_phone_s_step_events_is_placed_by_them(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, upload_worker: None
) -> None:
    """A phone that detects its own steps sends ``step`` events, no raw IMU: placement
    uses them between the beacons' passes instead of a constant speed."""
    site_id, _ = await _beacon_site(client, admin)
    n_steps = int(WALK_S * STEP_HZ)
    steps = [
        {
            "type": "step",
            "t": WALK_T0 + 1000 + int(1000 * (k + 1) / STEP_HZ),
            "length_m": STEP_M,
            "heading_rad": math.pi / 2,
        }
        for k in range(n_steps)
    ]
    events = [e for e in _walk_events() if e["type"] != "imu"] + steps
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "floor": 0},
        json={"events": events},
        headers=admin,
    )
    assert r.status_code == 202, r.text
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "done", upload
    report = upload["report"]
    assert report["anchor_source"] == "beacons"
    assert report["placement"] == "steps between anchors"
    assert report["steps_from"] == "the phone's step events"
    assert report["steps"] >= n_steps // 2
    async with app.state.runtime.transaction() as s:
        stmt = select(SurveyPoint).where(SurveyPoint.upload_id == upload["id"])
        rows = (await s.scalars(stmt)).all()
    assert rows
    for p in rows:
        t_s = (p.t_ms - WALK_T0) / 1000
        x = 2.0 + STEP_M * STEP_HZ * min(max(t_s - 1.0, 0.0), WALK_S)
        assert math.hypot(p.x_m - x, p.y_m - WALK_Y) < 2.5, (t_s, p.x_m, p.y_m)


async def test_a_malformed_walk_of_our_events_names_the_field(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> None:
    site_id = await _site(client, admin, [0])
    before = await _count_uploads(app)
    bad = {"events": [{"type": "wifi", "t": -5, "readings": []}]}
    r = await client.post("/v1/uploads", params={"site_id": site_id}, json=bad, headers=admin)
    assert r.status_code == 422, r.text
    assert "events.0.t" in r.json()["message"]
    # the events' plausible ranges hold in a walk as in a session's batch
    step = {"type": "step", "t": WALK_T0 + 600, "length_m": 0.7, "heading_rad": 1.0}
    for odd, field in (
        ({"type": "mag", "t": WALK_T0, "field_ut": [0.0, 1e308, 0.0]}, "events.1.field_ut.1"),
        ({**step, "heading_rad": 1e308}, "events.1.heading_rad"),
    ):
        r = await client.post(
            "/v1/uploads", params={"site_id": site_id}, json={"events": [step, odd]}, headers=admin
        )
        assert r.status_code == 422, r.text
        assert r.json()["message"].startswith(f"{field}: "), r.json()
    r = await client.post(
        "/v1/uploads", params={"site_id": site_id}, json={"events": []}, headers=admin
    )
    assert r.status_code == 422
    assert "events" in r.json()["message"]
    assert await _count_uploads(app) == before


async def test_an_ended_session_offered_for_map_building_becomes_an_upload(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, upload_worker: None
) -> None:
    site_id, building_id = await _beacon_site(client, admin)
    # the toy floor's radio map places the phone, so the session knows its floor
    from tests.support.toy_site import rssi_at

    points = [
        {"x_m": float(x), "y_m": float(y), "floor": 0, "wifi": rssi_at(x, y, 0)}
        for x in range(0, 21, 2)
        for y in range(0, 11, 2)
    ]
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text

    body = {"site_id": site_id, "engine": "wknn", "contribute": True, "device_model": "Pixel 4"}
    # contributing needs a key allowed to: none, or a plain device key, is refused
    assert (await client.post("/v1/sessions", json=body)).status_code == 401
    device = await device_headers(client, admin, site_id=site_id)
    r = await client.post("/v1/sessions", json=body, headers=device)
    assert r.status_code == 403, r.text
    assert "contribute" in r.json()["message"]
    contributor = await device_headers(client, admin, ("device", "contribute"), site_id)
    r = await client.post("/v1/sessions", json=body, headers=contributor)
    assert r.status_code == 201, r.text
    sid, auth = r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}
    events = sorted(_walk_events(), key=lambda e: e["t"])
    batches = [events[i : i + 12] for i in range(0, len(events), 12)]
    for seq, batch in enumerate(batches, start=1):
        r = await client.post(
            f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": batch}, headers=auth
        )
        assert r.status_code == 200, r.text
    # a retried batch is kept once
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 2, "events": batches[1]}, headers=auth
    )
    assert r.json()["replayed"] is True
    r = await client.delete(f"/v1/sessions/{sid}", headers=auth)
    assert r.status_code == 204
    upload_id = r.headers["location"].rsplit("/", 1)[1]
    upload = await _settled(client, admin, upload_id)
    assert upload["status"] == "done", upload
    assert upload["floor"] == 0
    assert upload["device_model"] == "Pixel 4"
    assert upload["report"]["anchor_source"] == "beacons"
    assert upload["report"]["scans"] >= 5
    # a session that did not offer its walk leaves nothing
    r = await client.post(
        "/v1/sessions", json={"site_id": site_id, "engine": "wknn"}, headers=device
    )
    sid, auth = r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}
    await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": batches[0]}, headers=auth
    )
    r = await client.delete(f"/v1/sessions/{sid}", headers=auth)
    assert r.status_code == 204
    assert "location" not in r.headers


def _louder(text: bytes, db: float) -> bytes:
    """The trace with every WiFi reading ``db`` stronger (another phone model)."""
    lines = []
    for line in text.decode().splitlines():
        f = line.split("\t")
        if len(f) > 4 and f[1] == "TYPE_WIFI":
            f[4] = str(int(f[4]) + int(db))
        lines.append("\t".join(f))
    return "\n".join(lines).encode()


@needs_data
async def test_device_offsets_come_from_co_located_contributions(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, upload_worker: None
) -> None:
    site_id = await _site(client, admin, [3])
    text = _trace_text()
    for model, body in (("quiet phone", text), ("loud phone", _louder(text, 8))):
        r = await client.post(
            "/v1/uploads",
            params={"site_id": site_id, "device_model": model},
            content=body,
            headers={**admin, "content-type": "text/plain"},
        )
        assert (await _settled(client, admin, r.json()["id"]))["status"] == "done"
    r = await client.get(f"/v1/sites/{site_id}/buildings", headers=admin)
    building_id = r.json()["items"][0]["id"]
    r = await client.get(f"/v1/buildings/{building_id}/device-offsets", headers=admin)
    assert r.status_code == 200, r.text
    found = {o["device_model"]: o for o in r.json()["items"]}
    assert set(found) == {"quiet phone", "loud phone"}
    gap = found["loud phone"]["offset_db"] - found["quiet phone"]["offset_db"]
    assert gap == pytest.approx(8.0, abs=0.5)
    assert found["loud phone"]["n_pairs"] >= 20
    # a session of the loud phone has its scans brought down by its offset
    async with app.state.runtime.transaction() as s:
        from server.services.maps import site_maps

        app.state.runtime.maps.invalidate(site_id)
        maps = await site_maps(s, app.state.runtime.maps, site_id)
    assert maps.device_offsets["loud phone"] == pytest.approx(found["loud phone"]["offset_db"])
    r = await client.get(f"/v1/buildings/{'0' * 32}/device-offsets", headers=admin)
    assert r.status_code == 404


async def test_satellite_fixes_at_the_doors_anchor_a_walk(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI, upload_worker: None
) -> None:
    """Mansour IV-B: fixes with accuracy < 5 m and HDOP < 20, turned into the building's
    frame by its geo-reference, anchor the walk; a poor fix does not."""
    origin = (22.3, 114.2)
    r = await client.post("/v1/sites", json={"name": "outdoors"}, headers=admin)
    site_id = r.json()["id"]
    body = {"name": "b", "origin_lat": origin[0], "origin_lon": origin[1]}
    r = await client.post(f"/v1/sites/{site_id}/buildings", json=body, headers=admin)
    building_id = r.json()["id"]
    await client.post(f"/v1/buildings/{building_id}/floors", json={"level": 0}, headers=admin)

    def fix(t_s: float, x: float, y: float, accuracy: float) -> dict[str, Any]:
        earth_m = 6_371_008.8
        lat = origin[0] + math.degrees(y / earth_m)
        lon = origin[1] + math.degrees(x / (earth_m * math.cos(math.radians(origin[0]))))
        return {
            "type": "gnss",
            "t": WALK_T0 + int(1000 * t_s),
            "lat_deg": lat,
            "lon_deg": lon,
            "accuracy_m": accuracy,
            "hdop": 1.1,
        }

    events = [e for e in _walk_events() if e["type"] != "ble"]
    end_x = 2.0 + WALK_S * STEP_HZ * STEP_M
    events += [fix(0.5, 2.0, WALK_Y, 3.0), fix(WALK_S + 1.5, end_x, WALK_Y, 3.0)]
    events.append(fix(6.0, 40.0, 40.0, 12.0))  # too poor to count
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "floor": 0},
        json={"events": events},
        headers=admin,
    )
    assert r.status_code == 202, r.text
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "done", upload
    assert upload["report"]["anchors"] == 2
    async with app.state.runtime.transaction() as s:
        stmt = select(SurveyPoint).where(SurveyPoint.upload_id == upload["id"])
        rows = (await s.scalars(stmt)).all()
    assert rows
    for p in rows:
        t_s = (p.t_ms - WALK_T0) / 1000
        x = 2.0 + STEP_M * STEP_HZ * min(max(t_s - 1.0, 0.0), WALK_S)
        assert math.hypot(p.x_m - x, p.y_m - WALK_Y) < 2.5, (t_s, p.x_m, p.y_m)
    bad = {"events": [{**events[-1], "lat_deg": 91.0}]}
    r = await client.post("/v1/uploads", params={"site_id": site_id}, json=bad, headers=admin)
    assert r.status_code == 422
    assert "events.0.lat_deg" in r.json()["message"]


async def test_a_walk_stretched_across_a_city_by_its_anchors_is_rejected(
    client: httpx.AsyncClient, admin: dict[str, str], upload_worker: None
) -> None:
    site_id = await _site(client, admin, [0])
    anchors = [
        {"t": WALK_T0 + 1000, "x_m": -90_000.0, "y_m": WALK_Y},
        {"t": WALK_T0 + 1000 * (WALK_S + 1), "x_m": 90_000.0, "y_m": WALK_Y},
    ]
    # no steps (a phone that sends none): placed at constant speed between the anchors
    events: list[dict[str, Any]] = [
        {"type": "mag", "t": WALK_T0 + 500 * k, "field_ut": [20.0, 0.0, -40.0]}
        for k in range(2 * (WALK_S + 2))
    ]
    r = await client.post(
        "/v1/uploads",
        params={"site_id": site_id, "floor": 0},
        json={"events": events, "anchors": anchors},
        headers=admin,
    )
    assert r.status_code == 202, r.text
    upload = await _settled(client, admin, r.json()["id"])
    assert upload["status"] == "rejected", str(upload["report"])
    # the reason names the cause that cost the most samples, as not_used lists it first
    reason, not_used = upload["report"]["reason"], upload["report"]["not_used"]
    assert "m/s" in not_used[0]
    assert reason.startswith(f"nothing could be placed; main cause: {not_used[0]}"), reason
    assert "magnetic_map_version" not in upload["report"]
