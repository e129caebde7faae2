"""Radio maps: survey points in, a new version out; site map sets (radio, plans, magnetic,
and what the worker built of the current versions: the fix-error table, FAI maps and floor
graphs, ``services.map_builds``) cached in memory by version."""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import anyio
import numpy as np
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.magnetic.field_grid import MagneticMap
from server.positioning.mapping.device_offsets import DeviceOffset
from server.positioning.mapping.gridding import build_radio_map, fold_radio_maps
from server.positioning.mapping.magnetic_gridding import MagneticSamples
from server.positioning.mapping.map_set import merged_fai, most_learned, parse_plans
from server.positioning.mapping.matrices import merge_radio_maps, readings_matrix
from server.positioning.mapping.survey_points import SurveyPointData
from server.positioning.model.events import radio_key
from server.positioning.model.geo import GeoReference
from server.positioning.plan.anchors import anchors_from_plan
from server.positioning.plan.geojson_plan import plan_extent
from server.positioning.plan.navigation_graph import FloorGraph, attach, site_graphs
from server.positioning.plan.zones import ZoneIndex
from server.positioning.radio import fix_error
from server.positioning.radio.accuracy_indicators import FaiMaps
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap, in_place_order
from server.positioning.radio.fix_error import FixErrorModel
from server.positioning.radio.scan_matching import ScanMap, merge_scan_maps
from server.services.device_offsets import building_offsets
from server.services.errors import Invalid, NotFound
from server.services.magnetic_maps import check_on_floor, fold_sources
from server.storage import models
from server.storage.map_artefacts import decode_artefacts, fix_error_from_json, plan_digest
from server.storage.models import Building, RadioMapVersion
from server.storage.repositories import maps as map_repo
from server.storage.repositories import sites as site_repo
from server.storage.repositories import surveys as survey_repo
from server.storage.repositories import zones as zone_repo

# A dense survey (points every metre or two) keeps its resolution with 1 m cells; points
# closer than that are merged into one reference point at their mean position.
SURVEY_CELL_M = 1.0
# How long a process trusts its cached map set before asking SQL for a newer version.
VERSION_CHECK_S = 2.0

# What the worker has made of a radio map version beside the map (services.map_builds).
PENDING = "pending"
BUILT = "built"
FAILED = "failed"
SUPERSEDED = "superseded"


def stored_readings(
    pairs: Sequence[tuple[str, float]], ages_ms: Sequence[float | None]
) -> list[list[Any]]:
    """Readings as a survey point keeps them: ``[id, rssi_dbm]``, or ``[id, rssi_dbm,
    age_ms]`` where the reading's age is known."""
    out: list[list[Any]] = []
    for i, (key, value) in enumerate(pairs):
        age = ages_ms[i] if i < len(ages_ms) else None
        out.append([key.lower(), value] if age is None else [key.lower(), value, age])
    return out


class MapCache:
    """Site map sets per process, keyed by site and refreshed when a version changes."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._entries: OrderedDict[str, tuple[float, SiteMaps]] = OrderedDict()
        self._locks: dict[str, anyio.Lock] = {}

    def invalidate(self, site_id: str) -> None:
        self._entries.pop(site_id, None)

    def expire(self, site_id: str) -> None:
        """Have the next reader check the site's versions against SQL: what changed is
        loaded again, the rest is kept (a new zone does not rasterise the plans again)."""
        entry = self._entries.get(site_id)
        if entry is not None:
            self._entries[site_id] = (-math.inf, entry[1])

    def fresh(self, site_id: str) -> SiteMaps | None:
        """The cached map set when it was checked against SQL less than
        ``VERSION_CHECK_S`` ago (no SQL needed), else None."""
        entry = self._entries.get(site_id)
        if entry is not None and time.monotonic() - entry[0] < VERSION_CHECK_S:
            self._entries.move_to_end(site_id)
            return entry[1]
        return None

    async def get(self, s: AsyncSession, site_id: str) -> SiteMaps:
        cached = self.fresh(site_id)
        if cached is not None:
            return cached
        lock = self._locks.setdefault(site_id, anyio.Lock())
        async with lock:
            entry = self._entries.get(site_id)
            if entry is not None and time.monotonic() - entry[0] < VERSION_CHECK_S:
                return entry[1]
            maps = await _load_site_maps(s, site_id, entry[1] if entry else None)
            self._entries[site_id] = (time.monotonic(), maps)
            self._entries.move_to_end(site_id)
            while len(self._entries) > self._size:
                self._entries.popitem(last=False)
            return maps


async def _load_site_maps(s: AsyncSession, site_id: str, cached: SiteMaps | None) -> SiteMaps:
    floors = await site_repo.list_site_floors(s, site_id)
    refs = tuple(FloorRef(b.id, f.id, f.level, b.rotation_rad, geo_reference(b)) for f, b in floors)
    building_ids = list(dict.fromkeys(b.id for _, b in floors))
    latest = [m for b in building_ids if (m := await map_repo.latest_radio_map(s, b)) is not None]
    anchors = tuple(
        a for i, (f, _) in enumerate(floors) for a in anchors_from_plan(f.plan_geojson, i)
    )
    magnetic = [await map_repo.latest_magnetic_map(s, f.floor_id) for f in refs]
    # a new plan changes walls and anchors without a new radio map
    stored = [f.plan_geojson for f, _ in floors]
    version = "|".join(
        [f.floor_id for f in refs]
        + [f"{m.id}:{m.build_status}" for m in latest]
        + [m.id if m else "-" for m in magnetic]
        + [plan_digest(stored)]
        # where each building sits and how it is turned: fixes in world coordinates
        + [f"{b.origin_lat},{b.origin_lon},{b.rotation_rad}" for _, b in floors]
    )
    zones_version = await zone_repo.site_zones_version(s, site_id)
    zones = None
    if cached is not None and cached.zones.digest == zones_version and cached.floors == refs:
        zones = cached.zones  # by floor index: kept while the floors are the same
    if zones is None:
        zones = zone_index(await zone_repo.site_zones(s, site_id), refs, zones_version)
    if cached is not None and cached.version == version:
        # zones are no map: new ones leave the maps (and what is built of them) as they are
        return cached if cached.zones is zones else replace(cached, zones=zones)
    # rasterising a mall floor takes a good part of a second: not on the event loop
    plans = await anyio.to_thread.run_sync(parse_plans, stored)
    grids = await anyio.to_thread.run_sync(
        lambda: tuple(map_repo.magnetic_grid(m) if m else None for m in magnetic)
    )
    floor_index = {f.floor_id: i for i, f in enumerate(refs)}
    parts = []
    for row in latest:
        parts.append(
            stored_radio_map(await map_repo.load_radio_map(s, row.id, MISSING_DBM), floor_index)
        )
    merged = merge_radio_maps(parts)
    radio = in_place_order(merged) if merged is not None else None
    # what the worker built of each version, also while it builds it again (a new plan
    # changes only the graphs, which are not used on a plan they were not built on)
    built = [
        (row, blob)
        for row in latest
        if row.fix_error is not None and (blob := await map_repo.load_artefacts(s, row.id))
    ]
    learned = await anyio.to_thread.run_sync(
        lambda: _learned(
            built, radio, refs, stored, single=len(latest) == 1, complete=len(built) == len(latest)
        )
    )
    offsets: dict[str, DeviceOffset] = {}
    for building_id in building_ids:  # per model, from the building with most evidence
        for model, found in (await building_offsets(s, building_id)).items():
            if model not in offsets or found.n_pairs > offsets[model].n_pairs:
                offsets[model] = found
    return SiteMaps(
        floors=refs,
        radio=radio,
        version=version,
        anchors=anchors,
        plans=plans,
        magnetic=MagneticMap(grids, version) if any(g is not None for g in grids) else None,
        device_offsets={model: o.offset_db for model, o in offsets.items()},
        fix_error=learned.fix_error,
        fai=learned.fai,
        graphs=learned.graphs,
        scans=learned.scans,
        zones=zones,
        plan_geojson=tuple(stored),
        plan_digest=plan_digest(stored),
    )


def zone_index(rows: Sequence[models.Zone], floors: Sequence[FloorRef], version: str) -> ZoneIndex:
    """A site's zones by floor index, under the ``version`` they were read at."""
    floor_index = {f.floor_id: i for i, f in enumerate(floors)}
    return ZoneIndex.of(
        (
            (floor_index[r.floor_id], r.floor_id, r.id, r.name, r.geometry)
            for r in rows
            if r.floor_id in floor_index
        ),
        version,
    )


@dataclass(frozen=True)
class _Learned:
    fix_error: FixErrorModel
    fai: FaiMaps | None
    graphs: tuple[FloorGraph | None, ...]
    scans: ScanMap | None = None


def _learned(
    built: Sequence[tuple[RadioMapVersion, bytes]],
    radio: RadioMap | None,
    refs: Sequence[FloorRef],
    plans: Sequence[dict[str, Any] | None],
    *,
    single: bool,
    complete: bool = True,
) -> _Learned:
    """What the worker built of the site's current versions, as the site's map set
    holds it: the fix-error table of the version learned from the most fixes, the FAI
    emitter fits by emitter key (the DSF as stored for a one-building site, computed
    here otherwise), and each floor's graph where it was built on the floor's current
    plan, attached to the site's reference points; the reference scans of every building
    when every building's current version has them (``complete``: every one was built)."""
    if not built or radio is None:
        return _Learned(fix_error.DEFAULT, None, ())
    table = most_learned([fix_error_from_json(row.fix_error) for row, _ in built if row.fix_error])
    decoded = [decode_artefacts(blob) for _, blob in built]
    fai_parts = [(a.fai_keys, a.fai) for a in decoded if a.fai is not None]
    # a one-building site's map is its version's: the DSF its build made holds
    dsf = fai_parts[0][1].dsf_m if single and fai_parts else None
    if dsf is not None and dsf.shape[0] != radio.rp_xy.shape[0]:
        dsf = None
    fai = merged_fai(radio, fai_parts, dsf)
    by_floor = {k: v for artefacts in decoded for k, v in artefacts.graphs.items()}
    graphs: list[FloorGraph | None] = []
    for i, ref in enumerate(refs):
        graph, digest = by_floor.get(ref.floor_id, (None, ""))
        current = plan_digest(plans[i]) if i < len(plans) else ""
        graphs.append(attach(graph, radio, i) if graph is not None and digest == current else None)
    # the reference scans of every building once each building's version has them
    # (``complete``); until then scans match on the cells, as every building can
    index = {ref.floor_id: i for i, ref in enumerate(refs)}
    scans = [a.scans_on(index) for a in decoded]
    every = complete and all(m is not None for m in scans)
    joined = merge_scan_maps([m for m in scans if m is not None]) if every else None
    return _Learned(table, fai, tuple(graphs), joined)


def stored_radio_map(stored: map_repo.RadioMapArrays, floor_index: Mapping[str, int]) -> RadioMap:
    """A stored version as the engines and the folding read it, floors by index."""
    return RadioMap(
        rp_xy=stored.rp_xy,
        rp_floor=np.array([floor_index[f] for f in stored.rp_floor_id], dtype=np.int32),
        mean_dbm=stored.mean_dbm,
        var_db2=stored.var_db2,
        count=stored.count,
        emitters=tuple(radio_key(kind, key) for kind, key in stored.emitters),
        # versions stored as rows do not know their points: one per RP
        rp_points=stored.rp_points
        if stored.rp_points is not None
        else np.ones(len(stored.rp_xy), dtype=np.int32),
    )


_GRAPHS: OrderedDict[str, SiteMaps] = OrderedDict()
GRAPH_CACHE_SIZE = 16  # map sets with graphs kept per process


async def with_graphs(maps: SiteMaps) -> SiteMaps:
    """The map set with each floor's reference-point graph, for the engines that read
    them: the worker's (moves learned from the walks, ``services.map_builds``) where it
    has built them, else built here once per map version (``navigation_graph``: from the plan,
    else over the reference points; moves uniform)."""
    found = _GRAPHS.get(maps.version)
    if (
        found is None
        and maps.graphs
        and all(g is not None for i, g in enumerate(maps.graphs) if _has_space(maps, i))
    ):
        found = maps  # the worker built every graph: nothing to add
        _GRAPHS[maps.version] = found
    if found is None:
        built = await anyio.to_thread.run_sync(
            lambda: site_graphs(maps.plans, [], maps.radio, len(maps.floors))
        )
        graphs = tuple(
            maps.graphs[i] if i < len(maps.graphs) and maps.graphs[i] is not None else g
            for i, g in enumerate(built)
        )
        found = replace(maps, graphs=graphs)
        _GRAPHS[maps.version] = found
    _GRAPHS.move_to_end(maps.version)
    while len(_GRAPHS) > GRAPH_CACHE_SIZE:
        _GRAPHS.popitem(last=False)
    # zones are no map (they leave the version as it is): the set's own, not the cached
    return found if found.zones is maps.zones else replace(found, zones=maps.zones)


def _has_space(maps: SiteMaps, floor: int) -> bool:
    """Whether a floor can have a graph: a plan, or reference points."""
    if floor < len(maps.plans) and maps.plans[floor] is not None:
        return True
    return maps.radio is not None and bool(np.any(maps.radio.rp_floor == floor))


async def site_maps(s: AsyncSession, cache: MapCache, site_id: str) -> SiteMaps:
    if await site_repo.get_site(s, site_id) is None:
        raise NotFound(f"site {site_id} not found", field="site_id")
    return await cache.get(s, site_id)


async def add_survey(
    s: AsyncSession,
    building_id: str,
    points: Sequence[SurveyPointData],
    upload_id: str | None = None,
) -> RadioMapVersion:
    """Store labelled fingerprints and build the building's next radio map version from every
    survey point it has (see ``gridding.build_radio_map`` for the gridding rules). Points
    from an upload remember it (``upload_id``). A point on an unknown floor level, or
    farther than ``geojson_plan.PLAN_MARGIN_M`` outside its floor's plan, is refused
    naming it (``magnetic_maps.check_on_floor``, as magnetic surveys are checked)."""
    # one rebuild per building at a time: each sees every point the previous one stored
    building = await site_repo.lock_building(s, building_id)
    if building is None:
        raise NotFound(f"building {building_id} not found", field="building_id")
    floor_by_level = {f.level: f for f in await site_repo.list_floors(s, building_id)}
    for i, p in enumerate(points):
        if p.floor_level not in floor_by_level:
            raise Invalid(
                f"floor level {p.floor_level} does not exist in building {building_id}",
                field=f"points.{i}.floor",
            )
    extents = {level: plan_extent(f.plan_geojson) for level, f in floor_by_level.items()}
    check_on_floor(
        [(f"points.{i}", (p.x_m, p.y_m), extents[p.floor_level]) for i, p in enumerate(points)],
        axes=(".x_m", ".y_m"),
    )
    radio = await fold_survey(
        s,
        building_id,
        points,
        {level: f.id for level, f in floor_by_level.items()},
        source="upload" if upload_id else "survey",
    )
    await survey_repo.add_survey_points(
        s,
        [
            {
                "building_id": building_id,
                "floor_id": floor_by_level[p.floor_level].id,
                "x_m": p.x_m,
                "y_m": p.y_m,
                "t_ms": p.t_ms,
                "upload_id": upload_id,
                # an upload is one walk; its points are held out together
                "walk": p.walk if p.walk is not None or upload_id is None else upload_id,
                "route": p.route,
                "radio_map_id": radio.id,
                "readings": {
                    "wifi": stored_readings(p.wifi, p.wifi_age_ms),
                    "ble": stored_readings(p.ble, p.ble_age_ms),
                    "mag_ut": list(p.mag_ut) if p.mag_ut else None,
                },
            }
            for p in points
        ],
    )
    # the magnetometer readings of the points go into their floors' magnetic maps
    for level, floor in floor_by_level.items():
        with_field = [p for p in points if p.floor_level == level and p.mag_ut is not None]
        if with_field:
            samples = MagneticSamples(
                xy=[(p.x_m, p.y_m) for p in with_field],
                magnitude=[float(np.linalg.norm(p.mag_ut or ())) for p in with_field],
            )
            await fold_sources(s, floor.id, [samples])
    return radio


async def list_radio_maps(s: AsyncSession, building_id: str) -> Sequence[RadioMapVersion]:
    if await site_repo.get_building(s, building_id) is None:
        raise NotFound(f"building {building_id} not found", field="building_id")
    return await map_repo.list_radio_maps(s, building_id)


async def fold_survey(
    s: AsyncSession,
    building_id: str,
    points: Sequence[SurveyPointData],
    floor_ids: dict[int, str],
    source: str = "survey",
) -> RadioMapVersion:
    """Grid the new points' scans (``gridding.build_radio_map``) and fold them into the
    building's current radio map (``gridding.fold_radio_maps``): the next version holds
    the statistics of every point folded so far along the chain of current versions, and
    is written as one blob. ``floor_ids`` maps the points' levels to floor ids. The
    caller holds the building lock."""
    order = sorted(floor_ids.values())
    floor_index = {f: i for i, f in enumerate(order)}
    with_readings = [p for p in points if p.wifi or p.ble]
    scans = [
        [(radio_key("wifi", k), float(v)) for k, v in p.wifi]
        + [(radio_key("ble", k), float(v)) for k, v in p.ble]
        for p in with_readings
    ]
    emitters, rssi = readings_matrix(scans)
    xy = np.array([(p.x_m, p.y_m) for p in with_readings], dtype=np.float64).reshape(-1, 2)
    floor = np.array([floor_index[floor_ids[p.floor_level]] for p in with_readings], dtype=np.int64)
    current = await map_repo.latest_radio_map(s, building_id)
    base = None
    if current is not None:
        base = stored_radio_map(
            await map_repo.load_radio_map(s, current.id, MISSING_DBM), floor_index
        )

    def build() -> RadioMap:
        new = build_radio_map(xy, floor, rssi, emitters, cell_m=SURVEY_CELL_M)
        return fold_radio_maps(base, new, cell_m=SURVEY_CELL_M) if base is not None else new

    radio = await anyio.to_thread.run_sync(build)
    kinds_keys = [tuple(key.split(":", 1)) for key in radio.emitters]
    ids = await map_repo.ensure_emitters(s, building_id, [(k, v) for k, v in kinds_keys])
    return await map_repo.save_radio_map(
        s,
        building_id,
        cell_m=SURVEY_CELL_M,
        n_survey_points=(current.n_survey_points if current else 0) + len(points),
        floor_ids=order,
        radio=radio,
        emitter_ids=[ids[(k, v)] for k, v in kinds_keys],
        source=source,
        parent_id=current.id if current is not None else None,
    )


async def activate_radio_map(s: AsyncSession, building_id: str, version: int) -> RadioMapVersion:
    """Make an earlier (or later) version the building's current radio map again: sessions
    use it from their next map refresh, and later surveys and uploads fold into it (so
    what came after it is left out from then on)."""
    if await site_repo.lock_building(s, building_id) is None:
        raise NotFound(f"building {building_id} not found", field="building_id")
    row = await map_repo.get_radio_map_version(s, building_id, version)
    if row is None:
        raise NotFound(f"radio map version {version} not found", field="version")
    row.activated_at = await map_repo.next_activation(
        s, RadioMapVersion, RadioMapVersion.building_id, building_id
    )
    if row.build_status in (SUPERSEDED, FAILED):  # never built: the worker builds it now
        owe_build(row)
    return row


def owe_build(row: RadioMapVersion) -> None:
    """Make the worker build the version (again), from its first attempt."""
    row.build_status = PENDING
    row.build_attempts = 0
    row.build_leased_until = None


def geo_reference(building: Building) -> GeoReference | None:
    """Where ``building`` sits on the Earth; None when its origin is not set."""
    if building.origin_lat is None or building.origin_lon is None:
        return None
    try:
        return GeoReference(building.origin_lat, building.origin_lon, building.rotation_rad)
    except ValueError:  # stored before the API refused it (a pole): no world coordinates
        return None
