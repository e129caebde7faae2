"""Provision a synthetic site through the admin API: site, building, floors, plans, survey."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from client_sim.api import ApiClient
from client_sim.building import SyntheticBuilding
from client_sim.seeding import stream
from client_sim.survey import MAX_POINTS_PER_REQUEST, survey_bodies, survey_points
from client_sim.world import SyntheticWorld, synthesize_world


@dataclass(frozen=True)
class ProvisionedSite:
    """Ids of what :func:`provision_site` created; ``radio_map`` is the last survey's
    ``RadioMapRead``."""

    site_id: str
    building_id: str
    floor_ids: Mapping[int, str]  # level -> floor id
    survey_points: int
    radio_map: Mapping[str, Any]
    world: SyntheticWorld


async def provision_site(
    api: ApiClient,
    building: SyntheticBuilding,
    seed: int,
    *,
    world: SyntheticWorld | None = None,
    name: str | None = None,
    survey_spacing_m: float = 2.0,
    max_points_per_request: int = MAX_POINTS_PER_REQUEST,
) -> ProvisionedSite:
    """Create a site with ``building``, put each floor's plan and post its survey.

    The radio environment and magnetic field come from ``world`` when given (its building
    must be ``building``), else from ``synthesize_world(seed, building)``; the survey's
    scans draw from the ``"survey"`` stream of ``seed``.
    """
    if world is None:
        world = synthesize_world(seed, building)
    elif world.building is not building:
        raise ValueError("world.building must be the building being provisioned")
    site = await api.create_site(name or f"client_sim seed {seed}")
    created = await api.create_building(site["id"], "synthetic building")
    building_id = str(created["id"])
    floor_ids: dict[int, str] = {}
    for floor in building.floors:
        row = await api.create_floor(building_id, floor.level, f"level {floor.level}")
        floor_ids[floor.level] = str(row["id"])
        await api.put_plan(floor_ids[floor.level], floor.plan_geojson())
    # timestamps one second apart, the last one now
    n_points = sum(len(f.walkable_grid(survey_spacing_m)) for f in building.floors)
    points = survey_points(
        world,
        stream(seed, "survey"),
        spacing_m=survey_spacing_m,
        t0_ms=int(time.time() * 1000) - 1000 * max(0, n_points - 1),
        period_ms=1000,
    )
    radio_map: Mapping[str, Any] = {}
    for body in survey_bodies(points, max_points_per_request):
        radio_map = await api.post_survey(building_id, body)
    return ProvisionedSite(
        site_id=str(site["id"]),
        building_id=building_id,
        floor_ids=floor_ids,
        survey_points=len(points),
        radio_map=radio_map,
        world=world,
    )


async def reuse_site(api: ApiClient, site_id: str, world: SyntheticWorld) -> ProvisionedSite:
    """A site :func:`provision_site` made before for ``world``'s building: its ids, checked
    to have one building with a floor of every level, each with a plan, and a radio map."""
    await api.get(f"/v1/sites/{site_id}")
    buildings = (await api.get(f"/v1/sites/{site_id}/buildings"))["items"]
    if len(buildings) != 1:
        raise ValueError(f"site {site_id} has {len(buildings)} buildings, not the simulator's one")
    building_id = str(buildings[0]["id"])
    floors = (await api.get(f"/v1/buildings/{building_id}/floors"))["items"]
    floor_ids = {int(f["level"]): str(f["id"]) for f in floors if f["has_plan"]}
    missing = sorted(set(world.building.levels) - set(floor_ids))
    if missing:
        raise ValueError(f"site {site_id} has no planned floor at levels {missing}")
    maps = (await api.get(f"/v1/buildings/{building_id}/radio-maps"))["items"]
    if not maps:
        raise ValueError(f"site {site_id} has no radio map")
    latest = max(maps, key=lambda m: str(m["activated_at"]))
    return ProvisionedSite(
        site_id=site_id,
        building_id=building_id,
        floor_ids=floor_ids,
        survey_points=int(latest["n_survey_points"]),
        radio_map=latest,
        world=world,
    )
