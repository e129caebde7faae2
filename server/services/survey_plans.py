"""Where to survey a floor next: the reference-point placement plan of its graph and
current radio map (``mapping.survey_plan``), as GeoJSON points."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import anyio
import numpy as np
from scipy.spatial import cKDTree
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.mapping.survey_plan import SurveyPlan, survey_plan
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.navigation_graph import FloorGraph, free_graph, plan_graph
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap
from server.services.errors import Invalid, NotFound
from server.services.maps import stored_radio_map
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo


@dataclass(frozen=True)
class FloorSurveyPlan:
    """A floor's plan, the current map's reference points and the graph it was laid on."""

    floor_id: str
    plan: SurveyPlan
    graph: FloorGraph
    rp_xy: np.ndarray  # (n, 2) the floor's current reference points
    surveyed: np.ndarray  # (n_points,) bool: a current RP within one grid gap

    def geojson(self) -> dict[str, Any]:
        """The planned points as a GeoJSON FeatureCollection with the plan's figures."""
        plan = self.plan
        features = [
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [float(x), float(y)]},
                "properties": {
                    "kind": "reference_point",
                    "rule": "ap_line" if from_ap else "coverage",
                    "surveyed": bool(done),
                },
            }
            for (x, y), from_ap, done in zip(
                plan.points.tolist(), plan.from_aps.tolist(), self.surveyed.tolist(), strict=True
            )
        ]
        return {
            "type": "FeatureCollection",
            "features": features,
            "properties": {
                "floor_id": self.floor_id,
                "n_points": len(features),
                "n_surveyed": int(self.surveyed.sum()),
                "grid_m": self.graph.spacing_m,
                "noise_db": plan.noise_db,
                "noise_source": plan.noise_source,
                "n_access_points": len(plan.aps),
                "expected_error_m": plan.expected_error_m,
                "expected_error_p90_m": plan.expected_error_p90_m,
            },
        }


def plan_floor(
    floor_id: str,
    plan_geojson: dict[str, Any] | None,
    radio: RadioMap | None,
    floor: int,
    noise_distance_m: float | None = None,
) -> FloorSurveyPlan:
    """The survey plan of one floor (CPU work: run it off the event loop).

    Raises
    ------
    Invalid
        The floor has neither a usable plan nor reference points to lay a grid over.
    """
    rows = radio.rp_floor == floor if radio is not None else np.zeros(0, dtype=bool)
    rp_xy = radio.rp_xy[rows].astype(np.float64) if radio is not None else np.zeros((0, 2))
    graph: FloorGraph | None = None
    if plan_geojson:
        try:
            graph = plan_graph(plan_from_geojson(plan_geojson), plan_geojson)
        except ValueError:
            graph = None
    if graph is None:
        if rp_xy.shape[0] == 0:
            raise Invalid(
                f"floor {floor_id} has neither a usable plan nor reference points to plan over",
                field="floor_id",
            )
        graph = free_graph(rp_xy)
    found = survey_plan(graph, radio, floor, noise_distance_m)
    if rp_xy.shape[0] and found.points.shape[0]:
        gap = cKDTree(rp_xy).query(found.points)[0]
        surveyed = gap <= graph.spacing_m
    else:
        surveyed = np.zeros(found.points.shape[0], dtype=bool)
    return FloorSurveyPlan(floor_id, found, graph, rp_xy, surveyed)


async def floor_survey_plan(
    s: AsyncSession, floor_id: str, noise_distance_m: float | None = None
) -> FloorSurveyPlan:
    """The floor's survey plan from its stored plan and its building's latest radio map."""
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    floors = await site_repo.list_floors(s, floor.building_id)
    index = {f.id: i for i, f in enumerate(floors)}
    row = await map_repo.latest_radio_map(s, floor.building_id)
    radio = None
    if row is not None:
        radio = stored_radio_map(await map_repo.load_radio_map(s, row.id, MISSING_DBM), index)
    geojson = floor.plan_geojson
    return await anyio.to_thread.run_sync(
        lambda: plan_floor(floor_id, geojson, radio, index[floor_id], noise_distance_m)
    )
