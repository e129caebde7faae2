"""The one map builder: what a site has in, the whole map set every engine reads out.

What a site has (``SiteRecords``): its floors, the scans surveyed on them (each at its
position and time, on a walk and a route, ``SurveyedScans``), the magnetometer samples
placed on each floor, and each floor's plan (GeoJSON). What comes out is a ``SiteMaps``
(with the plans parsed and the anchors they mark):

1. **radio map**: the scans gridded into reference points (``gridding.build_radio_map``,
   cells of ``CELL_M``) and put in place order, unless the caller brings the map (the
   service folds each survey into its current version with the same gridding,
   ``gridding.fold_radio_maps``, so that a version is written on the request);
2. **fix-error table** (``fix_error``): radio fixes of held-out routes located on maps
   gridded from the other routes (``fix_calibration.learn_fix_error``): a route's scans
   never locate themselves, and walks repeated along one route are held out together;
3. **FAI maps** (``fai_maps.build_fai_maps``, ``papers/000_*`` eq 15-18 and 23);
4. **magnetic grids**: per floor over its extent (``magnetic_gridding.grid_from_samples``);
5. **floor graphs** (``navigation_graph.site_graphs``): from each floor's plan, else over its
   reference points, with the chain's moves learned from the walks (``papers/004_*``
   eq 15): each walk is its scans' positions in time order, cut where it changes floor.

The steps are chosen by ``parts``, so a caller builds only what its engines read; the
result depends only on the records (and ``seed``, which deals routes into folds), so the
lab and the service get equal maps from equal records.
"""

from __future__ import annotations

from collections.abc import Collection, Hashable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.magnetic.field_grid import MagneticGrid, MagneticMap
from server.positioning.mapping.fai_maps import build_fai_maps
from server.positioning.mapping.fix_calibration import learn_fix_error
from server.positioning.mapping.gridding import build_radio_map
from server.positioning.mapping.magnetic_gridding import grid_from_samples
from server.positioning.mapping.matrices import readings_matrix
from server.positioning.motion import barometer
from server.positioning.plan.anchors import anchors_from_plan
from server.positioning.plan.floor_plan import FloorPlan
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.navigation_graph import site_graphs
from server.positioning.radio import fix_error
from server.positioning.radio.accuracy_indicators import FaiMaps, FaiParams, spreads
from server.positioning.radio.fingerprints import RadioMap, in_place_order
from server.positioning.radio.scan_matching import ScanMap, build_scan_map

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

CELL_M = 1.0
"""Reference-point cell side: walks sample every metre or two, surveys as dense."""

FIX_ERROR = "fix_error"
FAI = "fai"
GRAPHS = "graphs"
MAGNETIC = "magnetic"
PARTS = frozenset({FIX_ERROR, FAI, GRAPHS, MAGNETIC})
"""What ``build_map_set`` can build besides the radio map."""

KeyedScan = Sequence[tuple[str, float]]  # (column key "wifi:<bssid>" | "ble:<id>", rssi_dbm)


def _first_seen(labels: Sequence[Hashable | None]) -> IntArray:
    """Each label's index in order of first appearance; -1 for None."""
    index: dict[Hashable, int] = {}
    out = np.full(len(labels), -1, dtype=np.int64)
    for i, label in enumerate(labels):
        if label is not None:
            out[i] = index.setdefault(label, len(index))
    return out


@dataclass(frozen=True)
class SurveyedScans:
    """Scans at known positions, in the order they were recorded or stored.

    Attributes
    ----------
    xy_m : ndarray, shape (n, 2)
    floor : ndarray, shape (n,), int
        Floor index into the site's floors.
    t_ms : ndarray, shape (n,), int
        Time of each scan (orders a walk's scans; 0 where unknown).
    walk : ndarray, shape (n,), int
        Walk of each scan, numbered in order of first appearance; -1 for a point surveyed
        on its own (it is its own fold group and in no walk).
    route : ndarray, shape (n,), int
        Fold group of each scan: walks along one route share one (order of first
        appearance); -1 where the scan's walk (or the scan itself) is its own group.
    readings : tuple of n sequences of (column key, rssi_dbm)
    ages_ms : tuple of n sequences of float or None
        Each reading's age (parallel to ``readings``); empty: every reading fresh.
    """

    xy_m: FloatArray
    floor: IntArray
    t_ms: IntArray
    walk: IntArray
    route: IntArray
    readings: tuple[KeyedScan, ...]
    ages_ms: tuple[Sequence[float | None], ...] = ()

    @classmethod
    def of(
        cls,
        xy_m: Sequence[tuple[float, float]] | FloatArray,
        floor: Sequence[int] | IntArray,
        readings: Sequence[KeyedScan],
        *,
        t_ms: Sequence[int | None] | None = None,
        walk: Sequence[Hashable | None] | None = None,
        route: Sequence[Hashable | None] | None = None,
        ages_ms: Sequence[Sequence[float | None]] | None = None,
    ) -> SurveyedScans:
        """Scans labelled by anything hashable (walk and route names, ids); the labels
        are numbered in order of first appearance, so equal records in equal order give
        equal scans whatever the labels were."""
        n = len(readings)
        none: list[Hashable | None] = [None] * n
        times = [0 if t is None else int(t) for t in (t_ms if t_ms is not None else [0] * n)]
        return cls(
            np.asarray(xy_m, dtype=np.float64).reshape(-1, 2),
            np.asarray(floor, dtype=np.int64).reshape(-1),
            np.asarray(times, dtype=np.int64),
            _first_seen(list(walk) if walk is not None else none),
            _first_seen(list(route) if route is not None else none),
            tuple(tuple(r) for r in readings),
            tuple(tuple(a) for a in ages_ms) if ages_ms is not None else (),
        )

    def __len__(self) -> int:
        return len(self.readings)

    def groups(self) -> IntArray:
        """The fold group of each scan: its route, else its walk, else the scan alone
        (distinct numbers for distinct groups)."""
        n_routes = int(self.route.max(initial=-1)) + 1
        n_walks = int(self.walk.max(initial=-1)) + 1
        alone = n_routes + n_walks + np.arange(len(self), dtype=np.int64)
        return np.where(
            self.route >= 0, self.route, np.where(self.walk >= 0, n_routes + self.walk, alone)
        )

    def walks(self) -> dict[int, list[FloatArray]]:
        """Each walk's positions in time order, cut at its floor changes, by floor index
        (walks in order of first appearance)."""
        out: dict[int, list[FloatArray]] = {}
        for w in range(int(self.walk.max(initial=-1)) + 1):
            rows = np.flatnonzero(self.walk == w)
            rows = rows[np.argsort(self.t_ms[rows], kind="stable")]
            floors = self.floor[rows]
            starts = np.flatnonzero(np.r_[True, floors[1:] != floors[:-1]])
            ends = np.r_[starts[1:], rows.size]
            for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
                out.setdefault(int(floors[start]), []).append(self.xy_m[rows[start:end]])
        return out


@dataclass(frozen=True)
class FloorField:
    """Magnetometer samples placed on one floor, and the extent its grid covers."""

    xy_m: FloatArray  # (n, 2)
    magnitude_ut: FloatArray  # (n,)
    extent: tuple[float, float, float, float]  # x0, y0, x1, y1


@dataclass(frozen=True)
class SiteRecords:
    """What a site has that maps are built from (module docstring)."""

    floors: tuple[FloorRef, ...]
    scans: SurveyedScans
    plans: tuple[Mapping[str, Any] | None, ...] = ()  # GeoJSON per floor index
    field: Mapping[int, FloorField] = field(default_factory=dict)  # per floor index
    # walks with the barometer on: ([t_ms, hPa] rows, waypoint times, waypoint levels)
    pressure_walks: tuple[barometer.PressureWalk, ...] = ()


def parse_plans(geojsons: Sequence[Mapping[str, Any] | None]) -> tuple[FloorPlan | None, ...]:
    """Each floor's walkable space and walls; None without a plan or where the plan has
    no usable walkable area."""
    plans: list[FloorPlan | None] = []
    for geojson in geojsons:
        try:
            plans.append(plan_from_geojson(geojson) if geojson else None)
        except ValueError:
            plans.append(None)
    return tuple(plans)


def grid_scans(scans: SurveyedScans, cell_m: float = CELL_M) -> RadioMap | None:
    """The scans gridded into a radio map in place order; None without scans."""
    if not len(scans):
        return None
    emitters, rssi = readings_matrix(scans.readings)
    return in_place_order(build_radio_map(scans.xy_m, scans.floor, rssi, emitters, cell_m=cell_m))


def scan_map(scans: SurveyedScans) -> ScanMap | None:
    """The surveyed scans as the matcher reads them (``scan_matching``); None without."""
    if not len(scans):
        return None
    return build_scan_map(
        scans.xy_m, scans.floor, scans.readings, ages_ms=scans.ages_ms or None, walk=scans.walk
    )


def learned_fix_error(scans: SurveyedScans, seed: int = 0) -> fix_error.FixErrorModel:
    """The fix-error table by route-wise cross-validation (module docstring, step 2);
    the default without scans."""
    if not len(scans):
        return fix_error.DEFAULT
    return learn_fix_error(
        scans.xy_m,
        scans.floor,
        scans.groups(),
        scans.readings,
        np.random.default_rng(seed),
        ages_ms=scans.ages_ms or None,
        walk=scans.walk,
    )


def magnetic_map(
    n_floors: int, fields: Mapping[int, FloorField], version: str
) -> MagneticMap | None:
    """One grid per floor that has samples (``magnetic.CELL_M`` cells over its extent)."""
    grids: list[MagneticGrid | None] = [None] * n_floors
    for index, samples in fields.items():
        grids[index] = grid_from_samples(samples.xy_m, samples.magnitude_ut, extent=samples.extent)
    return MagneticMap(tuple(grids), version) if any(g is not None for g in grids) else None


def most_learned(tables: Sequence[fix_error.FixErrorModel]) -> fix_error.FixErrorModel:
    """Of several buildings' fix-error tables, the one learned from the most fixes (the
    default without any): a site's map set holds one."""
    return max(
        tables, key=lambda t: sum(sum(c) for c in t.counts.values()), default=fix_error.DEFAULT
    )


def merged_fai(
    radio: RadioMap,
    parts: Sequence[tuple[Sequence[str], FaiMaps]],
    dsf_m: FloatArray | None = None,
) -> FaiMaps | None:
    """A site's FAI maps from its buildings' (each with the column keys its arrays
    follow): every emitter's fit by its key in ``radio``'s column order (NaN where none
    was fitted), and the DSF given (a one-building site's, as its build made it on the
    same map) or computed over ``radio`` (``accuracy_indicators.spreads``); None without any fit."""
    if not any(len(keys) for keys, _ in parts):
        return None
    fits: dict[str, tuple[FloatArray, float, float]] = {}
    for keys, fai in parts:
        for j, key in enumerate(keys):
            fits[key] = (fai.emitter_xy[j], float(fai.p0_dbm[j]), float(fai.exponent[j]))
    nan = (np.full(2, np.nan), np.nan, np.nan)
    rows = [fits.get(key, nan) for key in radio.emitters]
    params = FaiParams()
    return FaiMaps(
        np.array([r[0] for r in rows], dtype=np.float64).reshape(-1, 2),
        np.array([r[1] for r in rows], dtype=np.float64),
        np.array([r[2] for r in rows], dtype=np.float64),
        dsf_m if dsf_m is not None else spreads(radio, params.kappa_d, params.min_sd_db),
    )


def build_map_set(
    records: SiteRecords,
    *,
    parts: Collection[str] = PARTS,
    radio: RadioMap | None = None,
    plans: tuple[FloorPlan | None, ...] | None = None,
    version: str = "",
    seed: int = 0,
) -> SiteMaps:
    """The map set of a site from its records (module docstring).

    Parameters
    ----------
    records : SiteRecords
    parts : collection of str
        Which of ``PARTS`` to build besides the radio map (all by default).
    radio : RadioMap, optional
        The site's radio map when the caller has it (in place order); gridded from the
        scans otherwise.
    plans : tuple, optional
        The records' plans already parsed (``parse_plans``), when the caller has them.
    version : str
        The map set's version.
    seed : int
        Deals routes into the cross-validation's folds.
    """
    unknown = set(parts) - PARTS
    if unknown:
        raise ValueError(f"unknown map parts: {sorted(unknown)}")
    n = len(records.floors)
    radio = radio if radio is not None else grid_scans(records.scans)
    plans = plans if plans is not None else parse_plans(records.plans)
    anchors = tuple(a for i, p in enumerate(records.plans) for a in anchors_from_plan(p, i))
    maps = SiteMaps(
        records.floors,
        radio,
        version=version,
        anchors=anchors,
        plans=plans,
        scans=scan_map(records.scans),
        floor_spacing_hpa=barometer.floor_spacing(records.pressure_walks),
    )
    if FIX_ERROR in parts:
        maps = replace(maps, fix_error=learned_fix_error(records.scans, seed))
    if FAI in parts and radio is not None:
        maps = replace(maps, fai=build_fai_maps(radio, FaiParams()))
    if MAGNETIC in parts:
        maps = replace(maps, magnetic=magnetic_map(n, records.field, version))
    if GRAPHS in parts:
        graphs = site_graphs(plans, records.plans, radio, n, records.scans.walks())
        maps = replace(maps, graphs=graphs)
    return maps
