"""A session's history: every fix it made, read page by page and exported as GeoJSON and
MF-JSON, by its token while it lives and by a viewer key after it ended; who else is
refused; a building without a geo-reference; the retention purge."""

from __future__ import annotations

import math
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from typing import Any

import anyio
import httpx
import orjson
import pytest
from fastapi import FastAPI
from geojson_pydantic import FeatureCollection
from sqlalchemy import func, select, update

from server.api.schemas.history import TrackGeoJSON
from server.config import Settings
from server.services import history
from server.services.history_writer import FLUSH_S
from server.services.runtime import Runtime
from server.storage.models import SessionFixes
from server.storage.repositories import history as history_repo
from server.storage.repositories.history import Window
from tests.support.geo_walk import ORIGIN, provision_geo_site, walk
from tests.support.sessions import lose_the_store, open_session, scan, step
from tests.support.toy_site import ToySite, build_toy_site, device_headers

T0 = 1_700_000_000_000


@pytest.fixture
def rt(app: FastAPI) -> Runtime:
    runtime: Runtime = app.state.runtime
    return runtime


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def _post(
    client: httpx.AsyncClient, sid: str, auth: dict[str, str], seq: int, events: list[Any]
) -> list[dict[str, Any]]:
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": events}, headers=auth
    )
    assert r.status_code == 200, r.text
    fixes: list[dict[str, Any]] = r.json()["fixes"]
    return fixes


async def _history(
    client: httpx.AsyncClient,
    sid: str,
    headers: dict[str, str],
    limit: int,
    **window: int,
) -> list[dict[str, Any]]:
    """Every page of the session's history (in the ``from``, ``to`` window given)."""
    items: list[dict[str, Any]] = []
    after = 0
    while True:
        r = await client.get(
            f"/v1/sessions/{sid}/history",
            params={"after_seq": after, "limit": limit, **window},
            headers=headers,
        )
        assert r.status_code == 200, r.text
        page = r.json()
        assert page["count"] == len(page["items"])
        items += page["items"]
        if not page["more"]:
            return items
        after = page["last_seq"]


@pytest.mark.slow
async def test_a_ten_minute_walk_exports_every_fix_as_valid_geojson(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    geo = await provision_geo_site(client, admin)
    r = await client.post(
        "/v1/sessions", json={"site_id": geo.site_id, "engine": "step_ekf"}, headers=geo.device
    )
    assert r.status_code == 201, r.text
    sid, auth = r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}
    fixes = []
    for seq, events in enumerate(walk(geo.world, minutes=10.0), start=1):
        fixes += await _post(client, sid, auth, seq, events)
    assert (fixes[-1]["t"] - fixes[0]["t"]) / 60_000 > 9.5
    assert len(fixes) > 500  # a step's fix for each of the walk's batches, and the scans'

    r = await client.get(f"/v1/sessions/{sid}/track.geojson", headers=auth)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/geo+json"
    document = r.json()
    FeatureCollection.model_validate(document)  # RFC 7946, as geojson-pydantic reads it
    TrackGeoJSON.model_validate(document)  # and as the OpenAPI document says
    vertices = []  # (t, lon, lat, accuracy) of every vertex, in order
    for feature in document["features"]:
        geometry, properties = feature["geometry"], feature["properties"]
        positions = (
            [geometry["coordinates"]] if geometry["type"] == "Point" else geometry["coordinates"]
        )
        assert properties["building_id"] == geo.building_id
        assert len(positions) == len(properties["times_ms"]) == len(properties["coordTimes"])
        for (lon, lat), t, accuracy in zip(
            positions, properties["times_ms"], properties["accuracy_m"], strict=True
        ):
            assert -180 <= lon <= 180 and -90 <= lat <= 90  # noqa: PT018
            vertices.append((t, lon, lat, accuracy))
    assert len(vertices) == len(fixes)  # every fix, once
    for (t, lon, lat, accuracy), fix in zip(
        vertices, sorted(fixes, key=lambda f: f["t"]), strict=True
    ):
        assert t == fix["t"]
        assert lon == pytest.approx(fix["lon"], abs=1e-7)
        assert lat == pytest.approx(fix["lat"], abs=1e-7)
        assert accuracy == fix["accuracy_m"]
    # the walk is in the building, near its origin
    assert math.hypot(vertices[0][1] - ORIGIN[1], vertices[0][2] - ORIGIN[0]) < 0.01

    # a window of it: the fixes from its second to its third minute, and only those
    start, end = fixes[0]["t"] + 60_000, fixes[0]["t"] + 180_000
    inside = sorted(f["t"] for f in fixes if start <= f["t"] <= end)
    window = {"from": start, "to": end}
    r = await client.get(f"/v1/sessions/{sid}/track.geojson", params=window, headers=auth)
    assert r.status_code == 200, r.text
    times = [t for feature in r.json()["features"] for t in feature["properties"]["times_ms"]]
    assert times == inside
    assert await _history(client, sid, auth, limit=100, **window) == [
        f for f in fixes if start <= f["t"] <= end
    ]

    moving = (await client.get(f"/v1/sessions/{sid}/track.mfjson", headers=auth)).json()
    (feature,) = moving["features"]
    temporal = feature["temporalGeometry"]
    assert temporal["type"] == "MovingPoint"
    assert temporal["interpolation"] == "Linear"
    assert temporal["datetimes"] == sorted(set(temporal["datetimes"]))  # unique, increasing
    assert len(temporal["datetimes"]) == len({f["t"] for f in fixes})
    assert len(temporal["coordinates"]) == len(temporal["datetimes"])

    # the same fixes in the floor's frame, page by page
    assert await _history(client, sid, auth, limit=100) == fixes

    # once the session ended its token reads nothing; a viewer key of its site reads on
    viewer = await device_headers(client, admin, ("viewer",), geo.site_id)
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    r = await client.get(f"/v1/sessions/{sid}/track.geojson", headers=auth)
    assert r.status_code == 403, r.text
    r = await client.get(f"/v1/sessions/{sid}/track.geojson", headers=viewer)
    assert r.status_code == 200, r.text
    assert r.json() == document


async def test_who_reads_a_history_is_who_reads_the_track(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    fixes = await _post(client, sid, auth, 1, [scan(T0, 5, 5), step(T0 + 600)])
    _, other_auth = await open_session(client, site)
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    stranger = await device_headers(
        client, admin, ("viewer",), (await build_toy_site(client, admin)).site_id
    )
    for headers in (auth, viewer, admin):
        assert await _history(client, sid, headers, limit=10) == fixes
    missing = "0" * 32
    for path in ("/history", "/track.geojson", "/track.mfjson"):
        # another session's token and a device key: as GET /track answers them
        for headers in (other_auth, site.device):
            track = await client.get(f"/v1/sessions/{sid}/track", headers=headers)
            r = await client.get(f"/v1/sessions/{sid}{path}", headers=headers)
            assert r.status_code == track.status_code == 403, r.text
        # a viewer of another site hears of it what it hears of a session never made
        theirs = await client.get(f"/v1/sessions/{sid}{path}", headers=stranger)
        none = await client.get(f"/v1/sessions/{missing}{path}", headers=stranger)
        assert theirs.status_code == none.status_code == 404, theirs.text
        assert theirs.text.replace(sid, missing) == none.text
        r = await client.get(f"/v1/sessions/{sid}{path}", headers={"Authorization": "Bearer x"})
        assert r.status_code in {401, 403}
    # once it ended, its site's viewers read it from its SQL row: still none of another's
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    assert await _history(client, sid, viewer, limit=10) == fixes
    for path in ("/history", "/track.geojson", "/track.mfjson"):
        theirs = await client.get(f"/v1/sessions/{sid}{path}", headers=stranger)
        none = await client.get(f"/v1/sessions/{missing}{path}", headers=stranger)
        assert theirs.status_code == none.status_code == 404, theirs.text
        assert theirs.text.replace(sid, missing) == none.text


async def test_a_building_without_a_geo_reference_cannot_be_exported_in_wgs84(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    fixes = await _post(client, sid, auth, 1, [scan(T0, 5, 5), step(T0 + 600)])
    assert fixes
    assert fixes[0]["lat"] is None
    for path in ("/track.geojson", "/track.mfjson"):
        r = await client.get(f"/v1/sessions/{sid}{path}", headers=auth)
        assert r.status_code == 409, r.text
        assert f"building {site.building_id}" in r.json()["message"]
        assert "geo-reference" in r.json()["message"]
    # the floor frame has them
    assert await _history(client, sid, auth, limit=10) == fixes


async def test_a_page_holds_whole_batches_and_a_retry_is_kept_once(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    batches = [
        [scan(T0, 5, 5)],
        [step(T0 + 600), step(T0 + 1200)],
        [step(T0 + 1800), step(T0 + 2400)],
    ]
    fixes = [await _post(client, sid, auth, seq, b) for seq, b in enumerate(batches, start=1)]
    await _post(client, sid, auth, 3, batches[2])  # a retry: answered again, not kept again
    assert [len(f) for f in fixes] == [1, 2, 2]
    url = f"/v1/sessions/{sid}/history"
    first = (await client.get(url, params={"limit": 2}, headers=auth)).json()
    assert first["items"] == fixes[0]  # batch 2 would take it past 2 fixes
    assert (first["last_seq"], first["more"]) == (1, True)
    rest = (await client.get(url, params={"after_seq": 1, "limit": 1}, headers=auth)).json()
    assert rest["items"] == fixes[1]  # a page's first batch comes whole
    last = (await client.get(url, params={"after_seq": 2}, headers=auth)).json()
    assert (last["items"], last["last_seq"], last["more"]) == (fixes[2], 3, False)
    empty = (await client.get(url, params={"after_seq": 3}, headers=auth)).json()
    assert (empty["items"], empty["last_seq"], empty["more"]) == ([], None, False)
    for bad in ({"limit": 0}, {"limit": 5001}, {"after_seq": -1}):
        assert (await client.get(url, params=bad, headers=auth)).status_code == 422


async def test_the_runtime_writes_the_history_with_no_reader_flushing_it(
    client: httpx.AsyncClient, site: ToySite, rt: Runtime
) -> None:
    sid, auth = await open_session(client, site)
    fixes = await _post(client, sid, auth, 1, [scan(T0, 5, 5)])
    fixes += await _post(client, sid, auth, 2, [step(T0 + 600)])
    await anyio.sleep(FLUSH_S)
    with anyio.fail_after(2 * FLUSH_S):  # the writer's timer, not a reader, wrote them
        while True:
            async with rt.read() as s:
                rows = await history_repo.fixes_of(s, sid, 0, Window(), 10)
            if len(rows) == 2:
                break
            await anyio.sleep(0.05)
    assert [fix for _, body in rows for fix in orjson.loads(body)] == fixes


async def test_a_time_window_reads_the_fixes_from_and_to_the_times_given(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    batches = [
        [scan(T0, 5, 5)],
        [step(T0 + 600), step(T0 + 1200)],
        [step(T0 + 1800), step(T0 + 2400)],
    ]
    fixes = []
    for seq, events in enumerate(batches, start=1):
        fixes += await _post(client, sid, auth, seq, events)
    start, end = T0 + 1000, T0 + 2000  # across the second batch and the third
    inside = [f for f in fixes if start <= f["t"] <= end]
    assert 0 < len(inside) < len(fixes) - 1
    assert await _history(client, sid, auth, limit=10, **{"from": start, "to": end}) == inside
    assert await _history(client, sid, auth, limit=10, **{"from": start}) == [
        f for f in fixes if f["t"] >= start
    ]
    url = f"/v1/sessions/{sid}/history"
    r = await client.get(url, params={"from": end, "to": start}, headers=auth)
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("to: ")
    r = await client.get(url, params={"from": 1}, headers=auth)  # 1970: not a phone's time
    assert r.status_code == 422, r.text


async def test_an_export_past_its_limit_asks_for_a_narrower_window(
    client: httpx.AsyncClient, site: ToySite, monkeypatch: pytest.MonkeyPatch
) -> None:
    sid, auth = await open_session(client, site)
    await _post(client, sid, auth, 1, [scan(T0, 5, 5)])
    await _post(client, sid, auth, 2, [step(T0 + 600), step(T0 + 1200)])
    monkeypatch.setattr(history, "MAX_EXPORT_FIXES", 2)
    for path in ("/track.geojson", "/track.mfjson"):
        r = await client.get(f"/v1/sessions/{sid}{path}", headers=auth)
        assert r.status_code == 422, r.text
        assert "3 fixes" in r.json()["message"]
        assert "at most 2" in r.json()["message"]
        assert "from and to" in r.json()["message"]
        # the first batch alone is within it (and has no WGS84 position)
        r = await client.get(f"/v1/sessions/{sid}{path}", params={"to": T0 + 100}, headers=auth)
        assert r.status_code == 409, r.text


async def test_a_batch_past_a_gap_in_seq_waits_until_the_gap_cannot_fill(
    client: httpx.AsyncClient, site: ToySite, rt: Runtime
) -> None:
    sid, auth = await open_session(client, site)
    first = await _post(client, sid, auth, 1, [scan(T0, 5, 5)])

    async def written_elsewhere(seq: int) -> dict[str, Any]:
        """Batch ``seq`` as another process writes it, in a shape of fix older than
        today's (a field this version does not have): it is served as it was kept."""
        fix = {"t": T0 + 600 * seq, "x_m": 1.0, "y_m": 2.0, "a_field_of_old": [1]}
        row = {
            "session_id": sid,
            "seq": seq,
            "site_id": site.site_id,
            "t_first_ms": fix["t"],
            "t_last_ms": fix["t"],
            "n_fixes": 1,
            "fixes": orjson.dumps([fix]),
            "created_at": datetime.now(UTC),
        }
        async with rt.transaction() as s:
            await history_repo.keep_fixes(s, [row])
        return fix

    async def page(after_seq: int) -> tuple[list[dict[str, Any]], int | None, bool]:
        r = await client.get(
            f"/v1/sessions/{sid}/history", params={"after_seq": after_seq}, headers=auth
        )
        assert r.status_code == 200, r.text
        return r.json()["items"], r.json()["last_seq"], r.json()["more"]

    async def age(seq: int) -> None:
        async with rt.transaction() as s:
            await s.execute(
                update(SessionFixes)
                .where(SessionFixes.session_id == sid, SessionFixes.seq == seq)
                .values(created_at=datetime.now(UTC) - timedelta(seconds=10 * history.HOLD_S))
            )

    # seq 3 is written; seq 2, applied before it by another process, is on its way
    third = await written_elsewhere(3)
    assert await page(0) == (first, 1, False)
    assert await page(1) == ([], None, False)
    second = await written_elsewhere(2)  # it came: both read
    assert await page(1) == ([second, third], 3, False)
    # seq 5 past a gap that stays (seq 4 made no fix): read once the gap cannot fill
    fifth = await written_elsewhere(5)
    assert await page(3) == ([], None, False)
    await age(5)
    assert await page(3) == ([fifth], 5, False)


async def test_a_batch_applied_again_after_a_rebuild_keeps_its_first_fixes(
    client: httpx.AsyncClient, site: ToySite, rt: Runtime
) -> None:
    sid, auth = await open_session(client, site)
    first = await _post(client, sid, auth, 1, [scan(T0, 5, 5)])
    second = [scan(T0 + 600, 12, 5), step(T0 + 1200)]
    answered = await _post(client, sid, auth, 2, second)
    await lose_the_store(rt, sid)  # before the phone heard the answer: it sends seq 2 again
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 2, "events": second}, headers=auth
    )
    assert r.json()["reinitialised"] is True, r.text
    assert r.json()["fixes"] != answered  # a filter started again answers otherwise
    assert await _history(client, sid, auth, limit=10) == first + answered


async def test_rows_of_one_seq_in_one_write_keep_the_first(rt: Runtime, site: ToySite) -> None:
    def row(seq: int, fixes: bytes) -> dict[str, Any]:
        return {
            "session_id": "e" * 32,
            "seq": seq,
            "site_id": site.site_id,
            "t_first_ms": T0,
            "t_last_ms": T0,
            "n_fixes": 1,
            "fixes": fixes,
            "created_at": datetime.now(UTC),
        }

    async with rt.transaction() as s:
        new = await history_repo.keep_fixes(s, [row(1, b"[1]"), row(1, b"[2]"), row(2, b"[3]")])
        assert new == 2
    async with rt.transaction() as s:
        assert await history_repo.keep_fixes(s, [row(2, b"[4]")]) == 0
    async with rt.read() as s:
        got = await history_repo.fixes_of(s, "e" * 32, 0, Window(), 10)
    assert got == [(1, b"[1]"), (2, b"[3]")]


@pytest.fixture
def retention(settings: Settings) -> Iterator[Settings]:
    original = settings.history_retention_days
    yield settings
    settings.history_retention_days = original


async def test_the_purge_deletes_what_is_past_the_retention(
    client: httpx.AsyncClient,
    site: ToySite,
    rt: Runtime,
    retention: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    old_sid, old_auth = await open_session(client, site)
    await _post(client, old_sid, old_auth, 1, [scan(T0, 5, 5)])
    await _post(client, old_sid, old_auth, 2, [step(T0 + 600)])
    sid, auth = await open_session(client, site)
    kept = await _post(client, sid, auth, 1, [scan(T0, 5, 5)])
    await rt.history.flush(rt.transaction)
    async with rt.transaction() as s:  # written ten days ago
        await s.execute(
            update(SessionFixes)
            .where(SessionFixes.session_id == old_sid)
            .values(created_at=datetime.now(UTC) - timedelta(days=10))
        )
    retention.history_retention_days = None  # kept for good
    assert await history.purge(rt) == 0
    retention.history_retention_days = 11.0
    assert await history.purge(rt) == 0
    retention.history_retention_days = 9.0
    monkeypatch.setattr(history, "PURGE_CHUNK", 1)  # a transaction per batch
    assert await history.purge(rt) == 2
    assert await _history(client, old_sid, old_auth, limit=10) == []
    assert await _history(client, sid, auth, limit=10) == kept
    retention.history_retention_days = 0.0  # none kept
    await history.purge(rt)
    async with rt.read() as s:
        left = select(func.count()).where(SessionFixes.session_id.in_([old_sid, sid]))
        assert await s.scalar(left) == 0
