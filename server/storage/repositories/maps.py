"""Map versions: radio maps (emitters, reference-point statistics) and magnetic grids, and
which version is current (``next_activation``)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import func, insert, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.radio.fingerprints import RadioMap
from server.storage.codec import array_to_str, compress_arrays, decompress_arrays, str_to_array
from server.storage.models import (
    Emitter,
    Floor,
    MagneticMapVersion,
    RadioMapVersion,
    RadioStat,
    ReferencePoint,
    utcnow,
)


async def ensure_emitters(
    s: AsyncSession, building_id: str, keys: Iterable[tuple[str, str]]
) -> dict[tuple[str, str], int]:
    """Ids of the building's emitters ``(kind, key)``, creating the missing ones."""
    wanted = set(keys)
    stmt = select(Emitter.kind, Emitter.key, Emitter.id).where(Emitter.building_id == building_id)
    known = {(k, key): i for k, key, i in (await s.execute(stmt)).all()}
    missing = sorted(wanted - known.keys())
    if missing:
        rows = [{"building_id": building_id, "kind": k, "key": key} for k, key in missing]
        await s.execute(insert(Emitter), rows)
        known = {(k, key): i for k, key, i in (await s.execute(stmt)).all()}
    return {k: known[k] for k in wanted}


@dataclass(frozen=True)
class RadioMapArrays:
    """One radio map version as dense arrays (rows: reference points, columns: emitters)."""

    map_id: str
    rp_floor_id: list[str]
    rp_xy: NDArray[np.float32]
    emitters: list[tuple[str, str]]  # (kind, key) per column
    mean_dbm: NDArray[np.float32]
    var_db2: NDArray[np.float32]
    count: NDArray[np.int32]
    rp_points: NDArray[np.int32] | None = None  # None for versions stored as rows


async def save_radio_map(
    s: AsyncSession,
    building_id: str,
    *,
    cell_m: float,
    n_survey_points: int,
    floor_ids: Sequence[str],
    radio: RadioMap,
    emitter_ids: Sequence[int],
    source: str = "survey",
    parent_id: str | None = None,
) -> RadioMapVersion:
    """Store a new version (the next number for the building) and make it current. The
    arrays go into one compressed blob: RPs (position, floor as an index into
    ``floor_ids``, points behind each) and only the heard RP x emitter entries."""
    last = await s.scalar(
        select(func.max(RadioMapVersion.version)).where(RadioMapVersion.building_id == building_id)
    )
    heard_rp, heard_em = np.nonzero(radio.count > 0)
    points = radio.rp_points if radio.rp_points is not None else np.ones(len(radio.rp_xy))
    arrays = {
        "rp_xy": np.asarray(radio.rp_xy, dtype=np.float32),
        "rp_floor": np.asarray(radio.rp_floor, dtype=np.int32),
        "rp_points": np.asarray(points, dtype=np.int32),
        "floor_ids": str_to_array(",".join(floor_ids)),
        "emitter_ids": np.asarray(emitter_ids, dtype=np.int64),
        "heard_rp": heard_rp.astype(np.int32),
        "heard_em": heard_em.astype(np.int32),
        "mean_dbm": radio.mean_dbm[heard_rp, heard_em].astype(np.float32),
        "var_db2": radio.var_db2[heard_rp, heard_em].astype(np.float32),
        "count": radio.count[heard_rp, heard_em].astype(np.int32),
    }
    row = RadioMapVersion(
        building_id=building_id,
        version=(last or 0) + 1,
        cell_m=cell_m,
        n_reference_points=int(radio.rp_xy.shape[0]),
        n_emitters=int(np.unique(heard_em).size),
        n_survey_points=n_survey_points,
        source=source,
        parent_id=parent_id,
        arrays=compress_arrays(arrays),
        activated_at=await next_activation(
            s, RadioMapVersion, RadioMapVersion.building_id, building_id
        ),
    )
    s.add(row)
    await s.flush()
    return row


async def latest_radio_map(s: AsyncSession, building_id: str) -> RadioMapVersion | None:
    """The building's current version: the one activated last (a new version is
    activated when it is written; an older one again when it is rolled back to)."""
    stmt = (
        select(RadioMapVersion)
        .where(RadioMapVersion.building_id == building_id)
        .order_by(RadioMapVersion.activated_at.desc(), RadioMapVersion.version.desc())
        .limit(1)
    )
    return (await s.scalars(stmt)).one_or_none()


async def current_radio_map_id(s: AsyncSession, building_id: str) -> str | None:
    """The id of the building's current version (``latest_radio_map``) alone."""
    stmt = (
        select(RadioMapVersion.id)
        .where(RadioMapVersion.building_id == building_id)
        .order_by(RadioMapVersion.activated_at.desc(), RadioMapVersion.version.desc())
        .limit(1)
    )
    return (await s.execute(stmt)).scalar_one_or_none()


async def load_artefacts(s: AsyncSession, map_id: str) -> bytes | None:
    """What the worker built of a version beside its map (``storage.map_artefacts``)."""
    stmt = select(RadioMapVersion.artefacts).where(RadioMapVersion.id == map_id)
    return (await s.execute(stmt)).scalar_one_or_none()


async def get_radio_map_version(
    s: AsyncSession, building_id: str, version: int
) -> RadioMapVersion | None:
    stmt = select(RadioMapVersion).where(
        RadioMapVersion.building_id == building_id, RadioMapVersion.version == version
    )
    return (await s.scalars(stmt)).one_or_none()


async def list_radio_maps(s: AsyncSession, building_id: str) -> Sequence[RadioMapVersion]:
    stmt = select(RadioMapVersion).where(RadioMapVersion.building_id == building_id)
    return (await s.scalars(stmt.order_by(RadioMapVersion.version))).all()


async def load_radio_map(s: AsyncSession, map_id: str, missing_dbm: float) -> RadioMapArrays:
    """A stored version without the reference points of floors deleted since it was
    made (a version outlives the floors it covered)."""
    row = await s.get(RadioMapVersion, map_id)
    if row is not None and row.arrays is not None:
        return await _radio_map_from_blob(s, row, missing_dbm)
    rps = (
        await s.execute(
            select(
                ReferencePoint.floor_id, ReferencePoint.x_m, ReferencePoint.y_m, ReferencePoint.idx
            )
            .where(ReferencePoint.map_id == map_id)
            .order_by(ReferencePoint.idx)
        )
    ).all()
    stats = (
        await s.execute(
            select(
                RadioStat.rp_idx,
                RadioStat.emitter_id,
                RadioStat.mean_dbm,
                RadioStat.var_db2,
                RadioStat.count,
                Emitter.kind,
                Emitter.key,
            )
            .join(Emitter, RadioStat.emitter_id == Emitter.id)
            .where(RadioStat.map_id == map_id)
        )
    ).all()
    # a deleted floor took its reference points with it (the foreign key's cascade)
    row_of = {r[3]: i for i, r in enumerate(rps)}
    stats = [r for r in stats if r[0] in row_of]
    columns = sorted({(kind, key) for *_, kind, key in stats})
    col_of = {k: i for i, k in enumerate(columns)}
    n_rp, n_em = len(rps), len(columns)
    mean = np.full((n_rp, n_em), missing_dbm, dtype=np.float32)
    var = np.zeros((n_rp, n_em), dtype=np.float32)
    count = np.zeros((n_rp, n_em), dtype=np.int32)
    if stats:
        rp_idx = np.fromiter((row_of[r[0]] for r in stats), dtype=np.int64, count=len(stats))
        col = np.fromiter((col_of[(r[5], r[6])] for r in stats), dtype=np.int64, count=len(stats))
        mean[rp_idx, col] = [r[2] for r in stats]
        var[rp_idx, col] = [r[3] for r in stats]
        count[rp_idx, col] = [r[4] for r in stats]
    return RadioMapArrays(
        map_id=map_id,
        rp_floor_id=[r[0] for r in rps],
        rp_xy=np.asarray([(r[1], r[2]) for r in rps], dtype=np.float32).reshape(n_rp, 2),
        emitters=columns,
        mean_dbm=mean,
        var_db2=var,
        count=count,
    )


async def _radio_map_from_blob(
    s: AsyncSession, row: RadioMapVersion, missing_dbm: float
) -> RadioMapArrays:
    assert row.arrays is not None
    a = decompress_arrays(row.arrays)
    floor_ids = array_to_str(a["floor_ids"]).split(",")
    ids = a["emitter_ids"].tolist()
    stmt = select(Emitter.id, Emitter.kind, Emitter.key).where(Emitter.id.in_(ids))
    by_id = {i: (kind, key) for i, kind, key in (await s.execute(stmt)).all()}
    n_rp, n_em = a["rp_xy"].shape[0], len(ids)
    mean = np.full((n_rp, n_em), missing_dbm, dtype=np.float32)
    var = np.zeros((n_rp, n_em), dtype=np.float32)
    count = np.zeros((n_rp, n_em), dtype=np.int32)
    mean[a["heard_rp"], a["heard_em"]] = a["mean_dbm"]
    var[a["heard_rp"], a["heard_em"]] = a["var_db2"]
    count[a["heard_rp"], a["heard_em"]] = a["count"]
    stored = RadioMapArrays(
        map_id=row.id,
        rp_floor_id=[floor_ids[i] for i in a["rp_floor"].tolist()],
        rp_xy=a["rp_xy"],
        emitters=[by_id[i] for i in ids],
        mean_dbm=mean,
        var_db2=var,
        count=count,
        rp_points=a["rp_points"],
    )
    existing = set(await s.scalars(select(Floor.id).where(Floor.id.in_(set(floor_ids)))))
    if existing.issuperset(floor_ids):
        return stored
    keep = np.array([f in existing for f in stored.rp_floor_id], dtype=bool)
    return replace(
        stored,
        rp_floor_id=[f for f in stored.rp_floor_id if f in existing],
        rp_xy=stored.rp_xy[keep],
        mean_dbm=mean[keep],
        var_db2=var[keep],
        count=count[keep],
        rp_points=a["rp_points"][keep],
    )


async def next_activation(s: AsyncSession, model: Any, owner: Any, owner_id: str) -> datetime:
    """The activation time for a version made current now: the clock, but always after
    every earlier activation of the same building or floor, so that a host whose clock
    lags can never make an older version current again. Call with the building lock."""
    last = await s.scalar(select(func.max(model.activated_at)).where(owner == owner_id))
    now = utcnow()
    return now if last is None or now > last else last + timedelta(microseconds=1)


async def save_magnetic_map(
    s: AsyncSession, floor_id: str, grid: MagneticGrid, *, source: str = "survey"
) -> MagneticMapVersion:
    """Store a floor's grid as its next version (arrays compressed in one blob)."""
    last = await s.scalar(
        select(func.max(MagneticMapVersion.version)).where(MagneticMapVersion.floor_id == floor_id)
    )
    arrays = {"magnitude": grid.magnitude, "var": grid.var, "count": grid.count}
    for name in ("horizontal", "vertical"):
        if (component := getattr(grid, name)) is not None:
            arrays[name] = component
    n_rows, n_cols = grid.magnitude.shape
    row = MagneticMapVersion(
        floor_id=floor_id,
        version=(last or 0) + 1,
        origin_x_m=grid.origin_m[0],
        origin_y_m=grid.origin_m[1],
        resolution_m=grid.cell_m,
        n_rows=n_rows,
        n_cols=n_cols,
        n_samples=int(grid.count.sum()),
        known_cells=int(np.isfinite(grid.magnitude).sum()),
        source=source,
        arrays=compress_arrays(arrays),
        activated_at=await next_activation(
            s, MagneticMapVersion, MagneticMapVersion.floor_id, floor_id
        ),
    )
    s.add(row)
    await s.flush()
    return row


async def latest_magnetic_map(s: AsyncSession, floor_id: str) -> MagneticMapVersion | None:
    """The floor's current version: the one activated last."""
    stmt = (
        select(MagneticMapVersion)
        .where(MagneticMapVersion.floor_id == floor_id)
        .order_by(MagneticMapVersion.activated_at.desc(), MagneticMapVersion.version.desc())
        .limit(1)
    )
    return (await s.scalars(stmt)).one_or_none()


async def get_magnetic_map_version(
    s: AsyncSession, floor_id: str, version: int
) -> MagneticMapVersion | None:
    stmt = select(MagneticMapVersion).where(
        MagneticMapVersion.floor_id == floor_id, MagneticMapVersion.version == version
    )
    return (await s.scalars(stmt)).one_or_none()


async def list_magnetic_maps(s: AsyncSession, floor_id: str) -> Sequence[MagneticMapVersion]:
    stmt = select(MagneticMapVersion).where(MagneticMapVersion.floor_id == floor_id)
    return (await s.scalars(stmt.order_by(MagneticMapVersion.version))).all()


def magnetic_grid(row: MagneticMapVersion) -> MagneticGrid:
    """The grid a stored version holds (CPU work: decompression)."""
    arrays = decompress_arrays(row.arrays)
    for values in arrays.values():
        values.flags.writeable = False
    return MagneticGrid(
        origin_m=(row.origin_x_m, row.origin_y_m),
        cell_m=row.resolution_m,
        magnitude=arrays["magnitude"],
        var=arrays["var"],
        count=arrays["count"],
        horizontal=arrays.get("horizontal"),
        vertical=arrays.get("vertical"),
    )
