"""Maps from training traces, and what they were built from.

Each scan is placed by linear interpolation between the surveyor's waypoints; for engines
that read them, the magnetometer samples are placed the same way. What a site has is then
handed to the one map builder the service's worker calls too
(``positioning.mapping.map_set.build_map_set``): radio map, fix-error table, FAI maps,
magnetic grids and floor graphs come out of the same code whichever side built them. What
the maps were built from is kept as a surveyor would upload it (``TrainingSurvey``).
"""

from __future__ import annotations

from collections.abc import Collection, Hashable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lab.datasets.ilc import IlcSite
from lab.progress import Progress
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.mapping import map_set
from server.positioning.mapping.labelled import interpolate_track
from server.positioning.mapping.map_set import FloorField, SiteRecords, SurveyedScans
from server.positioning.model.events import BleEvent, WifiEvent, radio_key
from server.positioning.model.walk import Walk
from server.positioning.motion.barometer import PressureWalk
from server.storage.ilc_trace_format import read_trace


def site_floors(site: IlcSite) -> tuple[FloorRef, ...]:
    return tuple(FloorRef(site.name, f.name, f.level) for f in site.floors)


@dataclass
class LabelledScans:
    """Scans placed on the floor by interpolation between waypoints: what the map builder
    eats, and what a survey upload carries."""

    xy_m: list[tuple[float, float]] = field(default_factory=list)
    floor: list[int] = field(default_factory=list)
    events: list[WifiEvent | BleEvent] = field(default_factory=list)
    walk: list[Hashable] = field(default_factory=list)  # which walk each scan came from
    route: list[Hashable | None] = field(default_factory=list)  # walks sharing a route
    n_traces: int = 0

    def add_trace(
        self,
        trace: Walk,
        floor_index: int,
        group: Hashable | None = None,
        walk: Hashable | None = None,
    ) -> None:
        """Place the trace's scans. ``walk`` names the walk they were taken on (by default
        each trace is its own: pass one name for the parts of a walk cut by floor);
        ``group`` names the route of walks repeated along one, whose scans are held out
        together in the cross-validation of fix errors (by default a walk is its own)."""
        events = trace.radio_events()
        self.n_traces += 1
        if not events or trace.waypoint_t_ms.size == 0:
            return
        name = f"trace {self.n_traces}" if walk is None else walk
        t = np.array([e.t_ms for e in events], dtype=np.int64)
        xy, valid = interpolate_track(trace.waypoint_t_ms, trace.waypoint_xy_m, t)
        for event, point, ok in zip(events, xy.tolist(), valid.tolist(), strict=True):
            if ok and event.readings:
                self.xy_m.append((point[0], point[1]))
                self.floor.append(floor_index)
                self.events.append(event)
                self.walk.append(name)
                self.route.append(group)

    def keyed_scans(self) -> list[list[tuple[str, float]]]:
        """Each scan's readings keyed as map columns."""
        return [
            [(radio_key(_kind(e), r.emitter), r.rssi_dbm) for r in e.readings] for e in self.events
        ]

    def surveyed(self) -> SurveyedScans:
        """The scans as the map builder takes them."""
        return SurveyedScans.of(
            self.xy_m,
            self.floor,
            self.keyed_scans(),
            t_ms=[e.t_ms for e in self.events],
            walk=self.walk,
            route=self.route,
            ages_ms=[[r.age_ms for r in e.readings] for e in self.events],
        )


def _kind(event: WifiEvent | BleEvent) -> str:
    return "wifi" if isinstance(event, WifiEvent) else "ble"


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

    def floor_fields(self, site: IlcSite) -> dict[int, FloorField]:
        """The samples per floor with the floor's extent, as the map builder takes them."""
        return {
            index: FloorField(
                np.concatenate(self.xy_m[index]),
                np.concatenate(self.magnitude_ut[index]),
                (0.0, 0.0, site.floors[index].width_m, site.floors[index].height_m),
            )
            for index in sorted(self.xy_m)
        }


@dataclass(frozen=True)
class TrainingSurvey:
    """What the training maps were built from, as a surveyor would upload it: the labelled
    scans (with their walks and routes), the magnetometer samples for engines that read
    them, and the floor plans (GeoJSON by floor index)."""

    scans: LabelledScans
    field: LabelledField | None = None
    plans: tuple[dict[str, Any] | None, ...] = ()
    traces: tuple[tuple[int, Path], ...] = ()  # (floor index, file) of each training trace
    pressure_walks: tuple[PressureWalk, ...] = ()  # walks with the barometer (map_set)


def parts_for(engines: Collection[str]) -> frozenset[str]:
    """What the map builder must build besides the radio map for these engines: the
    fix-error table always, the rest where an engine reads it."""
    from server.positioning.engines.registry import NEEDS_GRAPHS, get_engine

    parts = {map_set.FIX_ERROR}
    for engine in engines:
        if "mag" in get_engine(engine).uses:
            parts.add(map_set.MAGNETIC)
        if engine in NEEDS_FAI_MAPS:
            parts.add(map_set.FAI)
        if engine in NEEDS_GRAPHS:
            parts.add(map_set.GRAPHS)
    return frozenset(parts)


# engines that read the fingerprinting accuracy indicators' data (``SiteMaps.fai``)
NEEDS_FAI_MAPS = frozenset({"fai_ekf"})


def build_site_maps(
    site: IlcSite,
    train: Iterable[tuple[int, Path]],
    progress: Progress | None = None,
    *,
    parts: Collection[str] = frozenset({map_set.FIX_ERROR}),
) -> tuple[SiteMaps, TrainingSurvey, int]:
    """The site's map set from its training traces (``map_set.build_map_set`` with
    ``parts``); also what it was built from (``TrainingSurvey``) and the number of
    unreadable lines met."""
    labelled = LabelledScans()
    field_samples = LabelledField()
    magnetic = map_set.MAGNETIC in parts
    bad_lines = 0
    train = list(train)
    for done, (floor_index, path) in enumerate(train, start=1):
        trace = read_trace(path, site.floors[floor_index].name)
        bad_lines += trace.bad_lines
        labelled.add_trace(trace, floor_index)
        if magnetic:
            field_samples.add_trace(trace, floor_index)
        if progress:
            progress("maps", done, len(train))
    geojsons = tuple(f.plan for f in site.floors)
    records = SiteRecords(
        site_floors(site),
        labelled.surveyed(),
        geojsons,
        field_samples.floor_fields(site) if magnetic else {},
    )
    maps = map_set.build_map_set(records, parts=parts, version="train")
    survey = TrainingSurvey(labelled, field_samples if magnetic else None, geojsons, tuple(train))
    return maps, survey, bad_lines
