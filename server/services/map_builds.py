"""What the worker builds of each radio map version beside the map, and how a process
reads it back.

A survey, an upload or an activation leaves the building's current radio map version
``pending``. A worker leases it (``claim``; one worker at a time, the lease runs out
after ``LEASE_S`` so a worker that died gives it back), gathers what the version was
built from (``build_inputs``: the survey points folded along its chain of versions with
their walks and routes, the floor plans) and hands them to the one map builder of the
core (``positioning.mapping.map_set.build_map_set``) with the version's own radio map, in
a thread; the fix-error table, the FAI maps and the floor graphs it returns are stored on
the version (``storage.map_artefacts``) and the version is ``built``. A version superseded
before a worker reached it is left ``superseded`` and built if it is activated again. A
build that raises is retried ``MAX_ATTEMPTS`` times, then the version is ``failed`` and
sessions keep the defaults (the constant-variance strategies, uniform graph moves).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import delete, select, update
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.events import radio_key
from server.positioning.fingerprint import MISSING_DBM, RadioMap, in_place_order
from server.positioning.floor_graph import FloorGraph
from server.positioning.mapping import map_set
from server.positioning.mapping.map_set import SiteRecords, SurveyedScans
from server.positioning.sitemaps import FloorRef
from server.services.maps import BUILT, FAILED, PENDING, SUPERSEDED, stored_radio_map
from server.storage import map_artefacts
from server.storage.models import RadioMapVersion, SurveyPoint, utcnow
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo

LEASE_S = 900.0  # a build of a mall takes a minute or two; a dead worker's lease runs out
MAX_ATTEMPTS = 3
PARTS = frozenset({map_set.FIX_ERROR, map_set.FAI, map_set.GRAPHS})
"""What the worker builds of a version (its radio and magnetic maps are written on the
request that made them)."""


async def claim(
    s: AsyncSession, settle_s: float = 0.0, building_id: str | None = None
) -> RadioMapVersion | None:
    """Lease the oldest pending version that is its building's current one (versions a
    newer one replaced meanwhile become ``superseded``) and was made at least
    ``settle_s`` ago (a survey sent in several requests makes a version per request:
    only the last is worth building); only of ``building_id`` when given; None when there
    is none."""
    now = utcnow()
    stmt = (
        select(RadioMapVersion)
        .where(RadioMapVersion.build_status == PENDING)
        .where(RadioMapVersion.created_at <= now - timedelta(seconds=settle_s))
        .where(
            (RadioMapVersion.build_leased_until.is_(None))
            | (RadioMapVersion.build_leased_until < now)
        )
        .order_by(RadioMapVersion.created_at)
    )
    if building_id is not None:
        stmt = stmt.where(RadioMapVersion.building_id == building_id)
    for row in (await s.scalars(stmt)).all():
        current = await map_repo.latest_radio_map(s, row.building_id)
        if current is None or current.id != row.id:
            row.build_status = SUPERSEDED
            continue
        if row.build_attempts >= MAX_ATTEMPTS:
            row.build_status = FAILED
            continue
        # compare-and-set on the lease: of two workers reading the same row, one wins
        taken = await s.execute(
            update(RadioMapVersion)
            .where(RadioMapVersion.id == row.id)
            .where(RadioMapVersion.build_attempts == row.build_attempts)
            .values(
                build_leased_until=now + timedelta(seconds=LEASE_S),
                build_attempts=row.build_attempts + 1,
            )
            .execution_options(synchronize_session=False)
        )
        if taken.rowcount == 1:  # type: ignore[attr-defined]
            await s.refresh(row)
            return row
    return None


async def prune_walks(s: AsyncSession, retention_days: float) -> int:
    """Delete the survey points folded more than ``retention_days`` ago; how many."""
    cutoff = utcnow() - timedelta(days=retention_days)
    gone = await s.execute(
        delete(SurveyPoint)
        .where(SurveyPoint.created_at < cutoff)
        .execution_options(synchronize_session=False)
    )
    return int(gone.rowcount or 0)  # type: ignore[attr-defined]


async def release_leases(s: AsyncSession) -> None:
    """Give back every lease (for a process that is the only worker: whatever build was
    leased died with its previous run)."""
    await s.execute(
        update(RadioMapVersion)
        .where(RadioMapVersion.build_status == PENDING)
        .values(build_leased_until=None)
        .execution_options(synchronize_session=False)
    )


@dataclass(frozen=True)
class BuildInputs:
    """What one version's build reads: the site's floors, the records (the version's
    points, and the plans of its own building's floors), the version's radio map in place
    order, and the ids and plan digests of the site's floors, with which of them are the
    building's."""

    version_id: str
    building_id: str
    records: SiteRecords
    radio: RadioMap | None
    floor_ids: tuple[str, ...]
    plan_digests: tuple[str, ...]
    own: tuple[bool, ...]


async def _chain(s: AsyncSession, version: RadioMapVersion) -> set[str]:
    """The version and every version it was folded onto."""
    ids = {version.id}
    parent = version.parent_id
    while parent is not None and parent not in ids:
        ids.add(parent)
        row = await s.get(RadioMapVersion, parent)
        parent = row.parent_id if row is not None else None
    return ids


async def build_inputs(s: AsyncSession, version_id: str) -> BuildInputs:
    """Gather a version's build inputs (module docstring). The floors are the site's,
    in the order the map cache gives them, so the artefacts index what sessions read;
    only the version's own building's floors have their plans (and graphs)."""
    version = await s.get(RadioMapVersion, version_id)
    if version is None:
        raise LookupError(f"radio map {version_id} is gone")
    building = await site_repo.get_building(s, version.building_id)
    if building is None:
        raise LookupError(f"building {version.building_id} is gone")
    floors = await site_repo.list_site_floors(s, building.site_id)
    refs = tuple(FloorRef(b.id, f.id, f.level, b.rotation_rad) for f, b in floors)
    own = tuple(b.id == building.id for _, b in floors)
    index = {f.id: i for i, (f, _) in enumerate(floors)}
    chain = await _chain(s, version)
    stmt = (
        select(SurveyPoint)
        .where(SurveyPoint.building_id == version.building_id)
        .where(SurveyPoint.radio_map_id.in_(chain) | SurveyPoint.radio_map_id.is_(None))
        .order_by(SurveyPoint.id)
    )
    xy, floor, t, walk, route, readings = [], [], [], [], [], []
    for p in (await s.scalars(stmt)).all():
        keyed = [(radio_key("wifi", k), float(v)) for k, v in p.readings.get("wifi", [])]
        keyed += [(radio_key("ble", k), float(v)) for k, v in p.readings.get("ble", [])]
        if not keyed or p.floor_id not in index:
            continue
        xy.append((p.x_m, p.y_m))
        floor.append(index[p.floor_id])
        t.append(p.t_ms)
        walk.append(p.walk)
        route.append(p.route)
        readings.append(keyed)
    scans = SurveyedScans.of(xy, floor, readings, t_ms=t, walk=walk, route=route)
    plans = tuple(
        f.plan_geojson if mine else None for (f, _), mine in zip(floors, own, strict=True)
    )
    stored = await map_repo.load_radio_map(s, version.id, MISSING_DBM)
    radio = in_place_order(stored_radio_map(stored, index)) if len(stored.rp_xy) else None
    return BuildInputs(
        version.id,
        building.id,
        SiteRecords(refs, scans, plans),
        radio,
        tuple(f.id for f, _ in floors),
        tuple(map_artefacts.plan_digest(p) for p in plans),
        own,
    )


@dataclass(frozen=True)
class Built:
    fix_error: dict[str, Any]
    artefacts: bytes
    seconds: float


def build(inputs: BuildInputs) -> Built:
    """Run the map builder on a version's inputs and encode what it made (CPU-bound: call
    it in a thread or another process)."""
    started = time.perf_counter()
    maps = map_set.build_map_set(inputs.records, parts=PARTS, radio=inputs.radio)
    graphs: dict[str, tuple[FloorGraph, str]] = {}
    for i, graph in enumerate(maps.graphs):
        if graph is not None and inputs.own[i]:
            graphs[inputs.floor_ids[i]] = (graph, inputs.plan_digests[i])
    emitters = inputs.radio.emitters if inputs.radio is not None else ()
    blob = map_artefacts.encode_artefacts(emitters, maps.fai, graphs)
    return Built(
        map_artefacts.fix_error_to_json(maps.fix_error), blob, time.perf_counter() - started
    )


async def store(s: AsyncSession, inputs: BuildInputs, built: Built) -> bool:
    """Keep what was built on its version; False (the version stays pending, to be built
    again) when a plan of the building's floors changed while it was being built, or the
    version is gone."""
    row = await s.get(RadioMapVersion, inputs.version_id)
    if row is None:  # deleted with its building meanwhile
        return False
    floors = await site_repo.list_floors(s, inputs.building_id)
    now = {f.id: map_artefacts.plan_digest(f.plan_geojson) for f in floors}
    used = {
        f: digest
        for f, digest, mine in zip(inputs.floor_ids, inputs.plan_digests, inputs.own, strict=True)
        if mine
    }
    row.build_leased_until = None
    if now != used:
        row.build_status = PENDING
        row.build_attempts = 0
        return False
    row.fix_error = built.fix_error
    row.artefacts = built.artefacts
    row.build_seconds = built.seconds
    row.build_status = BUILT
    row.build_error = None
    return True


async def record_failure(s: AsyncSession, version_id: str, error: str) -> bool:
    """Note a failed build; True when the version is out of attempts (``failed``)."""
    row = await s.get(RadioMapVersion, version_id)
    if row is None:
        return True
    row.build_error = error[:2000]
    row.build_leased_until = None
    if row.build_attempts >= MAX_ATTEMPTS:
        row.build_status = FAILED
        return True
    return False
