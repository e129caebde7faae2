"""Magnetic maps: survey samples in, the floor's next grid version out.

Each survey is gridded on its own (``mapping.magnetic_gridding.grid_from_sources``,
0.5 m cells on the lattice of whole cells) and folded into the floor's current grid with
the pairwise moment update (``mapping.magnetic_gridding.merge_grids``), so a version
holds the statistics of every sample surveyed so far and the order of the surveys does
not matter. Versions of a building are written one at a time (the building row is
locked).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import anyio
import numpy as np
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.mapping.magnetic_gridding import (
    GridTooLarge,
    MagneticSamples,
    grid_from_sources,
    merge_grids,
    samples_along_line,
)
from server.positioning.plan.geojson_plan import PLAN_MARGIN_M, Extent, near_extent, plan_extent
from server.services.errors import Invalid, NotFound
from server.storage.models import MagneticMapVersion
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo


@dataclass(frozen=True)
class MagneticPointData:
    x_m: float
    y_m: float
    magnitude_ut: float
    horizontal_ut: float | None = None
    vertical_ut: float | None = None


@dataclass(frozen=True)
class MagneticLineData:
    start_xy: tuple[float, float]
    end_xy: tuple[float, float]
    t_start_ms: int
    t_end_ms: int
    samples: Sequence[tuple[float, float, float, float]]  # t, x, y, z in µT


def survey_sources(
    points: Sequence[MagneticPointData], lines: Sequence[MagneticLineData]
) -> list[MagneticSamples]:
    """The positioned samples of a survey: its points, then each line's samples placed by
    time (``mapping.magnetic_gridding.samples_along_line``). A line none of whose
    samples falls between its start and end times is refused, naming it."""
    sources = []
    if points:
        nan = float("nan")
        sources.append(
            MagneticSamples(
                xy=[(p.x_m, p.y_m) for p in points],
                magnitude=[p.magnitude_ut for p in points],
                horizontal=[nan if p.horizontal_ut is None else p.horizontal_ut for p in points]
                if any(p.horizontal_ut is not None for p in points)
                else None,
                vertical=[nan if p.vertical_ut is None else p.vertical_ut for p in points]
                if any(p.vertical_ut is not None for p in points)
                else None,
            )
        )
    for i, line in enumerate(lines):
        rows = np.asarray(line.samples, dtype=np.float64).reshape(-1, 4)
        xy, magnitude = samples_along_line(
            line.start_xy,
            line.end_xy,
            line.t_start_ms,
            line.t_end_ms,
            rows[:, 0],
            np.linalg.norm(rows[:, 1:4], axis=1),
        )
        if magnitude.size == 0:
            raise Invalid(
                "no sample falls between t_start and t_end of this line",
                field=f"lines.{i}.samples",
            )
        sources.append(MagneticSamples(xy=xy, magnitude=magnitude))
    return sources


async def fold_sources(
    s: AsyncSession,
    floor_id: str,
    sources: Sequence[MagneticSamples],
    source: str = "survey",
    field: str = "body",
) -> MagneticMapVersion:
    """Grid the sources and store them merged with the floor's current grid as its next
    version. The caller holds the building lock. Invalid (about ``field``) when the grid
    would be larger than ``mapping.magnetic_gridding.MAX_GRID_CELLS``, before it is allocated."""
    current = await map_repo.latest_magnetic_map(s, floor_id)

    def build() -> MagneticGrid:
        grid = grid_from_sources(sources)
        return merge_grids(map_repo.magnetic_grid(current), grid) if current else grid

    try:
        grid = await anyio.to_thread.run_sync(build)
    except GridTooLarge as exc:
        raise Invalid(str(exc), field=field) from None
    return await map_repo.save_magnetic_map(s, floor_id, grid, source=source)


def check_on_floor(
    places: Sequence[tuple[str, tuple[float, float], Extent | None]],
    axes: tuple[str, str] = ("", ""),
) -> None:
    """Refuse the first of ``places`` (name, ``(x, y)``, its floor plan's walkable extent)
    farther than ``PLAN_MARGIN_M`` outside its extent, naming it: the name, then the
    suffix in ``axes`` of the coordinate that is out (x first). A place on a floor without
    a plan (extent None) is bounded by the wire's coordinate range and the grid size alone
    (``mapping.magnetic_gridding.MAX_GRID_CELLS``). Magnetic and radio surveys
    (``services.maps``) both check their points with it."""
    bounded = [(name, xy, extent) for name, xy, extent in places if extent is not None]
    if not bounded:
        return
    near = near_extent([extent for *_, extent in bounded], [xy for _, xy, _ in bounded])
    for (name, (x, y), extent), (x_near, y_near) in zip(bounded, near.tolist(), strict=True):
        if not (x_near and y_near):
            x0, y0, x1, y1 = extent
            raise Invalid(
                f"({x:g}, {y:g}) lies more than {PLAN_MARGIN_M:g} m outside the floor plan, "
                f"which spans x {x0:g}..{x1:g} m and y {y0:g}..{y1:g} m",
                field=name + axes[1 if x_near else 0],
            )


async def add_magnetic_survey(
    s: AsyncSession,
    floor_id: str,
    points: Sequence[MagneticPointData],
    lines: Sequence[MagneticLineData],
) -> MagneticMapVersion:
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    extent = plan_extent(floor.plan_geojson)
    places = [(f"points.{i}", (p.x_m, p.y_m), extent) for i, p in enumerate(points)]
    for i, line in enumerate(lines):
        places += [
            (f"lines.{i}.start", line.start_xy, extent),
            (f"lines.{i}.end", line.end_xy, extent),
        ]
    check_on_floor(places)
    sources = survey_sources(points, lines)
    await site_repo.lock_building(s, floor.building_id)
    return await fold_sources(s, floor_id, sources, field="points" if not lines else "lines")


async def list_magnetic_maps(s: AsyncSession, floor_id: str) -> Sequence[MagneticMapVersion]:
    if await site_repo.get_floor(s, floor_id) is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    return await map_repo.list_magnetic_maps(s, floor_id)


async def activate_magnetic_map(s: AsyncSession, floor_id: str, version: int) -> MagneticMapVersion:
    """Make a version the floor's current magnetic map again (see
    ``maps.activate_radio_map``)."""
    floor = await site_repo.get_floor(s, floor_id)
    if floor is None:
        raise NotFound(f"floor {floor_id} not found", field="floor_id")
    await site_repo.lock_building(s, floor.building_id)
    row = await map_repo.get_magnetic_map_version(s, floor_id, version)
    if row is None:
        raise NotFound(f"magnetic map version {version} not found", field="version")
    row.activated_at = await map_repo.next_activation(
        s, MagneticMapVersion, MagneticMapVersion.floor_id, floor_id
    )
    return row
