"""Map builds through the API: a survey posted with its walks gets a radio map version
the worker builds (fix-error table, FAI maps, floor graphs); sessions' radii come from
the learned table; the service's map set equals the lab builder's from the same records;
rolling back to an older version brings its own artefacts back."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi import FastAPI
from sqlalchemy import select, update

from server import worker
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.wknn import WknnParams
from server.positioning.mapping.map_set import (
    FAI,
    FIX_ERROR,
    GRAPHS,
    SiteRecords,
    SurveyedScans,
    build_map_set,
)
from server.positioning.model.events import RadioReading, WifiEvent, radio_key
from server.positioning.radio import fix_error
from server.positioning.radio.fix_error import FixErrorModel
from server.services import map_builds
from server.services.maps import MapCache, site_maps
from server.services.runtime import Runtime
from server.storage.models import RadioMapVersion, SurveyPoint
from tests.support.toy_site import DEPTH_M, LEVELS, WIDTH_M, device_headers, rssi_at

T0 = 1_700_000_000_000
BUILD_TIMEOUT_S = 20.0
SHADOWING_DB = 3.0  # RSS noise added to the toy's log-distance readings
WORKER_PARTS = {FIX_ERROR, FAI, GRAPHS}  # what the worker builds (services.map_builds)

Point = dict[str, Any]


def _walk(
    name: str,
    route: str | None,
    level: int,
    start: tuple[float, float],
    end: tuple[float, float],
    rng: np.random.Generator,
    t0: int = T0,
) -> list[Point]:
    """A walk from ``start`` to ``end``, a scan every metre, one a second."""
    a, b = np.array(start), np.array(end)
    points = []
    for i, s in enumerate(np.linspace(0.0, 1.0, round(float(np.linalg.norm(b - a))) + 1)):
        x, y = (float(v) for v in a + s * (b - a))
        wifi = [
            {"bssid": r["bssid"], "rssi_dbm": float(r["rssi_dbm"] + rng.normal(0, SHADOWING_DB))}
            for r in rssi_at(x, y, level)
        ]
        for reading in wifi[::3]:  # a phone's scan lists cached readings, seconds old
            reading["age_ms"] = int(rng.integers(0, 8000))
        point: Point = {"x_m": x, "y_m": y, "floor": level, "t": t0 + 1000 * i, "wifi": wifi}
        point["walk"] = name
        if route is not None:
            point["route"] = route
        points.append(point)
    return points


def _corridor_walks(seed: int, corridors_y: Sequence[float] = (1.5, 5.5, 8.5)) -> list[Point]:
    """On each floor: east along the corridors, back west along the first (the same route)
    and north across them; then a walk up the stairs from level 0 to level 1 (out of time
    order in the request)."""
    rng = np.random.default_rng(seed)
    points: list[Point] = []
    for level in LEVELS:
        for y in corridors_y:
            name = f"{seed}-{level}-y{y}"
            points += _walk(name, name, level, (0.5, y), (WIDTH_M - 0.5, y), rng)
        y = corridors_y[0]
        route = f"{seed}-{level}-y{y}"
        points += _walk(f"{route}-back", route, level, (WIDTH_M - 0.5, y), (0.5, y), rng)
        points += _walk(f"{seed}-{level}-x", None, level, (10.5, 0.5), (10.5, DEPTH_M - 0.5), rng)
    up = f"{seed}-stairs"
    second = _walk(up, None, 1, (3.5, 9.5), (0.5, 9.5), rng, t0=T0 + 10_000)
    points += second + _walk(up, None, 0, (0.5, 6.5), (3.5, 9.5), rng)
    return points


def _plan(*, pillar: bool = False) -> dict[str, Any]:
    """A floor plan: the whole 20 m x 10 m floor walkable, with a 2 m pillar or not."""

    def box(x0: float, y0: float, x1: float, y1: float, kind: str) -> dict[str, Any]:
        ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
        return {
            "type": "Feature",
            "properties": {"kind": kind},
            "geometry": {"type": "Polygon", "coordinates": [ring]},
        }

    features = [box(0.0, 0.0, WIDTH_M, DEPTH_M, "walkable")]
    if pillar:
        features.append(box(14.0, 2.0, 16.0, 4.0, "obstacle"))
    return {"type": "FeatureCollection", "features": features}


async def _empty_site(client: httpx.AsyncClient, admin: dict[str, str]) -> tuple[str, str]:
    """A site with one building of levels 0 and 1 and no survey: (site id, building id)."""
    r = await client.post("/v1/sites", json={"name": "walked"}, headers=admin)
    assert r.status_code == 201, r.text
    site_id: str = r.json()["id"]
    r = await client.post(f"/v1/sites/{site_id}/buildings", json={"name": "B"}, headers=admin)
    assert r.status_code == 201, r.text
    building_id: str = r.json()["id"]
    for level in LEVELS:
        r = await client.post(
            f"/v1/buildings/{building_id}/floors", json={"level": level}, headers=admin
        )
        assert r.status_code == 201, r.text
    return site_id, building_id


async def _survey(
    client: httpx.AsyncClient, admin: dict[str, str], building_id: str, points: list[Point]
) -> dict[str, Any]:
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    body: dict[str, Any] = r.json()
    return body


async def _versions(
    client: httpx.AsyncClient, admin: dict[str, str], building_id: str
) -> dict[int, dict[str, Any]]:
    r = await client.get(f"/v1/buildings/{building_id}/radio-maps", headers=admin)
    assert r.status_code == 200, r.text
    return {m["version"]: m for m in r.json()["items"]}


async def _built(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime, building_id: str, version: int
) -> dict[str, Any]:
    """Run the worker's map builds (the app's own worker may be at it too: one of them
    leases each version) until ``version`` is built; its listing then."""
    deadline = time.monotonic() + BUILD_TIMEOUT_S
    while time.monotonic() < deadline:
        await worker.build_maps(rt, building_id=building_id)
        item = (await _versions(client, admin, building_id))[version]
        assert item["build_status"] in ("pending", "built"), item
        if item["build_status"] == "built":
            return item
        await asyncio.sleep(0.05)
    pytest.fail(f"version {version} was not built in {BUILD_TIMEOUT_S} s")


async def _service_maps(rt: Runtime, site_id: str) -> SiteMaps:
    """The site's map set as a process that has not cached it yet loads it."""
    async with rt.transaction() as s:
        return await site_maps(s, MapCache(4), site_id)


def _records(
    maps: SiteMaps,
    points: Sequence[Point],
    plans: Sequence[dict[str, Any] | None] = (),
) -> SiteRecords:
    """The posted points as the lab hands them to the map builder (floors by level),
    with the floors' plans (GeoJSON) by floor index."""
    floor_of = {f.level: i for i, f in enumerate(maps.floors)}
    scans = SurveyedScans.of(
        [(p["x_m"], p["y_m"]) for p in points],
        [floor_of[p["floor"]] for p in points],
        [[(radio_key("wifi", w["bssid"]), w["rssi_dbm"]) for w in p["wifi"]] for p in points],
        t_ms=[p["t"] for p in points],
        ages_ms=[[w.get("age_ms") for w in p["wifi"]] for p in points],
        walk=[p.get("walk") for p in points],
        route=[p.get("route") for p in points],
    )
    return SiteRecords(maps.floors, scans, tuple(plans))


def _radius_68(model: FixErrorModel, n_matched: int) -> float:
    """The 68 % radius of a ``wknn`` fix of a WiFi scan matching ``n_matched`` emitters on
    a map whose fix error is ``model``, at the table's variance (scan_fixes.match
    multiplies it by the scan's distance to the nearest reference scan)."""
    params = WknnParams()
    var = max(model.variance("wifi", n_matched) * params.fix_var_scale, params.min_fix_var_m2)
    return params.accuracy.radii(float(np.sqrt(var)), model.error_68_m)[0]


def _assert_same_maps(service: SiteMaps, lab: SiteMaps) -> None:
    assert service.radio is not None
    assert lab.radio is not None
    assert service.fix_error == lab.fix_error
    # FAI: the emitter fits by emitter key, the DSF by reference point (place order)
    assert service.fai is not None
    assert lab.fai is not None
    assert sorted(service.radio.emitters) == sorted(lab.radio.emitters)
    lab_column = {key: j for j, key in enumerate(lab.radio.emitters)}
    for j, key in enumerate(service.radio.emitters):
        k = lab_column[key]
        for name in ("emitter_xy", "p0_dbm", "exponent"):
            np.testing.assert_allclose(
                getattr(service.fai, name)[j],
                getattr(lab.fai, name)[k],
                rtol=1e-4,
                equal_nan=True,
                err_msg=f"{name} of {key}",
            )
    np.testing.assert_allclose(service.radio.rp_xy, lab.radio.rp_xy, atol=1e-5)
    np.testing.assert_allclose(service.fai.dsf_m, lab.fai.dsf_m, rtol=1e-4, equal_nan=True)
    # floor graphs, moves learned from the walks
    assert len(service.graphs) == len(lab.graphs) == len(LEVELS)
    for mine, theirs in zip(service.graphs, lab.graphs, strict=True):
        assert mine is not None
        assert theirs is not None
        for name in ("xy", "kind", "indptr", "indices", "rp_vertex"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name))
        np.testing.assert_allclose(mine.move_p, theirs.move_p, rtol=1e-12)
        np.testing.assert_allclose(mine.stay_p, theirs.stay_p, rtol=1e-12)
    # the reference scans, with their readings' ages
    assert service.scans is not None
    assert lab.scans is not None
    assert service.scans.emitters == lab.scans.emitters
    assert float(lab.scans.fresh.min()) < 1.0  # some readings were stale
    for name in ("xy_m", "floor", "indptr", "rows", "rssi_dbm", "fresh", "rarity", "totals"):
        np.testing.assert_allclose(
            getattr(service.scans, name), getattr(lab.scans, name), rtol=1e-6, err_msg=name
        )


@pytest.fixture
def rt(app: FastAPI) -> Runtime:
    runtime: Runtime = app.state.runtime
    return runtime


async def test_a_survey_with_walks_gets_a_version_the_worker_builds(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    _, building_id = await _empty_site(client, admin)
    points = _corridor_walks(seed=1)
    points.append({"x_m": 4.0, "y_m": 4.0, "floor": 0, "wifi": rssi_at(4.0, 4.0, 0)})  # alone
    posted = await _survey(client, admin, building_id, points)
    assert posted["version"] == 1
    assert posted["n_survey_points"] == len(points)
    assert posted["build_status"] == "pending"  # written on the request, built after it
    assert posted["build_seconds"] is None
    built = await _built(client, admin, rt, building_id, 1)
    assert built["id"] == posted["id"]
    assert built["build_seconds"] > 0.0
    assert built["n_reference_points"] == posted["n_reference_points"]


@pytest.mark.parametrize("label", ["", "w" * 65, 7])
async def test_walk_and_route_names_are_checked(
    client: httpx.AsyncClient, admin: dict[str, str], label: object
) -> None:
    _, building_id = await _empty_site(client, admin)
    point = {"x_m": 1.0, "y_m": 1.0, "floor": 0, "wifi": rssi_at(1.0, 1.0, 0)}
    for field in ("walk", "route"):
        r = await client.post(
            f"/v1/buildings/{building_id}/survey",
            json={"points": [point, {**point, field: label}]},
            headers=admin,
        )
        assert r.status_code == 422, r.text
        assert f"points.1.{field}" in r.text


async def test_fixes_are_as_accurate_as_the_learned_table_says(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, building_id = await _empty_site(client, admin)
    points = _corridor_walks(seed=2)
    await _survey(client, admin, building_id, points)
    await _built(client, admin, rt, building_id, 1)
    # the table the lab learns from the same records
    service = await _service_maps(rt, site_id)
    lab = build_map_set(_records(service, points), parts={FIX_ERROR})
    learned = lab.fix_error
    assert learned.error_68_m != fix_error.DEFAULT_ERROR_68_M

    device = await device_headers(client, admin, site_id=site_id)
    r = await client.post(
        "/v1/sessions", json={"site_id": site_id, "engine": "wknn"}, headers=device
    )
    assert r.status_code == 201, r.text
    session = r.json()
    scans: list[dict[str, Any]] = [
        {"type": "wifi", "t": T0 + 1000 * i, "readings": rssi_at(x, y, level)}
        for i, (x, y, level) in enumerate([(6.3, 4.2, 0), (14.8, 7.5, 1)])
    ]
    r = await client.post(
        f"/v1/sessions/{session['id']}/batches",
        json={"seq": 1, "events": scans},
        headers={"Authorization": f"Bearer {session['token']}"},
    )
    assert r.status_code == 200, r.text
    fixes = r.json()["fixes"]
    assert len(fixes) == len(scans)
    # the same scans through the engine in process, on the lab's maps
    spec = get_engine("wknn")
    events = [
        WifiEvent(e["t"], tuple(RadioReading(x["bssid"], x["rssi_dbm"]) for x in e["readings"]))
        for e in scans
    ]
    _, ours = spec.step(
        spec.start(spec.params()), events, lab, spec.params(), np.random.default_rng(0)
    )
    assert len(ours) == len(fixes)
    for fix, our in zip(fixes, ours, strict=True):
        n_matched = int(fix["diagnostics"]["n_matched"])
        # what the default table would have said is far from the learned one: the test can
        # tell them apart
        assert abs(_radius_68(learned, n_matched) - _radius_68(fix_error.DEFAULT, n_matched)) > 5.0
        assert fix["accuracy_68_m"] == pytest.approx(our.accuracy_68_m, rel=1e-9)


async def test_the_service_loads_the_map_set_the_lab_builds_from_the_same_records(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, building_id = await _empty_site(client, admin)
    r = await client.get(f"/v1/buildings/{building_id}/floors", headers=admin)
    upper = next(f["id"] for f in r.json()["items"] if f["level"] == 1)
    # level 1 has a plan (its graph is the plan's), level 0 none (a graph over its RPs)
    r = await client.put(f"/v1/floors/{upper}/plan", json=_plan(), headers=admin)
    assert r.status_code == 200, r.text
    points = _corridor_walks(seed=3)
    await _survey(client, admin, building_id, points)
    await _built(client, admin, rt, building_id, 1)
    service = await _service_maps(rt, site_id)
    assert [(f.building_id, f.level) for f in service.floors] == [
        (building_id, 0),
        (building_id, 1),
    ]
    lab = build_map_set(_records(service, points, (None, _plan())), parts=WORKER_PARTS)
    assert service.fix_error != fix_error.DEFAULT
    _assert_same_maps(service, lab)
    graph = service.graphs[1]
    assert graph is not None
    assert graph.n == WIDTH_M * DEPTH_M  # a vertex per square metre of the plan

    # a new plan: the version is built again, its graph on the new plan
    r = await client.put(f"/v1/floors/{upper}/plan", json=_plan(pillar=True), headers=admin)
    assert r.status_code == 200, r.text
    await _built(client, admin, rt, building_id, 1)
    service = await _service_maps(rt, site_id)
    lab = build_map_set(_records(service, points, (None, _plan(pillar=True))), parts=WORKER_PARTS)
    _assert_same_maps(service, lab)
    graph = service.graphs[1]
    assert graph is not None
    assert graph.n == WIDTH_M * DEPTH_M - 4  # not in the pillar


async def test_a_rolled_back_version_brings_its_own_maps_back(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, building_id = await _empty_site(client, admin)
    url = f"/v1/buildings/{building_id}"
    first = _corridor_walks(seed=4)
    await _survey(client, admin, building_id, first)
    v1 = await _built(client, admin, rt, building_id, 1)
    maps_1 = await _service_maps(rt, site_id)

    # version 2 folds more walks (other corridors, other noise) into version 1
    more = _corridor_walks(seed=5, corridors_y=(3.5, 7.5))
    await _survey(client, admin, building_id, more)
    await _built(client, admin, rt, building_id, 2)
    maps_2 = await _service_maps(rt, site_id)
    _assert_same_maps(maps_2, build_map_set(_records(maps_2, first + more), parts=WORKER_PARTS))
    # the two versions' artefacts differ: the test can tell which is in use
    assert maps_2.fix_error != maps_1.fix_error
    graph_1, graph_2 = maps_1.graphs[0], maps_2.graphs[0]
    assert graph_1 is not None
    assert graph_2 is not None
    assert graph_1.move_p.shape != graph_2.move_p.shape or not np.allclose(
        graph_1.move_p, graph_2.move_p
    )

    r = await client.post(f"{url}/radio-maps/1:activate", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["build_status"] == "built"  # built once; not owed again
    rolled_back = await _service_maps(rt, site_id)
    _assert_same_maps(rolled_back, maps_1)
    await worker.build_maps(rt, building_id=building_id)
    assert (await _versions(client, admin, building_id))[1] == {
        **v1,
        "activated_at": r.json()["activated_at"],
    }

    # what comes next folds into version 1: its build learns from version 1's walks and
    # its own, not version 2's
    last = _corridor_walks(seed=6, corridors_y=(2.5,))
    posted = await _survey(client, admin, building_id, last)
    assert posted["version"] == 3
    await _built(client, admin, rt, building_id, 3)
    maps_3 = await _service_maps(rt, site_id)
    _assert_same_maps(maps_3, build_map_set(_records(maps_3, first + last), parts=WORKER_PARTS))


async def test_a_version_superseded_before_its_build_is_built_when_activated(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, building_id = await _empty_site(client, admin)
    first = _corridor_walks(seed=7)
    await _survey(client, admin, building_id, first)
    # no build in between (the app's own worker may still get to version 1 first)
    await _survey(client, admin, building_id, _corridor_walks(seed=8, corridors_y=(4.5,)))
    await _built(client, admin, rt, building_id, 2)
    assert (await _versions(client, admin, building_id))[1]["build_status"] in (
        "superseded",
        "built",
    )
    r = await client.post(f"/v1/buildings/{building_id}/radio-maps/1:activate", headers=admin)
    assert r.status_code == 200, r.text
    await _built(client, admin, rt, building_id, 1)
    service = await _service_maps(rt, site_id)
    _assert_same_maps(service, build_map_set(_records(service, first), parts=WORKER_PARTS))


async def test_each_floor_keeps_the_graph_of_its_own_buildings_walks(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, walked = await _empty_site(client, admin)
    r = await client.post(f"/v1/sites/{site_id}/buildings", json={"name": "C"}, headers=admin)
    assert r.status_code == 201, r.text
    other = r.json()["id"]
    r = await client.post(f"/v1/buildings/{other}/floors", json={"level": 0}, headers=admin)
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/buildings/{walked}/floors", headers=admin)
    ground = next(f["id"] for f in r.json()["items"] if f["level"] == 0)
    r = await client.put(f"/v1/floors/{ground}/plan", json=_plan(), headers=admin)
    assert r.status_code == 200, r.text
    await _survey(client, admin, walked, _corridor_walks(seed=9))
    await _built(client, admin, rt, walked, 1)
    learned = (await _service_maps(rt, site_id)).graphs[0]
    assert learned is not None
    # a survey of the other building, without walks
    await _survey(
        client, admin, other, [{"x_m": 1.0, "y_m": 1.0, "floor": 0, "wifi": rssi_at(1.0, 1.0, 0)}]
    )
    await _built(client, admin, rt, other, 1)
    graph = (await _service_maps(rt, site_id)).graphs[0]
    assert graph is not None
    np.testing.assert_allclose(graph.move_p, learned.move_p)


async def _version_row(rt: Runtime, version_id: str) -> RadioMapVersion:
    async with rt.transaction() as s:
        row = await s.get(RadioMapVersion, version_id)
        assert row is not None
        s.expunge(row)
        return row


async def test_a_build_that_keeps_failing_is_retried_later_then_given_up(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    _, building_id = await _empty_site(client, admin)
    posted = await _survey(client, admin, building_id, _corridor_walks(seed=11))
    async with rt.transaction() as s:  # the version's map can no longer be read
        row = await s.get(RadioMapVersion, posted["id"])
        assert row is not None
        row.arrays = b"not an array container"
    for attempt in range(1, map_builds.MAX_ATTEMPTS + 1):
        assert await worker.build_maps(rt, building_id=building_id) == 0
        row = await _version_row(rt, posted["id"])
        assert row.build_attempts == attempt
        assert row.build_error is not None
        if attempt < map_builds.MAX_ATTEMPTS:
            assert row.build_status == "pending"
            # not taken again at once: it waits for its retry time
            assert row.build_leased_until is not None
            assert row.build_leased_until > datetime.now(UTC)
            assert await worker.build_maps(rt, building_id=building_id) == 0
            assert (await _version_row(rt, posted["id"])).build_attempts == attempt
            async with rt.transaction() as s:  # the retry time has come
                await s.execute(
                    update(RadioMapVersion)
                    .where(RadioMapVersion.id == posted["id"])
                    .values(build_leased_until=None)
                )
    assert (await _versions(client, admin, building_id))[1]["build_status"] == "failed"


async def test_a_plan_changed_during_a_build_leaves_the_version_to_be_built_again(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, building_id = await _empty_site(client, admin)
    points = _corridor_walks(seed=12)
    await _survey(client, admin, building_id, points)
    async with rt.transaction() as s:
        claim = await map_builds.claim(s, building_id=building_id)
    assert claim is not None
    async with rt.transaction() as s:
        inputs = await map_builds.build_inputs(s, claim.version_id)
    built = map_builds.build(inputs)
    r = await client.get(f"/v1/buildings/{building_id}/floors", headers=admin)
    ground = next(f["id"] for f in r.json()["items"] if f["level"] == 0)
    r = await client.put(f"/v1/floors/{ground}/plan", json=_plan(pillar=True), headers=admin)
    assert r.status_code == 200, r.text
    async with rt.transaction() as s:
        assert not await map_builds.store(s, inputs, built, claim.attempt)
    assert (await _versions(client, admin, building_id))[1]["build_status"] == "pending"
    await _built(client, admin, rt, building_id, 1)
    service = await _service_maps(rt, site_id)
    assert service.graphs[0] is not None  # built on the plan with the pillar
    lab = build_map_set(_records(service, points, [_plan(pillar=True), None]), parts=WORKER_PARTS)
    _assert_same_maps(service, lab)


async def test_walks_past_their_retention_are_pruned_and_lone_points_stay(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    _, building_id = await _empty_site(client, admin)
    walked = _corridor_walks(seed=13, corridors_y=(2.5,))
    alone = {"x_m": 4.0, "y_m": 4.0, "floor": 0, "wifi": rssi_at(4.0, 4.0, 0)}
    await _survey(client, admin, building_id, [*walked, alone])
    async with rt.transaction() as s:  # folded two days ago
        await s.execute(
            update(SurveyPoint)
            .where(SurveyPoint.building_id == building_id)
            .values(created_at=datetime.now(UTC) - timedelta(days=2))
        )
    async with rt.transaction() as s:
        assert await map_builds.prune_walks(s, retention_days=3.0) >= 0
        left = (
            await s.execute(select(SurveyPoint.walk).where(SurveyPoint.building_id == building_id))
        ).all()
    assert len(left) == len(walked) + 1  # none older than three days
    async with rt.transaction() as s:
        await map_builds.prune_walks(s, retention_days=1.0)
        left = (
            await s.execute(select(SurveyPoint.walk).where(SurveyPoint.building_id == building_id))
        ).all()
    assert [w for (w,) in left] == [None]  # the lone point stays


async def test_a_point_with_wifi_and_beacons_is_two_reference_scans(
    client: httpx.AsyncClient, admin: dict[str, str], rt: Runtime
) -> None:
    site_id, building_id = await _empty_site(client, admin)
    points = _corridor_walks(seed=6)
    for i, p in enumerate(points):  # a beacon heard at every point, louder at the west end
        p["ble"] = [{"id": "b-1", "rssi_dbm": -60.0 - p["x_m"], "age_ms": i % 3 * 1000}]
    await _survey(client, admin, building_id, points)
    await _built(client, admin, rt, building_id, 1)
    service = await _service_maps(rt, site_id)
    scans = service.scans
    assert scans is not None
    assert len(scans) == 2 * len(points)
    # no reference scan mixes WiFi with beacons
    kinds = np.array([key.split(":", 1)[0] for key in scans.emitters])
    per_entry = np.repeat(kinds, np.diff(scans.indptr))
    for row in range(len(scans)):
        assert len(set(per_entry[scans.rows == row].tolist())) == 1
    ble = scans.emitters.index("ble:b-1")
    assert scans.indptr[ble + 1] - scans.indptr[ble] == len(points)
    fresh = scans.fresh[scans.indptr[ble] : scans.indptr[ble + 1]]
    assert sorted({round(float(f), 4) for f in fresh}) == [0.88, 1.0]  # 0, 1 and 2 s old
