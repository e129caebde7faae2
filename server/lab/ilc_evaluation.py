"""Evaluation on ILC 2.0 traces, recorded data nobody in this project made.

``evaluate_ilc``: per floor, the traces are split by a seeded shuffle of their path ids
into training and test sets (``split``). Radio maps come from the training traces only:
each scan is placed by linear interpolation between the surveyor's waypoints and the scans
are gridded by the same code the survey API uses (``training_maps``:
``gridding.build_radio_map``, cells of ``TRACE_CELL_M``). Each test trace is then replayed
causally through the engine in batches of ``BATCH_MS`` of phone time, as a phone would post
them: its WiFi and BLE scans, and for engines that read raw motion samples its IMU samples
in blocks of ``BATCH_MS`` (``replay.trace_events``). The engine never sees waypoints or the
true floor and searches every floor of the site. The estimate at a waypoint is the last fix
at or before its timestamp (none yet: counted as missing; ``scoring``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from server.datasets.ilc import IlcSite, read_site
from server.datasets.ilc_trace import read_trace
from server.lab.progress import Progress
from server.lab.replay import Replayer, in_process_replayer, trace_events
from server.lab.scoring import PathResult, estimates_at_waypoints, summarize
from server.lab.split import SplitPaths, restrict, split_site
from server.lab.training_maps import (
    build_site_maps,
    site_plans,
    with_fai_maps,
    with_graphs,
)
from server.positioning.engines import NEEDS_GRAPHS, get_engine
from server.positioning.sitemaps import SiteMaps


@dataclass(frozen=True)
class IlcEvaluation:
    site: IlcSite
    maps: SiteMaps
    split: SplitPaths
    paths: tuple[PathResult, ...]
    summary: dict[str, Any]


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
        training_only = restrict(site, split.train)
        split = split_site(training_only, split_seed + 1, train_fraction)
    uses = get_engine(engine).uses
    maps, survey, bad_lines = build_site_maps(site, split.train, progress, magnetic="mag" in uses)
    maps = with_fai_maps(maps, engine)
    if engine in NEEDS_GRAPHS:
        maps = maps if maps.plans else replace(maps, plans=site_plans(site))
        maps = with_graphs(maps, engine, [f.plan for f in site.floors], survey.walks)
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
        radio_error_68_m=maps.fix_error.error_68_m,
        bad_lines=bad_lines,
    )
    return IlcEvaluation(site, maps, split, tuple(results), summary)
