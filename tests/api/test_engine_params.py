"""Engine parameters through the service: the engines' defaults, a site's settings and a
session's own ``params``, checked with a 422 that names the nested field."""

from __future__ import annotations

import httpx
import pytest
from fastapi import FastAPI

from server.positioning.engines.pf_magnetic import PfMagneticState
from server.positioning.engines.registry import get_engine
from server.positioning.filters.particle_cloud import Particles
from server.positioning.radio.fix_error import DEFAULT_ERROR_68_M
from server.services import batches, engine_settings, sessions
from server.services.maps import site_maps
from server.services.session_records import SessionState
from server.storage.repositories.engine_settings import put_engine_setting
from tests.support.sessions import lose_the_store
from tests.support.toy_site import ToySite, build_toy_site, rssi_at

T0 = 1_700_000_000_000


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def open_pf(
    client: httpx.AsyncClient, site: ToySite, params: object = None
) -> httpx.Response:
    body: dict[str, object] = {"site_id": site.site_id, "engine": "pf_magnetic"}
    if params is not None:
        body["params"] = params
    return await client.post("/v1/sessions", json=body, headers=site.device)


def error_field(r: httpx.Response) -> str:
    return ".".join(str(part) for part in r.json()["detail"][0]["loc"])


async def cloud_size(app: FastAPI, session_id: str) -> int:
    """Particles in the session's state, read back from the store."""
    return (await pf_cloud(app, session_id)).n


async def pf_cloud(app: FastAPI, session_id: str) -> Particles:
    """The session's cloud as the store holds it: its snapshot, stepped through the
    batches logged since (``services.batches``), not this process's copy."""
    rt = app.state.runtime
    rt.states.drop(session_id)
    _, meta, state = await sessions.load_state(rt, session_id, None)
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, meta.site_id)
    params = engine_settings.session_params(meta.engine, meta.params)
    engine_state = batches.caught_up(state, meta, maps, params)
    assert isinstance(engine_state, PfMagneticState)
    assert engine_state.cloud is not None
    return engine_state.cloud


async def start_cloud(client: httpx.AsyncClient, created: httpx.Response) -> None:
    sid, token = created.json()["id"], created.json()["token"]
    scan = {"type": "wifi", "t": T0, "readings": rssi_at(4.0, 5.0, 0)}
    r = await client.post(
        f"/v1/sessions/{sid}/batches",
        json={"seq": 1, "events": [scan]},
        headers={"Authorization": f"Bearer {token}"},
    )
    assert r.status_code == 200, r.text
    assert len(r.json()["fixes"]) == 1


async def test_a_session_runs_with_its_own_params(
    client: httpx.AsyncClient, app: FastAPI, site: ToySite
) -> None:
    created = await open_pf(client, site, {"particles": {"n": 500}})
    assert created.status_code == 201, created.text
    await start_cloud(client, created)
    assert await cloud_size(app, created.json()["id"]) == 500
    default = await open_pf(client, site)
    await start_cloud(client, default)
    assert await cloud_size(app, default.json()["id"]) == 3000


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"particles": {"n": 0}}, "params.particles.n"),
        ({"particles": {"n": 20_001}}, "params.particles.n"),
        ({"particles": {"n": "500"}}, "params.particles.n"),
        ({"particles": {"nn": 5}}, "params.particles.nn"),
        ({"particles": 5}, "params.particles"),
        ({"weighting": "magic"}, "params.weighting"),
        ({"tracker": {"steps": {"threshold_ms2": -1.0}}}, "params.tracker.steps.threshold_ms2"),
        # sizes a session could otherwise blow up
        ({"particles": {"window": 100_000}}, "params.particles.window"),
        ({"tracker": {"turns": {"window_steps": 10**6}}}, "params.tracker.turns.window_steps"),
        ({"tracker": {"fusion": {"window_s": 3600.0}}}, "params.tracker.fusion.window_s"),
        ({"floor_sd_db": 10**400}, "params.floor_sd_db"),
        ({"k": 2**64}, "params.k"),
        ({"accuracy": {"scale_68": 1e200}}, "params.accuracy.scale_68"),
        ({"accuracy": {"floor_68": 15.0}}, "params.accuracy.floor_95"),
    ],
)
async def test_a_bad_parameter_is_refused_naming_its_field(
    client: httpx.AsyncClient, site: ToySite, params: object, field: str
) -> None:
    r = await open_pf(client, site, params)
    assert r.status_code == 422, r.text
    assert error_field(r) == field, r.json()


async def test_site_settings_reach_new_sessions_under_their_own_params(
    client: httpx.AsyncClient, app: FastAPI, site: ToySite, admin: dict[str, str]
) -> None:
    url = f"/v1/sites/{site.site_id}/engines/pf_magnetic"
    r = await client.put(url, json={"params": {"particles": {"n": 800}}}, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["params"] == {"particles": {"n": 800}}
    assert r.json()["effective"]["particles"]["n"] == 800
    assert r.json()["effective"]["particles"]["window"] == 3  # the rest: defaults
    first = await open_pf(client, site)
    await start_cloud(client, first)
    assert await cloud_size(app, first.json()["id"]) == 800
    # a session's own params go over the site's, field by field
    own = await open_pf(client, site, {"particles": {"window": 4}})
    await start_cloud(client, own)
    cloud = await pf_cloud(app, own.json()["id"])
    assert cloud.n == 800
    assert cloud.observed.shape == (5,)
    # a later change reaches new sessions only
    r = await client.put(url, json={"params": {"particles": {"n": 600}}}, headers=admin)
    assert r.status_code == 200
    assert await cloud_size(app, first.json()["id"]) == 800
    r = await client.delete(url, headers=admin)
    assert r.status_code == 204
    assert (await client.get(url, headers=admin)).json()["params"] == {}


async def test_a_rebuilt_session_keeps_its_params(
    client: httpx.AsyncClient, app: FastAPI, site: ToySite
) -> None:
    created = await open_pf(client, site, {"particles": {"n": 400}})
    await lose_the_store(app.state.runtime, created.json()["id"])
    await start_cloud(client, created)
    assert await cloud_size(app, created.json()["id"]) == 400


async def test_site_settings_are_checked_and_need_a_maps_key(
    client: httpx.AsyncClient, site: ToySite, admin: dict[str, str]
) -> None:
    url = f"/v1/sites/{site.site_id}/engines/pf_magnetic"
    r = await client.put(url, json={"params": {"particles": {"n": -3}}}, headers=admin)
    assert r.status_code == 422
    assert error_field(r) == "params.particles.n"
    r = await client.put(url, json={"params": {}}, headers=site.device)
    assert r.status_code == 403
    r = await client.put(
        f"/v1/sites/{site.site_id}/engines/nope", json={"params": {}}, headers=admin
    )
    assert r.status_code == 404
    assert "known engines" in r.json()["message"]


async def test_the_engines_and_their_defaults_are_listed(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    r = await client.get("/v1/engines", headers=site.device)
    assert r.status_code == 200, r.text
    engines = {e["name"]: e for e in r.json()["items"]}
    assert {"wknn", "step_ekf", "pf_magnetic", "two_stage_ekf", "everywhere_ekf"} <= set(engines)
    assert engines["pf_magnetic"]["params"]["particles"]["n"] == 3000
    assert "mag" in engines["pf_magnetic"]["uses"]
    r = await client.get(f"/v1/sites/{site.site_id}/engines", headers=site.device)
    assert r.status_code == 403  # a device key is not a viewer


def test_an_engine_state_of_the_old_layout_is_not_decoded() -> None:
    spec = get_engine("wknn")
    state = SessionState(3, spec.start(spec.params()), (), b"", 0, 0)
    blob = state.to_bytes(spec)
    assert SessionState.from_bytes(blob, spec).last_seq == 3
    from server.services.session_records import StaleEngineState
    from server.storage.codec import decode_arrays, encode_arrays

    arrays = decode_arrays(blob)
    del arrays["engine_layout"]  # as the servers before the state codec wrote them
    with pytest.raises(StaleEngineState):
        SessionState.from_bytes(encode_arrays(arrays), spec)


async def test_stored_settings_a_newer_server_refuses_are_not_used(
    client: httpx.AsyncClient, app: FastAPI, site: ToySite, admin: dict[str, str]
) -> None:
    """Settings valid once and refused now (a parameter renamed) leave new sessions on
    the defaults, and the settings say why."""
    rt = app.state.runtime
    async with rt.transaction() as s:
        await put_engine_setting(s, site.site_id, "pf_magnetic", {"particles": {"nn": 800}})
    created = await open_pf(client, site, {"particles": {"n": 700}})
    assert created.status_code == 201, created.text
    await start_cloud(client, created)
    assert await cloud_size(app, created.json()["id"]) == 700
    r = await client.get(f"/v1/sites/{site.site_id}/engines/pf_magnetic", headers=admin)
    assert r.status_code == 200, r.text
    assert "particles.nn" in r.json()["problem"]
    assert r.json()["effective"]["particles"]["n"] == 3000


async def test_locate_reports_with_the_sites_wknn_settings(
    client: httpx.AsyncClient, site: ToySite, admin: dict[str, str]
) -> None:
    body = {"site_id": site.site_id, "wifi": rssi_at(4.0, 5.0, 0)}
    before = await client.post("/v1/locate", json=body, headers=site.device)
    assert before.status_code == 200, before.text
    assert before.json()["accuracy_68_m"] < before.json()["accuracy_95_m"]
    # floors in the map's radio error: the toy site's maps learn none, so the default's
    accuracy = {"floor_68": 2.0, "scale_68": 1.0, "floor_95": 3.0, "scale_95": 2.0}
    r = await client.put(
        f"/v1/sites/{site.site_id}/engines/wknn",
        json={"params": {"accuracy": accuracy}},
        headers=admin,
    )
    assert r.status_code == 200, r.text
    after = await client.post("/v1/locate", json=body, headers=site.device)
    assert after.json()["accuracy_68_m"] >= 2.0 * DEFAULT_ERROR_68_M
    assert after.json()["accuracy_95_m"] >= 3.0 * DEFAULT_ERROR_68_M
