"""Map quality of one floor: the figures of ``mapping.map_quality`` over the floor's current
maps and contributions, read from the store.

The current maps are the building's latest radio map version (its reference points, RPs,
on this floor) and the floor's latest magnetic map version; contributions are the floor's
survey points (surveyed through the admin API or folded in from uploads). The figures are
computed in a worker thread.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

import anyio
import numpy as np
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.mapping.map_quality import (
    Coverage,
    Emitters,
    FloorFigures,
    Freshness,
    MagneticCells,
    QualityParams,
    QualityPoint,
    RadioCells,
    floor_figures,
)
from server.positioning.radio.fingerprints import MISSING_DBM
from server.services.errors import NotFound
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo
from server.storage.repositories import surveys as survey_repo


@dataclass(frozen=True)
class MapRef:
    id: str
    version: int


@dataclass(frozen=True)
class MapQuality:
    floor_id: str
    radio_map: MapRef | None
    magnetic_map: MapRef | None
    coverage: Coverage
    radio_cells: RadioCells
    magnetic_cells: MagneticCells
    freshness: Freshness
    emitters: Emitters


async def floor_map_quality(
    s: AsyncSession, floor_id: str, params: QualityParams | None = None
) -> MapQuality:
    """How good the floor's current maps are (module docstring)."""
    params = params or QualityParams()
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    radio_row = await map_repo.latest_radio_map(s, floor.building_id)
    radio = await map_repo.load_radio_map(s, radio_row.id, MISSING_DBM) if radio_row else None
    magnetic_row = await map_repo.latest_magnetic_map(s, floor_id)
    points = [
        QualityPoint(p.x_m, p.y_m, p.t_ms, p.created_at, p.upload_id, p.readings)
        for p in await survey_repo.list_survey_points(s, floor.building_id)
        if p.floor_id == floor_id
    ]
    plan_geojson = floor.plan_geojson
    now = datetime.now(UTC)

    def figures_of_floor() -> FloorFigures:
        # CPU work (a grid of up to millions of cells decompressed, plans rasterised,
        # emitters fitted): in a worker thread
        grid = map_repo.magnetic_grid(magnetic_row) if magnetic_row is not None else None
        rp_xy, count, var, seen = np.zeros((0, 2)), np.zeros((0, 0), np.int32), None, set()
        if radio is not None:
            on_floor = np.array([f == floor_id for f in radio.rp_floor_id], dtype=bool)
            rp_xy = radio.rp_xy[on_floor].astype(np.float64)
            count, var = radio.count[on_floor], radio.var_db2[on_floor]
            seen = {radio.emitters[i] for i in np.flatnonzero((count > 0).any(axis=0)).tolist()}
        return floor_figures(plan_geojson, rp_xy, count, var, seen, grid, points, params, now)

    figures = await anyio.to_thread.run_sync(figures_of_floor)
    return MapQuality(
        floor_id=floor_id,
        radio_map=MapRef(radio_row.id, radio_row.version) if radio_row else None,
        magnetic_map=MapRef(magnetic_row.id, magnetic_row.version) if magnetic_row else None,
        coverage=figures.coverage,
        radio_cells=figures.radio_cells,
        magnetic_cells=figures.magnetic_cells,
        freshness=figures.freshness,
        emitters=figures.emitters,
    )
