"""Evaluation on the IPIN 2023 Track 3 logs (``lab.datasets.ipin``): leave one trial out.

For each trial, the maps come from every repetition of the other trials: each scan and,
for engines that read the magnetometer (``"mag"`` in their ``uses``), each magnetometer
sample is placed by linear interpolation in time between the POSI lines of its log (the
walkers walked straight between landmarks), only between consecutive POSI lines on one
floor, and gridded per floor as the ILC evaluation does (``training_maps.LabelledScans``,
``training_maps.LabelledField``; there are no floor plans). Each repetition of the left-out
trial is then replayed causally through the engine in the ILC evaluation's batches
(``replay.trace_events``, ``replay.replay``); the engine never sees POSI lines or
the true floor and searches every floor of the venue. The estimate at a POSI line is the
last fix at or before its time (none yet: counted as missing), its true floor the POSI
floor's index in the venue's floor list.

The summary holds the usual error report (``positioning.model.error_metrics.error_report``) over all
POSI lines, ``ipin_score_m`` (``error_metrics.ipin_score``: P75 of the horizontal
error plus 15 m per floor off), ``per_floor`` and ``per_log`` breakdowns and, per left-out
trial, what its maps were built from (``folds``). With ``validation`` only repetitions 01
and 03 of every trial are read at all, for the maps and for scoring: for choosing
parameters without looking at repetitions 02 and 04. Repetitions 01-02 were recorded with
one phone (a Galaxy A5, SM-A520F) and 03-04 with another (a Galaxy S7, SM-G930F), so the
validation split holds one repetition of each: a split of one phone hides what a second
one does to the errors (the S7's repetitions err more on the A5's maps).
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lab.datasets.ipin import IpinVenue, read_venue
from lab.datasets.ipin_log import IpinLog, read_log
from lab.engine_params import engine_params
from lab.progress import Progress
from lab.replay import Replayer, in_process_replayer, trace_events
from lab.scoring import PathResult, estimates_at_waypoints, summarize
from lab.training_maps import (
    LabelledField,
    LabelledScans,
    TrainingSurvey,
    parts_for,
    site_floors,
)
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.mapping.map_set import MAGNETIC, SiteRecords, build_map_set
from server.positioning.model.error_metrics import ipin_score
from server.positioning.model.events import Fix
from server.positioning.model.walk import Walk

VALIDATION_REPETITIONS = frozenset({1, 3})
"""Repetitions read with ``validation``."""

IPIN_FLOOR_PENALTY_M = 15.0
"""Metres the IPIN score adds per floor of difference."""


@dataclass(frozen=True)
class IpinEvaluation:
    """What ``evaluate_ipin`` read and found: one result per scored log (in log order)."""

    venue: IpinVenue
    paths: tuple[PathResult, ...]
    summary: dict[str, Any]


def floor_parts(trace: Walk, venue: IpinVenue) -> Iterator[tuple[int, Walk]]:
    """The trace cut at its floor changes: per maximal run of consecutive waypoints on one
    floor of the venue, that floor's index and the trace with only those waypoints (what
    lies between two waypoints on different floors, the stairs, is then in no part).
    Waypoints on a floor the venue does not have are in no part."""
    levels = trace.waypoint_floor
    if levels.size != trace.waypoint_t_ms.size:  # no per-waypoint floors: all on trace.floor
        index = venue.floor_index(int(trace.floor)) if trace.floor.lstrip("-").isdigit() else -1
        if index >= 0:
            yield index, trace
        return
    indices = np.array([venue.floor_index(int(v)) for v in levels.tolist()], dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, indices[1:] != indices[:-1]])
    ends = np.r_[starts[1:], indices.size]
    for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
        if indices[start] >= 0:
            yield (
                int(indices[start]),
                replace(
                    trace,
                    waypoint_t_ms=trace.waypoint_t_ms[start:end],
                    waypoint_xy_m=trace.waypoint_xy_m[start:end],
                    waypoint_floor=levels[start:end],
                ),
            )


def fold_records(venue: IpinVenue, logs: Sequence[IpinLog], *, magnetic: bool) -> TrainingSurvey:
    """What a fold's maps are built from: every scan (and with ``magnetic`` every
    magnetometer sample) of these logs placed between their POSI lines. A log is one walk
    (cut at its floor changes); the repetitions of a trial walk one route, so they share
    one group in the fix-error folds."""
    scans = LabelledScans()
    field = LabelledField()
    for log in logs:
        for floor_index, part in floor_parts(log.trace, venue):
            scans.add_trace(part, floor_index, group=log.trial, walk=log.trace.path_id)
            if magnetic:
                field.add_trace(part, floor_index)
    pressure = tuple(
        (log.trace.pressure, log.trace.waypoint_t_ms, log.trace.waypoint_floor)
        for log in logs
        if log.trace.pressure.shape[0] and log.trace.waypoint_floor.size
    )
    plans = (None,) * len(venue.floors)
    return TrainingSurvey(scans, field if magnetic else None, plans, pressure_walks=pressure)


def fold_maps(
    venue: IpinVenue,
    training: TrainingSurvey,
    *,
    parts: Collection[str],
    version: str,
) -> SiteMaps:
    """The venue's map set from a fold's records (``map_set.build_map_set``)."""
    fields = training.field.floor_fields(venue.site) if training.field is not None else {}
    records = SiteRecords(
        site_floors(venue.site),
        training.scans.surveyed(),
        (),
        fields,
        pressure_walks=training.pressure_walks,
    )
    return build_map_set(records, parts=parts, version=version)


@dataclass(frozen=True)
class IpinFold:
    """One left-out trial: the maps from the other trials' logs and what they were
    built from, and the logs scored on them."""

    trial: int
    maps: SiteMaps
    training: TrainingSurvey
    map_logs: int
    test: tuple[IpinLog, ...]


@dataclass(frozen=True)
class IpinSetup:
    """What every engine of one evaluation shares: the logs read once and each fold's
    maps built once for all the engines (``training_maps.parts_for``)."""

    venue: IpinVenue
    logs: tuple[IpinLog, ...]
    folds: tuple[IpinFold, ...]
    validation: bool
    parts: frozenset[str]


def prepare_ipin(
    venue_dir: Path,
    engines: Collection[str],
    *,
    validation: bool = False,
    progress: Progress | None = None,
    trials: Collection[int] | None = None,
    repetitions: Collection[int] | None = None,
) -> IpinSetup:
    """Read the chosen logs and build each fold's maps for ``engines`` (see
    ``evaluate_ipin``)."""
    for engine in engines:
        get_engine(engine)  # fail early on an unknown engine name
    venue = read_venue(venue_dir)
    chosen = [
        f
        for f in venue.logs
        if (trials is None or f.trial in trials)
        and (repetitions is None or f.repetition in repetitions)
        and (not validation or f.repetition in VALIDATION_REPETITIONS)
    ]
    logs: list[IpinLog] = []
    for done, file in enumerate(chosen, start=1):
        logs.append(read_log(file.path, venue.frame))
        if progress:
            progress("read logs", done, len(chosen))
    parts = parts_for(engines)
    folds = []
    fold_trials = sorted({log.trial for log in logs if log.trial is not None})
    for done, trial in enumerate(fold_trials, start=1):
        train = [log for log in logs if log.trial != trial]
        training = fold_records(venue, train, magnetic=MAGNETIC in parts)
        maps = fold_maps(venue, training, parts=parts, version=f"not-trial-{trial}")
        test = tuple(log for log in logs if log.trial == trial)
        folds.append(IpinFold(trial, maps, training, len(train), test))
        if progress:
            progress("maps", done, len(fold_trials))
    return IpinSetup(venue, tuple(logs), tuple(folds), validation, parts)


def score_log(log: IpinLog, venue: IpinVenue, fixes: Sequence[Fix]) -> PathResult:
    """The estimates of a replayed log at its POSI lines, with per-line true floors; the
    result's ``floor_index`` is the floor of most of its POSI lines."""
    trace = log.trace
    true_floor = np.array(
        [venue.floor_index(int(level)) for level in trace.waypoint_floor.tolist()],
        dtype=np.int64,
    )
    estimates = replace(estimates_at_waypoints(trace, 0, fixes), true_floor=true_floor)
    values, counts = np.unique(true_floor, return_counts=True)
    floor_index = int(values[np.argmax(counts)]) if values.size else -1
    return PathResult(trace.path_id, floor_index, estimates, tuple(fixes))


def _ipin_score(
    paths: Sequence[PathResult], venue: IpinVenue, levels: Sequence[NDArray[np.int64]]
) -> float | None:
    """``error_metrics.ipin_score`` over the POSI lines of ``paths`` (``levels``: per path, the
    true level of each of its lines). A missing estimate (floor index -1) is left out by
    ``ipin_score`` whatever level it is given here."""
    if not paths:
        return None
    floor_levels = np.array([f.level for f in venue.floors], dtype=np.int64)
    est_floor = np.concatenate([p.estimates.est_floor for p in paths])
    return ipin_score(
        np.concatenate([p.estimates.est_xy_m for p in paths]),
        np.concatenate([p.estimates.true_xy_m for p in paths]),
        np.where(est_floor >= 0, floor_levels[np.clip(est_floor, 0, None)], 0),
        np.concatenate(levels),
        floor_penalty_m=IPIN_FLOOR_PENALTY_M,
    )


def evaluate_ipin(
    venue_dir: Path,
    engine: str,
    *,
    validation: bool = False,
    progress: Progress | None = None,
    params: Mapping[str, str] | None = None,
    seed: int = 0,
    trials: Collection[int] | None = None,
    repetitions: Collection[int] | None = None,
    setup: IpinSetup | None = None,
    replayer: Replayer | None = None,
) -> IpinEvaluation:
    """Leave-one-trial-out evaluation of an engine on a venue's logs (module docstring).

    Parameters
    ----------
    venue_dir : Path
        The venue folder (``logs/``, ``BLE_Locations.csv``, ``references.csv``).
    engine : str
        Engine name.
    validation : bool
        Read only repetitions 01 and 03 (``VALIDATION_REPETITIONS``).
    progress : callable, optional
        ``progress(stage, done, total)``.
    params : mapping of str to str, optional
        Engine parameters other than their defaults, as text (``engine_params.engine_params``).
    seed : int
        Seed of every replay.
    trials, repetitions : collection of int, optional
        Only these trials and repetitions are read (for a quick run); all by default.
    setup : IpinSetup, optional
        The logs and fold maps of ``prepare_ipin`` (shared between engines); read and
        built here otherwise.
    replayer : Replayer, optional
        Replays a fold's logs (in process with ``seed`` and ``params`` by default; through
        a service with ``service_replay.http_replayer``).

    Returns
    -------
    IpinEvaluation

    Raises
    ------
    KeyError
        Unknown engine. ``ValueError`` for a parameter it refuses (before any log is read).
    """
    get_engine(engine)  # fail early on an unknown engine name
    engine_settings = engine_params(engine, params)
    if setup is None:
        setup = prepare_ipin(
            venue_dir,
            [engine],
            validation=validation,
            progress=progress,
            trials=trials,
            repetitions=repetitions,
        )
    missing = parts_for([engine]) - setup.parts
    if missing:
        raise ValueError(f"the setup's maps were built without {sorted(missing)} for {engine}")
    venue, logs = setup.venue, setup.logs
    replayer = replayer or in_process_replayer(seed, params=engine_settings)
    results: list[PathResult] = []
    folds: dict[str, dict[str, float]] = {}
    for fold in setup.folds:
        fixes = replayer(
            engine,
            fold.maps,
            fold.training,
            [trace_events(log.trace, engine) for log in fold.test],
        )
        for log, log_fixes in zip(fold.test, fixes, strict=True):
            results.append(score_log(log, venue, log_fixes))
        if progress:
            progress("replay", len(results), len(logs))
        folds[f"{fold.trial:02d}"] = {
            "map_logs": fold.map_logs,
            "test_logs": len(fold.test),
            "reference_points": int(fold.maps.radio.rp_xy.shape[0]) if fold.maps.radio else 0,
            "radio_error_68_m": fold.maps.fix_error.error_68_m,
        }
    fold_trials = [fold.trial for fold in setup.folds]

    by_id = {log.trace.path_id: log for log in logs}
    per_log: dict[str, dict[str, Any]] = {}
    for result in results:
        log = by_id[result.path_id]
        report = summarize([result])
        per_log[result.path_id] = {
            "trial": log.trial,
            "repetition": log.repetition,
            "phone": log.phone,
            "n_points": report["n_points"],
            "ipin_score_m": _ipin_score([result], venue, [log.trace.waypoint_floor]),
            "mean_m": report["mean_m"],
            "floor_hit_rate": report["floor_hit_rate"],
        }
    levels = [by_id[r.path_id].trace.waypoint_floor for r in results]
    summary = summarize(
        results,
        floor_names=[f.name for f in venue.floors],
        engine=engine,
        dataset=f"ipin:{venue.name}" + (":validation" if setup.validation else ""),
        protocol="leave one trial out",
        seed=seed,
        logs=len(logs),
        trials=fold_trials,
        repetitions=sorted({log.repetition for log in logs if log.repetition is not None}),
        floors=len(venue.floors),
        bad_lines=sum(log.bad_lines for log in logs),
        ipin_score_m=_ipin_score(results, venue, levels),
    )
    summary["per_log"] = per_log
    summary["folds"] = folds
    if params:
        summary["params"] = dict(params)
    return IpinEvaluation(venue, tuple(results), summary)
