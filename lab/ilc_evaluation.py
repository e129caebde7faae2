"""Evaluation on ILC 2.0 traces, recorded data nobody in this project made.

``evaluate_ilc``: per floor, the traces are split by a seeded shuffle of their path ids
into training and test sets (``split``). Maps come from the training traces only:
each scan is placed by linear interpolation between the surveyor's waypoints and the site's
records go to the one map builder the service's worker calls too (``training_maps``,
``positioning.mapping.map_set``), once for every engine of a run (``prepare_ilc``).
Each test trace is then replayed
causally through the engine in batches of ``BATCH_MS`` of phone time, as a phone would post
them: its WiFi and BLE scans, and for engines that read raw motion samples its IMU samples
in blocks of ``BATCH_MS`` (``replay.trace_events``). The engine never sees waypoints or the
true floor and searches every floor of the site. The estimate at a waypoint is the last fix
at or before its timestamp (none yet: counted as missing; ``scoring``).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lab.datasets.ilc import IlcSite, read_site
from lab.progress import Progress
from lab.replay import Replayer, in_process_replayer, trace_events
from lab.scoring import PathResult, estimates_at_waypoints, summarize
from lab.split import SplitPaths, restrict, split_site
from lab.training_maps import TrainingSurvey, build_site_maps, parts_for
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model.walk import Walk
from server.storage.ilc_trace_format import read_trace


@dataclass(frozen=True)
class IlcEvaluation:
    site: IlcSite
    maps: SiteMaps
    split: SplitPaths
    paths: tuple[PathResult, ...]
    summary: dict[str, Any]


@dataclass(frozen=True)
class IlcSetup:
    """What every engine of one evaluation shares: the site, its split, the map set built
    once for all of them (``training_maps.parts_for``) and the test traces read once."""

    site: IlcSite
    split: SplitPaths
    maps: SiteMaps
    survey: TrainingSurvey
    traces: tuple[tuple[int, Walk], ...]
    bad_lines: int
    validation: bool
    split_seed: int
    train_fraction: float
    parts: frozenset[str]


def prepare_ilc(
    site_dir: Path,
    engines: Collection[str],
    *,
    split_seed: int = 0,
    train_fraction: float = 0.8,
    progress: Progress | None = None,
    validation: bool = False,
) -> IlcSetup:
    """Split the site, build the maps every one of ``engines`` reads from the training
    traces, and read the test traces; with ``validation`` the test traces are left out
    entirely and the training traces are split again (seed + 1) into map and validation
    traces, for choosing parameters."""
    for engine in engines:
        get_engine(engine)  # fail early on an unknown engine name
    site = read_site(site_dir)
    split = split_site(site, split_seed, train_fraction)
    if validation:
        training_only = restrict(site, split.train)
        split = split_site(training_only, split_seed + 1, train_fraction)
    parts = parts_for(engines)
    maps, survey, bad_lines = build_site_maps(site, split.train, progress, parts=parts)
    traces = []
    for done, (floor_index, path) in enumerate(split.test, start=1):
        trace = read_trace(path, site.floors[floor_index].name)
        bad_lines += trace.bad_lines
        traces.append((floor_index, trace))
        if progress:
            progress("read test traces", done, len(split.test))
    return IlcSetup(
        site,
        split,
        maps,
        survey,
        tuple(traces),
        bad_lines,
        validation,
        split_seed,
        train_fraction,
        parts,
    )


def evaluate_ilc(
    site_dir: Path,
    engine: str,
    *,
    split_seed: int = 0,
    train_fraction: float = 0.8,
    progress: Progress | None = None,
    replayer: Replayer | None = None,
    validation: bool = False,
    setup: IlcSetup | None = None,
) -> IlcEvaluation:
    """Build maps from the training traces and score the engine on the test traces
    (``prepare_ilc``; pass its ``setup`` to share the maps between engines: its split,
    seed and validation choice are then the run's, the arguments here are not read)."""
    if setup is None:
        setup = prepare_ilc(
            site_dir,
            [engine],
            split_seed=split_seed,
            train_fraction=train_fraction,
            progress=progress,
            validation=validation,
        )
    get_engine(engine)
    missing = parts_for([engine]) - setup.parts
    if missing:
        raise ValueError(f"the setup's maps were built without {sorted(missing)} for {engine}")
    site, split, maps, traces = setup.site, setup.split, setup.maps, setup.traces
    replayer = replayer or in_process_replayer(setup.split_seed, progress)
    fixes = replayer(engine, maps, setup.survey, [trace_events(t, engine) for _, t in traces])
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
        dataset=f"ilc:{site.name}" + (":validation" if setup.validation else ""),
        split_seed=setup.split_seed,
        train_fraction=setup.train_fraction,
        train_paths=len(split.train),
        test_paths=len(split.test),
        floors=len(site.floors),
        reference_points=int(maps.radio.rp_xy.shape[0]) if maps.radio else 0,
        radio_error_68_m=maps.fix_error.error_68_m,
        bad_lines=setup.bad_lines,
    )
    return IlcEvaluation(site, maps, split, tuple(results), summary)
