"""The client simulator's synthetic building, geo-referenced, set up in the app under test
through the admin API, and a walk of one of its simulated phones cut into batches (the
tests of sessions' history and its exports)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import httpx

from client_sim.run import simulated_walker, step_batches, walker_params
from client_sim.seeding import stream
from client_sim.survey import survey_bodies, survey_points
from client_sim.world import SyntheticWorld, synthesize_world
from tests.support.toy_site import device_headers

SEED = 0
ORIGIN = (47.3769, 8.5417)  # latitude, longitude (Zurich)
ROTATION_RAD = math.radians(30.0)
T0_MS = 1_700_000_000_000


@dataclass(frozen=True)
class GeoSite:
    site_id: str
    building_id: str
    world: SyntheticWorld
    device: dict[str, str]  # the header of a device key for the site


async def provision_geo_site(client: httpx.AsyncClient, admin: dict[str, str]) -> GeoSite:
    """The simulator's building of ``SEED`` in a new site, at ``ORIGIN`` turned by
    ``ROTATION_RAD``: its floors, their plans and a survey of every floor."""
    world = synthesize_world(SEED)
    r = await client.post("/v1/sites", json={"name": "geo walk"}, headers=admin)
    assert r.status_code == 201, r.text
    site_id = r.json()["id"]
    building = {
        "name": "synthetic building",
        "origin_lat": ORIGIN[0],
        "origin_lon": ORIGIN[1],
        "rotation_rad": ROTATION_RAD,
    }
    r = await client.post(f"/v1/sites/{site_id}/buildings", json=building, headers=admin)
    assert r.status_code == 201, r.text
    building_id = r.json()["id"]
    for floor in world.building.floors:
        r = await client.post(
            f"/v1/buildings/{building_id}/floors", json={"level": floor.level}, headers=admin
        )
        assert r.status_code == 201, r.text
        r = await client.put(
            f"/v1/floors/{r.json()['id']}/plan", json=floor.plan_geojson(), headers=admin
        )
        assert r.status_code == 200, r.text
    points = survey_points(world, stream(SEED, "survey"), t0_ms=T0_MS - 86_400_000)
    for body in survey_bodies(points):
        r = await client.post(f"/v1/buildings/{building_id}/survey", json=body, headers=admin)
        assert r.status_code == 201, r.text
    device = await device_headers(client, admin, site_id=site_id)
    return GeoSite(site_id, building_id, world, device)


def walk(world: SyntheticWorld, minutes: float) -> list[list[dict[str, Any]]]:
    """The events of walker 0 (on the lowest level) over ``minutes`` of its own time, a
    batch per step, as a phone would post them."""
    walker = simulated_walker(world, SEED, 0, T0_MS, walker_params())
    batches: list[list[dict[str, Any]]] = []
    for due_s, batch in step_batches(walker.events(), 1):
        if due_s > 60.0 * minutes:
            return batches
        batches.append([item.event for item in batch])
    raise AssertionError("a walk has no end")
