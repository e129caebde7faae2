"""Map quality of one floor: the figures of ``mapping.map_quality`` over the floor's current
maps and contributions, read from the store, and the per-cell grid of
``mapping.coverage_grid`` that shows where the radio map is thin.

The current maps are the building's latest radio map version (its reference points, RPs,
on this floor) and the floor's latest magnetic map version; contributions are the floor's
survey points (surveyed through the admin API or folded in from uploads). The figures are
computed in a worker thread.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import anyio
import numpy as np
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.mapping.coverage_grid import (
    CoverageGrid,
    TooManyCells,
    coverage_grid,
    rows_of,
)
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
from server.positioning.radio import fix_error
from server.positioning.radio.fingerprints import MISSING_DBM
from server.services.errors import Invalid, NotFound
from server.storage.map_artefacts import fix_error_from_json
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


@dataclass(frozen=True)
class FloorCoverage:
    floor_id: str
    radio_map: MapRef | None
    fix_error_source: str  # "learned" with the map (a table of some kind), or "default"
    grid: CoverageGrid

    def document(self) -> dict[str, Any]:
        """The grid as the API answers it: its frame and, per figure, rows of cells
        (None where unknown), rounded to what a map can tell."""
        g = self.grid
        rows, cols = g.shape
        return {
            "floor_id": self.floor_id,
            "radio_map": vars(self.radio_map) if self.radio_map else None,
            "fix_error": self.fix_error_source,
            "walkable_area_known": g.walkable_area_known,
            "origin_m": list(g.origin_m),
            "cell_m": g.cell_m,
            "rows": rows,
            "cols": cols,
            "cells": {
                "in_area": rows_of(g.in_area),
                "readings": rows_of(g.readings),
                "points": rows_of(g.points),
                "emitters": rows_of(g.emitters),
                "var_db2": rows_of(g.var_db2, 2),
                "age_days": rows_of(g.age_days, 3),
                "nearest_rp_m": rows_of(g.nearest_rp_m, 2),
                "expected_error_m": rows_of(g.expected_error_m, 2),
            },
        }


async def floor_coverage(s: AsyncSession, floor_id: str, cell_m: float) -> FloorCoverage:
    """The coverage grid of the floor's current radio map and survey points, in cells of
    ``cell_m`` (``mapping.coverage_grid``). A floor without a map or points has an empty
    grid, or one of its plan's cells without data; a ``cell_m`` too small for the floor
    is refused (Invalid, naming it)."""
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    radio_row = await map_repo.latest_radio_map(s, floor.building_id)
    radio = await map_repo.load_radio_map(s, radio_row.id, MISSING_DBM) if radio_row else None
    table = radio_row.fix_error if radio_row is not None else None
    model = fix_error_from_json(table) if table is not None else fix_error.DEFAULT
    places = await survey_repo.survey_point_places(s, floor_id)
    plan_geojson = floor.plan_geojson
    now_s = datetime.now(UTC).timestamp()

    def grid_of_floor() -> CoverageGrid:
        # CPU work (the cells laid over a plan of thousands of vertices): in a worker thread
        rp_xy, count, var = np.zeros((0, 2)), np.zeros((0, 0), np.int32), np.zeros((0, 0))
        kinds: list[str] = []
        if radio is not None:
            on_floor = np.array([f == floor_id for f in radio.rp_floor_id], dtype=bool)
            rp_xy = radio.rp_xy[on_floor].astype(np.float64)
            count, var = radio.count[on_floor], radio.var_db2[on_floor].astype(np.float64)
            kinds = [kind for kind, _ in radio.emitters]
        return coverage_grid(
            plan_geojson,
            rp_xy,
            count,
            var,
            kinds,
            np.array([(x, y) for x, y, _ in places], dtype=np.float64).reshape(-1, 2),
            np.array([created.timestamp() for *_, created in places], dtype=np.float64),
            now_s,
            model,
            cell_m,
        )

    try:
        grid = await anyio.to_thread.run_sync(grid_of_floor)
    except TooManyCells as e:
        raise Invalid(f"{cell_m:g} m is too small: {e}", field="cell_m") from None
    return FloorCoverage(
        floor_id=floor_id,
        radio_map=MapRef(radio_row.id, radio_row.version) if radio_row else None,
        # a build without walks to learn from stores the default table
        fix_error_source="learned" if model.sigma_m else "default",
        grid=grid,
    )
