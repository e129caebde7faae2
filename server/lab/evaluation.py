"""Evaluation on recorded data nobody in this project made.

ILC 2.0 (``evaluate_ilc``): per floor, the traces are split by a seeded shuffle of their
path ids into training and test sets. Radio maps come from the training traces only: each
scan is placed by linear interpolation between the surveyor's waypoints and the scans are
gridded by the same code the survey API uses (``gridding.build_radio_map``, cells of
``TRACE_CELL_M``). Each test trace is then replayed causally through the engine in
batches of ``BATCH_MS`` of phone time, as a phone would post them: its WiFi and BLE scans,
and for engines that read raw motion samples its IMU samples in blocks of ``BATCH_MS``
(``trace_events``). The engine never sees waypoints or the true floor and searches every
floor of the site. The estimate at a waypoint is the last fix at or before its timestamp
(none yet: counted as missing).

UJIIndoorLoc-style data (``evaluate_uji``): every training fingerprint is a reference
point (no gridding: the published baselines match against raw fingerprints), floors are
(building, floor) pairs, so the floor choice of WKNN also picks the building.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.datasets.ilc import IlcSite, IlcTrace, read_site, read_trace
from server.datasets.uji import Fingerprints
from server.positioning import fix_error
from server.positioning.engines import get_engine
from server.positioning.engines.base import FloorRef, SiteMaps
from server.positioning.engines.step_ekf import StepEkfParams
from server.positioning.events import (
    BleEvent,
    Event,
    Fix,
    RadioReading,
    StepEvent,
    WifiEvent,
    radio_key,
)
from server.positioning.fingerprint import (
    MISSING_DBM,
    RadioMap,
    in_place_order,
    scan_vector,
    wknn,
)
from server.positioning.fix_error import FixErrorModel
from server.positioning.floorplan import FloorPlan
from server.positioning.floorplan_geojson import plan_from_geojson
from server.positioning.magnetic import MagneticGrid, MagneticMap, sample
from server.positioning.mapping.device_offsets import (
    apply_offsets,
    cell_ids,
    estimate_offsets,
    row_offsets,
    scan_readings,
)
from server.positioning.mapping.fix_calibration import learn_fix_error
from server.positioning.mapping.gridding import build_radio_map
from server.positioning.mapping.labelled import interpolate_track
from server.positioning.mapping.magnetic_gridding import grid_from_samples, known_share
from server.positioning.mapping.matrices import readings_matrix
from server.positioning.metrics import error_report
from server.positioning.step_tracker import TrackerParams
from server.services.traces import walk_steps

# Traces sample the walk every few metres; 1 m cells keep that resolution and merge only
# scans taken at nearly the same spot (the same cell size as surveys).
TRACE_CELL_M = 1.0
# A phone posts about once a second; replay cuts each trace into batches of that span.
BATCH_MS = 1000

# the floor under the fingerprint variance that the engines use
MIN_FIX_VAR_M2 = StepEkfParams().min_fix_var_m2

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class SplitPaths:
    """Trace files per floor index, for training and for testing."""

    train: tuple[tuple[int, Path], ...]
    test: tuple[tuple[int, Path], ...]


def split_site(site: IlcSite, seed: int, train_fraction: float) -> SplitPaths:
    """Seeded split of each floor's traces by path id; at least one on each side when a
    floor has two or more traces."""
    if not 0.0 < train_fraction < 1.0:
        raise ValueError("train_fraction must be between 0 and 1")
    train: list[tuple[int, Path]] = []
    test: list[tuple[int, Path]] = []
    for index, floor in enumerate(site.floors):
        files = sorted(floor.trace_files, key=_path_id)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index,)))
        order = rng.permutation(len(files))
        n_train = round(train_fraction * len(files))
        if len(files) >= 2:
            n_train = min(max(n_train, 1), len(files) - 1)
        train += [(index, files[i]) for i in sorted(order[:n_train].tolist())]
        test += [(index, files[i]) for i in sorted(order[n_train:].tolist())]
    return SplitPaths(tuple(train), tuple(test))


def _restrict(site: IlcSite, paths: Iterable[tuple[int, Path]]) -> IlcSite:
    keep = set(paths)
    floors = tuple(
        replace(f, trace_files=tuple(p for p in f.trace_files if (i, p) in keep))
        for i, f in enumerate(site.floors)
    )
    return replace(site, floors=floors)


def _path_id(path: Path) -> str:
    return path.name.split(".", 1)[0]


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

    def add_trace(self, trace: IlcTrace, floor_index: int, group: int | None = None) -> None:
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

    def add_trace(self, trace: IlcTrace, floor_index: int) -> None:
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


def site_plans(site: IlcSite) -> tuple[FloorPlan | None, ...]:
    """Each floor's plan as walkable space and walls (None where a floor has no plan)."""
    return tuple(plan_from_geojson(f.plan) if f.plan else None for f in site.floors)


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
    for done, (floor_index, path) in enumerate(train, start=1):
        trace = read_trace(path, site.floors[floor_index].name)
        bad_lines += trace.bad_lines
        labelled.add_trace(trace, floor_index)
        if magnetic:
            field_samples.add_trace(trace, floor_index)
        if progress:
            progress("maps", done, len(train))
    radio = in_place_order(labelled.radio_map()) if labelled.events else None
    maps = SiteMaps(
        site_floors(site), radio, version="train", fix_error=learned_fix_error(labelled)
    )
    if not magnetic:
        return maps, TrainingSurvey(labelled, traces=tuple(train)), bad_lines
    maps = replace(maps, plans=site_plans(site), magnetic=field_samples.magnetic_map(site))
    plans = tuple(f.plan for f in site.floors)
    return maps, TrainingSurvey(labelled, field_samples, plans, tuple(train)), bad_lines


PHONE_STEPS = TrackerParams(heading="rotation")
"""How a phone that detects its own steps finds them in a recording (for engines that
read ``step`` events and not raw samples): the project's step tracker with the phone's
rotation-vector heading, as a phone SDK would run it."""


def trace_events(trace: IlcTrace, engine: str) -> list[Event]:
    """What a phone running ``engine`` posts of a trace: its scans and, when the engine
    reads raw motion samples (``"imu"`` in its ``uses``), the IMU blocks too; an engine
    that reads steps but not raw samples gets the steps a phone would detect
    (``PHONE_STEPS``; those with a north-referenced heading). What an engine would
    ignore is left out, so replay stays fast."""
    uses = get_engine(engine).uses
    events = trace.events(imu="imu" in uses, block_ms=BATCH_MS)
    if "step" in uses and "imu" not in uses:
        steps = walk_steps(trace, PHONE_STEPS)
        events += [
            StepEvent(t, length, heading)
            for t, length, heading in zip(
                steps.t_ms.tolist(), steps.length_m.tolist(), steps.north_rad.tolist(), strict=True
            )
            if math.isfinite(heading)
        ]
        events.sort(key=lambda e: e.t_ms)
    return events


def batches(events: Sequence[Event], batch_ms: int = BATCH_MS) -> list[list[Event]]:
    """Cut a time-ordered event list into consecutive spans of ``batch_ms`` phone time."""
    out: list[list[Event]] = []
    start: int | None = None
    for event in events:
        if start is None or event.t_ms >= start + batch_ms:
            out.append([])
            start = event.t_ms
        out[-1].append(event)
    return out


def engine_params(engine: str, overrides: Mapping[str, str] | None = None) -> Any:
    """The engine's default parameters with some scalar ones replaced, the values given
    as text (``{"k": "8"}``), for trying variants on a validation split.

    Raises
    ------
    ValueError
        Naming the parameter, when it does not exist, is not a number or flag, or its
        value does not parse or is refused by the engine.
    """
    params = get_engine(engine).params_type()
    changes: dict[str, Any] = {}
    for name, text in (overrides or {}).items():
        if name.startswith("_") or not hasattr(params, name):
            raise ValueError(f"{engine} has no parameter {name!r}")
        kind = type(getattr(params, name))
        if kind not in (int, float, bool, str):
            raise ValueError(f"parameter {name!r} of {engine} is not a number, flag or word")
        try:
            changes[name] = text.lower() in ("1", "true", "yes") if kind is bool else kind(text)
        except ValueError:
            raise ValueError(f"parameter {name!r}: {text!r} is not a {kind.__name__}") from None
    try:
        return replace(params, **changes)
    except ValueError as e:
        raise ValueError(f"parameters of {engine}: {e}") from None


def replay(
    engine: str, events: Sequence[Event], maps: SiteMaps, seed: int, params: Any = None
) -> list[Fix]:
    """Run an engine over a trace batch by batch, as the service would (with its default
    parameters unless ``params`` is given)."""
    spec = get_engine(engine)
    params = spec.params_type() if params is None else params
    state = spec.initial_state(params)
    fixes: list[Fix] = []
    for seq, batch in enumerate(batches(events), start=1):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(seq,)))
        state, new = spec.run(state, batch, maps, params, rng)
        fixes += new
    return fixes


@dataclass(frozen=True)
class WaypointEstimates:
    """Per waypoint: the truth and the last fix at or before it (NaN when none)."""

    true_xy_m: NDArray[np.float64]
    true_floor: NDArray[np.int64]
    est_xy_m: NDArray[np.float64]
    est_floor: NDArray[np.int64]
    sigma_m: NDArray[np.float64]
    t_ms: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def estimates_at_waypoints(
    trace: IlcTrace, floor_index: int, fixes: Sequence[Fix]
) -> WaypointEstimates:
    n = trace.waypoint_t_ms.size
    est = np.full((n, 2), np.nan)
    est_floor = np.full(n, -1, dtype=np.int64)
    sigma = np.full(n, np.nan)
    if fixes:
        fix_t = np.array([f.t_ms for f in fixes], dtype=np.int64)
        order = np.argsort(fix_t, kind="stable")
        fix_t = fix_t[order]
        # index of the last fix with t <= waypoint t
        idx = np.searchsorted(fix_t, trace.waypoint_t_ms, side="right") - 1
        for row, i in enumerate(idx.tolist()):
            if i < 0:
                continue
            fix = fixes[int(order[i])]
            est[row] = (fix.x_m, fix.y_m)
            est_floor[row] = fix.floor
            sigma[row] = fix.uncertainty_m
    return WaypointEstimates(
        true_xy_m=trace.waypoint_xy_m.astype(np.float64),
        true_floor=np.full(n, floor_index, dtype=np.int64),
        est_xy_m=est,
        est_floor=est_floor,
        sigma_m=sigma,
        t_ms=trace.waypoint_t_ms.astype(np.int64),
    )


@dataclass(frozen=True)
class PathResult:
    path_id: str
    floor_index: int
    estimates: WaypointEstimates
    fixes: tuple[Fix, ...]


@dataclass(frozen=True)
class IlcEvaluation:
    site: IlcSite
    maps: SiteMaps
    split: SplitPaths
    paths: tuple[PathResult, ...]
    summary: dict[str, Any]


def _stack(paths: Sequence[PathResult]) -> WaypointEstimates:
    def cat(name: str, dtype: Any, shape: tuple[int, ...]) -> Any:
        parts = [getattr(p.estimates, name) for p in paths]
        return np.concatenate(parts) if parts else np.zeros(shape, dtype=dtype)

    return WaypointEstimates(
        true_xy_m=cat("true_xy_m", np.float64, (0, 2)),
        true_floor=cat("true_floor", np.int64, (0,)),
        est_xy_m=cat("est_xy_m", np.float64, (0, 2)),
        est_floor=cat("est_floor", np.int64, (0,)),
        sigma_m=cat("sigma_m", np.float64, (0,)),
    )


def _report(paths: Sequence[PathResult]) -> dict[str, Any]:
    est = _stack(paths)
    report = error_report(
        est.est_xy_m, est.true_xy_m, est.est_floor, est.true_floor, sigma_m=est.sigma_m
    )
    return report.to_dict()


def summarize(
    paths: Sequence[PathResult],
    *,
    floor_names: Sequence[str] | None = None,
    maps: SiteMaps | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The extra fields and the error report over all paths; with ``floor_names`` (by
    floor index) also ``per_floor``: per floor name the error report over the paths walked
    on that floor and their number (``test_paths``), and, when ``maps`` carry a magnetic
    map, the floor's ``magnetic_coverage`` (share of walkable cells with a known field) and
    ``magnetic_at_waypoints`` (share of the test waypoints where the map gives a field)."""
    summary = {**extra, **_report(paths)}
    if floor_names is not None:
        per_floor: dict[str, dict[str, Any]] = {}
        for index, name in enumerate(floor_names):
            on_floor = [p for p in paths if p.floor_index == index]
            figures = {**_report(on_floor), "test_paths": len(on_floor)}
            if maps is not None and maps.magnetic is not None:
                grids, plans = maps.magnetic.grids, maps.plans
                grid = grids[index] if index < len(grids) else None
                figures["magnetic_coverage"] = known_share(
                    grid, plans[index] if index < len(plans) else None
                )
                truth = _stack(on_floor).true_xy_m
                figures["magnetic_at_waypoints"] = (
                    float(np.isfinite(sample(grid, truth)).mean())
                    if grid is not None and len(truth)
                    else None
                )
            per_floor[name] = figures
        summary["per_floor"] = per_floor
    return summary


# Replays test traces (a list of time-ordered event lists) through an engine, given the
# training maps and what they were built from (``TrainingSurvey``); one fix list per trace.
Replayer = Callable[[str, SiteMaps, TrainingSurvey, list[list[Event]]], list[list[Fix]]]


def in_process_replayer(
    seed: int, progress: Progress | None = None, params: Any = None
) -> Replayer:
    def run(
        engine: str, maps: SiteMaps, _survey: TrainingSurvey, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        out = []
        for done, events in enumerate(traces, start=1):
            out.append(replay(engine, events, maps, seed=seed, params=params))
            if progress:
                progress("replay", done, len(traces))
        return out

    return run


def evaluate_ilc(
    site_dir: Path,
    engine: str,
    *,
    split_seed: int = 0,
    train_fraction: float = 0.8,
    progress: Progress | None = None,
    replayer: Replayer | None = None,
    validation: bool = False,
) -> IlcEvaluation:
    """Build maps from the training traces and score the engine on the test traces; with
    ``validation`` the test traces are left out entirely and the training traces are split
    again (seed + 1) into map and validation traces, for choosing parameters."""
    get_engine(engine)  # fail early on an unknown engine name
    site = read_site(site_dir)
    split = split_site(site, split_seed, train_fraction)
    if validation:
        training_only = _restrict(site, split.train)
        split = split_site(training_only, split_seed + 1, train_fraction)
    uses = get_engine(engine).uses
    maps, survey, bad_lines = build_site_maps(site, split.train, progress, magnetic="mag" in uses)
    traces = []
    for done, (floor_index, path) in enumerate(split.test, start=1):
        trace = read_trace(path, site.floors[floor_index].name)
        bad_lines += trace.bad_lines
        traces.append((floor_index, trace))
        if progress:
            progress("read test traces", done, len(split.test))
    replayer = replayer or in_process_replayer(split_seed, progress)
    fixes = replayer(engine, maps, survey, [trace_events(t, engine) for _, t in traces])
    results = [
        PathResult(
            trace.path_id,
            floor_index,
            estimates_at_waypoints(trace, floor_index, path_fixes),
            tuple(path_fixes),
        )
        for (floor_index, trace), path_fixes in zip(traces, fixes, strict=True)
    ]
    summary = summarize(
        results,
        floor_names=[f.name for f in site.floors],
        maps=maps,
        engine=engine,
        dataset=f"ilc:{site.name}" + (":validation" if validation else ""),
        split_seed=split_seed,
        train_fraction=train_fraction,
        train_paths=len(split.train),
        test_paths=len(split.test),
        floors=len(site.floors),
        reference_points=int(maps.radio.rp_xy.shape[0]) if maps.radio else 0,
        bad_lines=bad_lines,
    )
    return IlcEvaluation(site, maps, split, tuple(results), summary)


# ---------------------------------------------------------------- UJIIndoorLoc-style data


def fingerprint_map(train: Fingerprints) -> tuple[RadioMap, tuple[FloorRef, ...]]:
    """Every training fingerprint as a reference point; floors are (building, floor)."""
    pairs = sorted({(int(b), int(f)) for b, f in zip(train.building, train.floor, strict=True)})
    index = {p: i for i, p in enumerate(pairs)}
    rp_floor = np.array(
        [index[(int(b), int(f))] for b, f in zip(train.building, train.floor, strict=True)],
        dtype=np.int32,
    )
    heard = ~np.isnan(train.rssi_dbm)
    mean = np.where(heard, np.maximum(train.rssi_dbm, MISSING_DBM), MISSING_DBM)
    radio = RadioMap(
        rp_xy=train.xy_m.astype(np.float32),
        rp_floor=rp_floor,
        mean_dbm=mean.astype(np.float32),
        var_db2=np.where(heard, 16.0, 0.0).astype(np.float32),
        count=heard.astype(np.int32),
        emitters=tuple(radio_key("wifi", e) for e in train.emitters),
    )
    floors = tuple(FloorRef(str(b), f"{b}:{f}", f) for b, f in pairs)
    return radio, floors


# Co-location for per-phone offsets: UJIIndoorLoc was recorded at 933 fixed spots (in rooms
# and in front of doors; 727 of them by two or more phones), so cells need only gather the
# readings of one spot: 1 m cells of the dataset's Web-Mercator metres (0.77 m on the
# ground), per (building, floor). Chosen on the training set alone: its spots (distinct
# building, floor, position) shuffled by default_rng(seed), the first fifth held out as
# test rows, seeds 0-2; WKNN k = 4 EvAAL 7.87 / 8.82 / 8.75 m with 1 m cells, 7.87 / 8.87 /
# 8.84 m with 5 m cells, 7.94 / 8.94 / 8.99 m without offsets.
UJI_OFFSET_CELL_M = 1.0


def _phone_offsets(
    train: Fingerprints, test: Fingerprints
) -> tuple[Fingerprints, Fingerprints, dict[str, Any]]:
    """Per-phone RSS offsets from the training fingerprints (``mapping.device_offsets``;
    cells of ``UJI_OFFSET_CELL_M`` per (building, floor), emitters the WAP columns), taken
    off the training and test rows of phones that have one; and what to report of them."""
    cell = cell_ids(train.xy_m, np.column_stack([train.building, train.floor]), UJI_OFFSET_CELL_M)
    offsets = estimate_offsets(*scan_readings(train.rssi_dbm, cell, train.phone_id.astype(str)))
    train_offset = row_offsets(train.phone_id.astype(str), offsets)
    test_offset = row_offsets(test.phone_id.astype(str), offsets)
    summary = {
        "device_offset_cell_m": UJI_OFFSET_CELL_M,
        "phones_with_offset": len(offsets),
        "train_rows_corrected": int(np.isfinite(train_offset).sum()),
        "test_rows_known_phone": int(np.isin(test.phone_id, train.phone_id).sum()),
        "test_rows_corrected": int(np.isfinite(test_offset).sum()),
        "device_offsets": {
            phone: {"offset_db": o.offset_db, "n_pairs": o.n_pairs, "std_db": o.std_db}
            for phone, o in sorted(offsets.items(), key=lambda item: int(item[0]))
        },
    }
    return (
        replace(train, rssi_dbm=apply_offsets(train.rssi_dbm, train_offset[:, None])),
        replace(test, rssi_dbm=apply_offsets(test.rssi_dbm, test_offset[:, None])),
        summary,
    )


def evaluate_uji(
    train: Fingerprints,
    test: Fingerprints,
    method: str,
    *,
    k: int = 4,
    progress: Progress | None = None,
    device_offsets: bool = False,
) -> dict[str, Any]:
    """Score a fingerprint method on test fingerprints with every training fingerprint a
    reference point. With ``device_offsets``, per-phone RSS offsets are estimated on the
    training set only (``_phone_offsets``) and taken off the training readings before
    the map is built and off the test readings of phones that have one (other phones are
    not corrected); the summary then lists them (``device_offsets`` by phone id) and
    counts the rows corrected."""
    if method != "wknn":
        raise ValueError(f"unknown method {method!r}; known methods: wknn")
    extra: dict[str, Any] = {}
    if device_offsets:
        train, test, extra = _phone_offsets(train, test)
    radio, floors = fingerprint_map(train)
    n = test.rssi_dbm.shape[0]
    est = np.full((n, 2), np.nan)
    est_floor = np.full(n, -1, dtype=np.int64)
    est_building = np.full(n, -1, dtype=np.int64)
    sigma = np.full(n, np.nan)
    for row in range(n):
        heard = ~np.isnan(test.rssi_dbm[row])
        readings = [
            RadioReading(test.emitters[j], float(test.rssi_dbm[row, j]))
            for j in np.flatnonzero(heard).tolist()
        ]
        fix = wknn(radio, scan_vector(radio, readings, "wifi"), k=k)
        if fix is not None:
            est[row] = (fix.x_m, fix.y_m)
            est_floor[row] = floors[fix.floor].level
            est_building[row] = int(floors[fix.floor].building_id)
            sigma[row] = np.sqrt(max(fix.var_m2, MIN_FIX_VAR_M2))
        if progress and (row % 50 == 0 or row == n - 1):
            progress("locate", row + 1, n)
    report = error_report(
        est,
        test.xy_m,
        est_floor,
        test.floor,
        sigma_m=sigma,
        est_building=est_building,
        true_building=test.building,
    )
    return {
        "method": method,
        "k": k,
        "dataset": "uji",
        "train_points": int(train.rssi_dbm.shape[0]),
        "device_offsets_applied": device_offsets,
        **extra,
        **report.to_dict(),
    }


POINT_COLUMNS = (
    "path",
    "t_ms",
    "true_x_m",
    "true_y_m",
    "true_floor",
    "est_x_m",
    "est_y_m",
    "est_floor",
    "sigma_m",
    "error_m",
)


def write_points(paths: Sequence[PathResult], out: Path) -> int:
    """Every scored point as a CSV row (``POINT_COLUMNS``; floors as indices, empty
    estimate fields where no fix came before the point), so that anyone can re-plot or
    re-score; returns the number of rows."""
    rows = 0
    with out.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(POINT_COLUMNS)
        for p in paths:
            e = p.estimates
            times = e.t_ms if e.t_ms.size == e.true_floor.size else np.full(e.true_floor.size, -1)
            for i in range(e.true_floor.size):
                known = bool(np.isfinite(e.est_xy_m[i]).all())
                error = float(np.hypot(*(e.est_xy_m[i] - e.true_xy_m[i]))) if known else None
                writer.writerow(
                    [
                        p.path_id,
                        int(times[i]),
                        f"{e.true_xy_m[i, 0]:.3f}",
                        f"{e.true_xy_m[i, 1]:.3f}",
                        int(e.true_floor[i]),
                        f"{e.est_xy_m[i, 0]:.3f}" if known else "",
                        f"{e.est_xy_m[i, 1]:.3f}" if known else "",
                        int(e.est_floor[i]) if known else "",
                        f"{e.sigma_m[i]:.3f}" if known else "",
                        f"{error:.3f}" if error is not None else "",
                    ]
                )
                rows += 1
    return rows


def errors_m(evaluation: IlcEvaluation) -> list[float]:
    est = _stack(evaluation.paths)
    ok = ~np.isnan(est.est_xy_m[:, 0])
    errors: list[float] = np.hypot(*(est.est_xy_m[ok] - est.true_xy_m[ok]).T).tolist()
    return errors


def write_ilc_plots(evaluations: Sequence[IlcEvaluation], out_dir: Path) -> list[Path]:
    """The error CDF of every engine on one figure, per engine and test path the floor
    plan with the truth and the estimated track, and, when an engine read a magnetic map,
    per floor the map on the floor plan (``magnetic_<floor>.png``; the maps come from the
    same training traces for every engine, so once)."""
    from server.lab.plots import plot_error_cdf, plot_magnetic_grid, plot_track

    out_dir.mkdir(parents=True, exist_ok=True)
    site = evaluations[0].site.name
    written = [
        plot_error_cdf(
            {e.summary["engine"]: errors_m(e) for e in evaluations},
            out_dir / "error_cdf.png",
            title=f"ILC {site}: horizontal error at waypoints",
        )
    ]
    for evaluation in evaluations:
        engine = evaluation.summary["engine"]
        for path in evaluation.paths:
            floor = evaluation.site.floors[path.floor_index]
            fixes = path.fixes
            est = np.array([(f.x_m, f.y_m) for f in fixes], dtype=np.float64).reshape(-1, 2)
            floor_ok = np.array([f.floor == path.floor_index for f in fixes], dtype=bool)
            written.append(
                plot_track(
                    out_dir / engine / f"{floor.name}_{path.path_id}.png",
                    title=f"{engine} · {floor.name} · {path.path_id}",
                    plan=floor.plan,
                    truth_xy_m=path.estimates.true_xy_m,
                    est_xy_m=est,
                    est_floor_ok=floor_ok,
                    waypoint_xy_m=path.estimates.true_xy_m,
                    sigma_m=np.array([f.uncertainty_m for f in fixes]),
                )
            )
    magnetic = next((e for e in evaluations if e.maps.magnetic is not None), None)
    if magnetic is not None and magnetic.maps.magnetic is not None:
        plans = magnetic.maps.plans
        for index, (floor, grid) in enumerate(
            zip(magnetic.site.floors, magnetic.maps.magnetic.grids, strict=False)
        ):
            if grid is None:
                continue
            plan = plans[index] if index < len(plans) else None
            coverage = known_share(grid, plan)
            known = "no walkable cell" if coverage is None else f"{coverage:.0%} of walkable cells"
            written.append(
                plot_magnetic_grid(
                    out_dir / f"magnetic_{floor.name}.png",
                    title=f"{magnetic.site.name} · {floor.name}: magnetic map, {known} known",
                    plan=floor.plan,
                    grid=grid,
                )
            )
    return written
