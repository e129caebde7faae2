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

from server.positioning.engines.shared.site_maps import FloorRef
from server.positioning.mapping import map_set
from server.positioning.mapping.map_set import SiteRecords, SurveyedScans
from server.positioning.model.events import radio_key
from server.positioning.plan.navigation_graph import FloorGraph
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap, in_place_order
from server.services.maps import BUILT, FAILED, PENDING, SUPERSEDED, owe_build, stored_radio_map
from server.storage import map_artefacts
from server.storage.models import RadioMapVersion, SurveyPoint, utcnow
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo

LEASE_S = 900.0  # a build of a mall takes a minute or two; a dead worker's lease runs out
MAX_ATTEMPTS = 3
RETRY_S = 60.0  # a failed build is tried again after this (times the attempts so far)
CLAIM_SCAN = 50  # pending versions looked at per claim
POINTS_PER_READ = 5000  # survey points read from SQL at a time
PARTS = frozenset({map_set.FIX_ERROR, map_set.FAI, map_set.GRAPHS})
"""What the worker builds of a version (its radio and magnetic maps are written on the
request that made them)."""


@dataclass(frozen=True)
class Claim:
    """A version leased to this worker, and the attempt it is on."""

    version_id: str
    building_id: str
    attempt: int


async def claim(
    s: AsyncSession, settle_s: float = 0.0, building_id: str | None = None
) -> Claim | None:
    """Lease the newest pending version that is its building's current one (versions a
    newer one replaced meanwhile become ``superseded``) and was made at least
    ``settle_s`` ago (a survey sent in several requests makes a version per request:
    only the last is worth building); only of ``building_id`` when given; None when there
    is none. Every write is a compare-and-set on the row's status and attempts, so two
    workers (or a worker and an activation) never both win."""
    now = utcnow()
    free = (RadioMapVersion.build_leased_until.is_(None)) | (
        RadioMapVersion.build_leased_until < now
    )
    stmt = (
        select(RadioMapVersion.id, RadioMapVersion.building_id, RadioMapVersion.build_attempts)
        .where(RadioMapVersion.build_status == PENDING)
        .where(RadioMapVersion.created_at <= now - timedelta(seconds=settle_s))
        .where(free)
        # newest first: the survey somebody is waiting for, not a backlog of older ones
        .order_by(RadioMapVersion.created_at.desc())
        .limit(CLAIM_SCAN)
    )
    if building_id is not None:
        stmt = stmt.where(RadioMapVersion.building_id == building_id)
    for version_id, owner, attempts in (await s.execute(stmt)).all():
        pending = (
            update(RadioMapVersion)
            .where(RadioMapVersion.id == version_id)
            .where(RadioMapVersion.build_status == PENDING)
            .where(RadioMapVersion.build_attempts == attempts)
            .execution_options(synchronize_session=False)
        )
        if await map_repo.current_radio_map_id(s, owner) != version_id:
            await s.execute(pending.values(build_status=SUPERSEDED))
            continue
        if attempts >= MAX_ATTEMPTS:
            await s.execute(pending.values(build_status=FAILED))
            continue
        taken = await s.execute(
            pending.where(free).values(
                build_leased_until=now + timedelta(seconds=LEASE_S),
                build_attempts=attempts + 1,
            )
        )
        if taken.rowcount == 1:  # type: ignore[attr-defined]
            return Claim(version_id, owner, attempts + 1)
    return None


async def prune_walks(s: AsyncSession, retention_days: float) -> int:
    """Delete the points of recorded walks (surveyed on a walk, or uploaded) folded more
    than ``retention_days`` ago; how many. Points surveyed on their own stay."""
    cutoff = utcnow() - timedelta(days=retention_days)
    gone = await s.execute(
        delete(SurveyPoint)
        .where(SurveyPoint.created_at < cutoff)
        .where(SurveyPoint.walk.is_not(None) | SurveyPoint.upload_id.is_not(None))
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
    rows = await s.execute(
        select(RadioMapVersion.id, RadioMapVersion.parent_id).where(
            RadioMapVersion.building_id == version.building_id
        )
    )
    parents: dict[str, str | None] = {row[0]: row[1] for row in rows.all()}
    ids = {version.id}
    parent = version.parent_id
    while parent is not None and parent not in ids:
        ids.add(parent)
        parent = parents.get(parent)
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
        select(
            SurveyPoint.radio_map_id,
            SurveyPoint.floor_id,
            SurveyPoint.x_m,
            SurveyPoint.y_m,
            SurveyPoint.t_ms,
            SurveyPoint.walk,
            SurveyPoint.route,
            SurveyPoint.readings,
        )
        .where(SurveyPoint.building_id == version.building_id)
        .order_by(SurveyPoint.id)
        .execution_options(yield_per=POINTS_PER_READ)
    )
    xy, floor, t, walk, route, readings, ages = [], [], [], [], [], [], []
    async for map_id, floor_id, x_m, y_m, t_ms, walk_name, route_name, read in await s.stream(stmt):
        # points of the version's chain (and points stored before versions had chains)
        if (map_id is not None and map_id not in chain) or floor_id not in index:
            continue
        # a point's WiFi and BLE readings are two scans, as a phone's are: a WiFi scan
        # is matched against WiFi scans, and a beacon it cannot hear is no difference
        for kind in ("wifi", "ble"):
            rows = read.get(kind) or []
            if not rows:
                continue
            readings.append([(radio_key(kind, r[0]), float(r[1])) for r in rows])
            ages.append([float(r[2]) if len(r) > 2 else None for r in rows])
            xy.append((x_m, y_m))
            floor.append(index[floor_id])
            t.append(t_ms)
            walk.append(walk_name)
            route.append(route_name)
    scans = SurveyedScans.of(xy, floor, readings, t_ms=t, walk=walk, route=route, ages_ms=ages)
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
    blob = map_artefacts.encode_artefacts(emitters, maps.fai, graphs, maps.scans, inputs.floor_ids)
    return Built(
        map_artefacts.fix_error_to_json(maps.fix_error), blob, time.perf_counter() - started
    )


async def store(s: AsyncSession, inputs: BuildInputs, built: Built, attempt: int) -> bool:
    """Keep what was built on its version; False (the version stays pending, to be built
    again) when a plan of the building's floors changed while it was being built, and
    False without a word when the version is gone or no longer this attempt's (its lease
    ran out and another worker took it)."""
    row = await s.get(RadioMapVersion, inputs.version_id)
    if row is None or row.build_status != PENDING or row.build_attempts != attempt:
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
        owe_build(row)
        return False
    row.fix_error = built.fix_error
    row.artefacts = built.artefacts
    row.build_seconds = built.seconds
    row.build_status = BUILT
    row.build_error = None
    return True


async def record_failure(s: AsyncSession, version_id: str, error: str, attempt: int) -> bool:
    """Note a failed build: tried again after ``RETRY_S`` times the attempts so far; True
    when the version is out of attempts (``failed``) or no longer this attempt's."""
    row = await s.get(RadioMapVersion, version_id)
    if row is None or row.build_status != PENDING or row.build_attempts != attempt:
        return True
    row.build_error = error[:2000]
    row.build_leased_until = utcnow() + timedelta(seconds=RETRY_S * row.build_attempts)
    if row.build_attempts >= MAX_ATTEMPTS:
        row.build_status = FAILED
        return True
    return False
