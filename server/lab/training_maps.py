"""Maps from training traces, and what they were built from.

Each scan is placed by linear interpolation between the surveyor's waypoints and the scans
are gridded by the same code the survey API uses (``gridding.build_radio_map``, cells of
``TRACE_CELL_M``); for engines that read them, the magnetometer samples are placed the
same way and gridded per floor, and the floor plans come with the maps. What the maps were
built from is kept as a surveyor would upload it (``TrainingSurvey``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.datasets.ilc import IlcSite
from server.datasets.ilc_trace import read_trace
from server.datasets.walk import Walk
from server.lab.progress import Progress
from server.positioning import fix_error
from server.positioning.engines import NEEDS_GRAPHS
from server.positioning.events import BleEvent, WifiEvent, radio_key
from server.positioning.fai import FaiParams
from server.positioning.fingerprint import RadioMap, in_place_order
from server.positioning.fix_error import FixErrorModel
from server.positioning.floor_graph import site_graphs
from server.positioning.floorplan import FloorPlan
from server.positioning.floorplan_geojson import plan_from_geojson
from server.positioning.magnetic import MagneticGrid, MagneticMap
from server.positioning.mapping.fai_maps import build_fai_maps
from server.positioning.mapping.fix_calibration import learn_fix_error
from server.positioning.mapping.gridding import build_radio_map
from server.positioning.mapping.labelled import interpolate_track
from server.positioning.mapping.magnetic_gridding import grid_from_samples
from server.positioning.mapping.matrices import readings_matrix
from server.positioning.sitemaps import FloorRef, SiteMaps

# Traces sample the walk every few metres; 1 m cells keep that resolution and merge only
# scans taken at nearly the same spot (the same cell size as surveys).
TRACE_CELL_M = 1.0


def site_floors(site: IlcSite) -> tuple[FloorRef, ...]:
    return tuple(FloorRef(site.name, f.name, f.level) for f in site.floors)


@dataclass
class LabelledScans:
    """Scans placed on the floor by interpolation between waypoints: what the map builder
    eats, and what a survey upload carries."""

    xy_m: list[tuple[float, float]] = field(default_factory=list)
    floor: list[int] = field(default_factory=list)
    events: list[WifiEvent | BleEvent] = field(default_factory=list)
    path: list[int] = field(default_factory=list)  # which trace each scan came from
    n_traces: int = 0

    def add_trace(self, trace: Walk, floor_index: int, group: int | None = None) -> None:
        """Place the trace's scans; ``group`` says which walk they belong to for the
        cross-validation of fix errors (scans of one group are never located on a map
        holding any of them): by default each trace is its own, and walks repeated along
        one route should share one."""
        events = trace.radio_events()
        self.n_traces += 1
        if not events or trace.waypoint_t_ms.size == 0:
            return
        t = np.array([e.t_ms for e in events], dtype=np.int64)
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, t)
        for event, point, ok in zip(events, xy.tolist(), valid.tolist(), strict=True):
            if ok and event.readings:
                self.xy_m.append((point[0], point[1]))
                self.floor.append(floor_index)
                self.events.append(event)
                self.path.append(self.n_traces if group is None else -1 - group)

    def keyed_scans(self) -> list[list[tuple[str, float]]]:
        """Each scan's readings keyed as map columns."""
        return [
            [(radio_key(_kind(e), r.emitter), r.rssi_dbm) for r in e.readings] for e in self.events
        ]

    def radio_map(self, cell_m: float = TRACE_CELL_M) -> RadioMap:
        emitters, rssi = readings_matrix(self.keyed_scans())
        xy = np.asarray(self.xy_m, dtype=np.float64).reshape(-1, 2)
        return build_radio_map(
            xy, np.asarray(self.floor, dtype=np.int64), rssi, emitters, cell_m=cell_m
        )


def _kind(event: WifiEvent | BleEvent) -> str:
    return "wifi" if isinstance(event, WifiEvent) else "ble"


def learned_fix_error(scans: LabelledScans, seed: int = 0) -> FixErrorModel:
    """How far radio fixes fall from the truth by their evidence, learned from the
    labelled scans by path-wise cross-validation (``mapping.fix_calibration``)."""
    if not scans.events:
        return fix_error.DEFAULT
    return learn_fix_error(
        np.asarray(scans.xy_m, dtype=np.float64).reshape(-1, 2),
        np.asarray(scans.floor, dtype=np.int64),
        np.asarray(scans.path, dtype=np.int64),
        scans.keyed_scans(),
        np.random.default_rng(seed),
    )


@dataclass
class LabelledField:
    """Magnetometer samples placed on the floor by interpolation between waypoints, per
    floor index: what the magnetic map is gridded from."""

    xy_m: dict[int, list[NDArray[np.float64]]] = field(default_factory=dict)
    magnitude_ut: dict[int, list[NDArray[np.float64]]] = field(default_factory=dict)

    def add_trace(self, trace: Walk, floor_index: int) -> None:
        samples = trace.magnetic
        if samples.shape[0] == 0 or trace.waypoint_t_ms.size == 0:
            return
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, samples[:, 0])
        strength = np.linalg.norm(samples[:, 1:4], axis=1)
        keep = valid & np.isfinite(strength)
        self.xy_m.setdefault(floor_index, []).append(xy[keep])
        self.magnitude_ut.setdefault(floor_index, []).append(strength[keep])

    def magnetic_map(self, site: IlcSite) -> MagneticMap:
        """One grid per floor over the floor's extent (``magnetic.CELL_M`` cells)."""
        grids: list[MagneticGrid | None] = []
        for index, floor in enumerate(site.floors):
            if index not in self.xy_m:
                grids.append(None)
                continue
            grids.append(
                grid_from_samples(
                    np.concatenate(self.xy_m[index]),
                    np.concatenate(self.magnitude_ut[index]),
                    extent=(0.0, 0.0, floor.width_m, floor.height_m),
                )
            )
        return MagneticMap(tuple(grids), version="train")


@dataclass(frozen=True)
class TrainingSurvey:
    """What the training maps were built from, as a surveyor would upload it: the labelled
    scans, and for engines that read them the magnetometer samples and the floor plans
    (GeoJSON by floor index; empty otherwise)."""

    scans: LabelledScans
    field: LabelledField | None = None
    plans: tuple[dict[str, Any] | None, ...] = ()
    traces: tuple[tuple[int, Path], ...] = ()  # (floor index, file) of each training trace
    # the waypoints of each training trace by floor index: the walks the floor graphs'
    # moves are learned from (floor_graph.learn)
    walks: Mapping[int, tuple[NDArray[np.float64], ...]] = dataclasses.field(default_factory=dict)


def site_plans(site: IlcSite) -> tuple[FloorPlan | None, ...]:
    """Each floor's plan as walkable space and walls (None where a floor has no plan)."""
    return tuple(plan_from_geojson(f.plan) if f.plan else None for f in site.floors)


def with_graphs(
    maps: SiteMaps,
    engine: str,
    geojsons: Sequence[Mapping[str, Any] | None],
    walks: Mapping[int, Sequence[NDArray[np.float64]]],
) -> SiteMaps:
    """The maps with each floor's reference-point graph (from its plan, else over its
    reference points; moves learned from the training walks), for an engine that reads
    them."""
    if engine not in NEEDS_GRAPHS:
        return maps
    graphs = site_graphs(maps.plans, geojsons, maps.radio, len(maps.floors), walks)
    return replace(maps, graphs=graphs)


# engines that read the fingerprinting accuracy indicators' data (``SiteMaps.fai``)
NEEDS_FAI_MAPS = frozenset({"fai_ekf"})


def with_fai_maps(maps: SiteMaps, engine: str) -> SiteMaps:
    """The maps with what the accuracy indicators read of the radio map, for an engine
    that uses them (``mapping.fai_maps``; about half a minute for an ILC floor)."""
    if engine not in NEEDS_FAI_MAPS or maps.radio is None:
        return maps
    return replace(maps, fai=build_fai_maps(maps.radio, FaiParams()))


def build_site_maps(
    site: IlcSite,
    train: Iterable[tuple[int, Path]],
    progress: Progress | None = None,
    *,
    magnetic: bool = False,
) -> tuple[SiteMaps, TrainingSurvey, int]:
    """Radio map of the site from its training traces; also what it was built from
    (``TrainingSurvey``) and the number of unreadable lines met. With ``magnetic``, also
    the magnetic map from the training traces' magnetometer and the floor plans (for
    engines that read them)."""
    labelled = LabelledScans()
    field_samples = LabelledField()
    bad_lines = 0
    train = list(train)
    walks: dict[int, list[NDArray[np.float64]]] = {}
    for done, (floor_index, path) in enumerate(train, start=1):
        trace = read_trace(path, site.floors[floor_index].name)
        bad_lines += trace.bad_lines
        labelled.add_trace(trace, floor_index)
        walks.setdefault(floor_index, []).append(trace.waypoint_xy_m)
        if magnetic:
            field_samples.add_trace(trace, floor_index)
        if progress:
            progress("maps", done, len(train))
    radio = in_place_order(labelled.radio_map()) if labelled.events else None
    maps = SiteMaps(
        site_floors(site), radio, version="train", fix_error=learned_fix_error(labelled)
    )
    by_floor = {f: tuple(w) for f, w in walks.items()}
    if not magnetic:
        return maps, TrainingSurvey(labelled, traces=tuple(train), walks=by_floor), bad_lines
    maps = replace(maps, plans=site_plans(site), magnetic=field_samples.magnetic_map(site))
    plans = tuple(f.plan for f in site.floors)
    survey = TrainingSurvey(labelled, field_samples, plans, tuple(train), by_floor)
    return maps, survey, bad_lines
