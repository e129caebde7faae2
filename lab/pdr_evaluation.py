"""PDR alone on ILC 2.0 traces: how far the phone walked, and how far dead reckoning drifts.

Each test trace's raw IMU goes through the step tracker (``server.positioning.motion.step_tracker``)
in blocks of one second, as a phone would post it. Two things are measured:

* **Walked distance.** The steps between the first and the last waypoint give a walked
  distance; the waypoint polyline gives the true one (a lower bound: people do not walk
  exactly straight between waypoints). The per-trace error is ``detected / true - 1``.
  The step-length model (Weinberg's K of ``papers/002_*`` eq 8 or Mansour's m of
  ``papers/003_*`` eq 1, with its clamp) is scaled the way Cui trains K (their Table 2):
  by one factor, the median ratio of true to detected distance over the *training* traces
  of the split, then applied unchanged to the test traces. Both the paper model and the
  trained one are reported.
* **Dead-reckoning drift.** Starting at the first waypoint, each step moves the position
  by its (trained) length along the tracker's heading, turned onto north once at the
  first step (the building frame of ILC 2.0 is north-aligned; magnetic declination is not
  corrected). So ``--heading attitude`` (gyro-driven) shows its drift, ``fused`` and
  ``rotation`` how well the compass holds it. The error at each later waypoint is
  reported, and its ratio to the distance walked since the start.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lab.datasets.ilc import read_site
from lab.split import split_site
from server.positioning.model.walk import Walk
from server.positioning.motion.pdr import Detector, LengthModel
from server.positioning.motion.step_tracker import (
    TrackerParams,
)
from server.positioning.motion.straight_lines import straighten_track
from server.positioning.motion.walk_steps import anchored_steps
from server.storage.ilc_trace_format import read_trace

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TraceSteps:
    """Steps of one trace between its first and last waypoint, and the truth."""

    path_id: str
    floor: str
    true_m: float
    t_ms: NDArray[np.int64]
    length_m: NDArray[np.float64]  # paper model
    heading_rad: NDArray[np.float64]  # from the tracker's heading source
    north_rad: NDArray[np.float64]
    status: NDArray[np.int64]  # turns.STRAIGHT / SUSPECT / TURN
    segment: NDArray[np.int64]
    waypoint_t_ms: NDArray[np.int64]
    waypoint_xy_m: NDArray[np.float64]

    @property
    def detected_m(self) -> float:
        return float(self.length_m.sum())


def trace_steps(trace: Walk, params: TrackerParams) -> TraceSteps | None:
    """The tracker run over a trace (``walk_steps.anchored_steps``); None when it has under two
    waypoints or walks less than ``walk_steps.MIN_ANCHORED_PATH_M``."""
    steps = anchored_steps(trace, params)
    if steps is None:
        return None
    return TraceSteps(
        path_id=trace.path_id,
        floor=trace.floor,
        true_m=float(np.linalg.norm(np.diff(trace.waypoint_xy_m, axis=0), axis=1).sum()),
        t_ms=steps.t_ms,
        length_m=steps.length_m.astype(np.float64),
        heading_rad=steps.heading_rad.astype(np.float64),
        north_rad=steps.north_rad.astype(np.float64),
        status=steps.status.astype(np.int64),
        segment=steps.segment.astype(np.int64),
        waypoint_t_ms=trace.waypoint_t_ms,
        waypoint_xy_m=trace.waypoint_xy_m,
    )


def dead_reckon(
    steps: TraceSteps, scale: float, rng: np.random.Generator | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Errors at the waypoints after the first, dead reckoning from it, and the distance
    walked to each.

    The heading of each step is the tracker's heading turned once, at the first step whose
    north-referenced heading is known, onto north: a relative (gyro-only) source drifts
    from there, a north-referenced one stays as good as its reference. Steps before that
    do not move the position. With an ``rng`` the track's straight stretches are filtered
    with RANSAC (``straight_lines.straighten_track``, ``papers/003_*`` eq 2-3; the rng draws
    the pairs of long stretches).
    """
    known = np.flatnonzero(~np.isnan(steps.north_rad) & ~np.isnan(steps.heading_rad))
    length = scale * steps.length_m
    if known.size:
        offset = steps.north_rad[known[0]] - steps.heading_rad[known[0]]
        heading = np.nan_to_num(steps.heading_rad + offset)
        moved = length * (np.arange(length.size) >= known[0]) * ~np.isnan(steps.heading_rad)
    else:
        heading = np.zeros(length.size)
        moved = np.zeros(length.size)
    # position and distance after 0, 1, ..., k steps
    xy = steps.waypoint_xy_m[0] + np.vstack(
        [
            np.zeros((1, 2)),
            np.cumsum(np.column_stack([moved * np.sin(heading), moved * np.cos(heading)]), axis=0),
        ]
    )
    if rng is not None:
        xy[1:] = straighten_track(xy[1:], steps.status, steps.segment, rng=rng)
    walked = np.concatenate([[0.0], np.cumsum(length)])
    taken = np.searchsorted(steps.t_ms, steps.waypoint_t_ms[1:], side="right")
    errors = np.linalg.norm(xy[taken] - steps.waypoint_xy_m[1:], axis=1)
    return errors, walked[taken]


def _read(
    paths: Sequence[tuple[int, Path]],
    floors: Sequence[str],
    params: TrackerParams,
    what: str,
    progress: Progress | None,
) -> list[TraceSteps]:
    out: list[TraceSteps] = []
    for done, (index, path) in enumerate(paths, start=1):
        found = trace_steps(read_trace(path, floors[index]), params)
        if found is not None:
            out.append(found)
        if progress is not None:
            progress(what, done, len(paths))
    return out


def _distance_summary(rows: Sequence[TraceSteps], scale: float) -> dict[str, float]:
    errors = np.array([scale * r.detected_m / r.true_m - 1.0 for r in rows])
    a = np.abs(errors)
    return {
        "median_abs_error": float(np.median(a)),
        "mean_abs_error": float(np.mean(a)),
        "p90_abs_error": float(np.quantile(a, 0.9)),
        "median_signed_error": float(np.median(errors)),
    }


def evaluate_pdr(
    site_dir: Path,
    params: TrackerParams | None = None,
    *,
    split_seed: int = 0,
    train_fraction: float = 0.8,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Walked-distance error and dead-reckoning drift on an ILC site's test traces.

    Returns a JSON-ready dict: the settings, the trained scale, distance-error summaries
    with the paper model and the trained one, dead-reckoning errors, and per-trace rows.

    Raises
    ------
    ValueError
        When the split leaves no usable training or test trace.
    """
    params = params or TrackerParams()
    site = read_site(site_dir)
    split = split_site(site, split_seed, train_fraction)
    floors = [f.name for f in site.floors]
    train = _read(split.train, floors, params, "train traces", progress)
    test = _read(split.test, floors, params, "test traces", progress)
    if not train or not test:
        raise ValueError("the split left no usable training or test trace")
    ratios = [r.true_m / r.detected_m for r in train if r.detected_m > 0]
    scale = float(np.median(ratios)) if ratios else 1.0

    dr = [dead_reckon(r, scale) for r in test]
    errors = np.concatenate([e for e, _ in dr])
    walked = np.concatenate([d for _, d in dr])
    far = walked > 0
    rng = np.random.default_rng(split_seed)
    straightened = np.concatenate([dead_reckon(r, scale, rng)[0] for r in test])
    return {
        "detector": params.steps.detector,
        "length_model": params.steps.length_model,
        "heading": params.heading,
        "split_seed": split_seed,
        "train_fraction": train_fraction,
        "n_train": len(train),
        "n_test": len(test),
        "trained_scale": scale,
        "distance_paper": _distance_summary(test, 1.0),
        "distance_trained": _distance_summary(test, scale),
        "dead_reckoning": {
            "n_points": int(errors.size),
            "mean_m": float(errors.mean()),
            "p50_m": float(np.median(errors)),
            "p90_m": float(np.quantile(errors, 0.9)),
            "median_error_per_walked": float(np.median(errors[far] / walked[far])),
        },
        "dead_reckoning_straightened": {
            "mean_m": float(straightened.mean()),
            "p50_m": float(np.median(straightened)),
            "p90_m": float(np.quantile(straightened, 0.9)),
        },
        "traces": [
            {
                "path_id": r.path_id,
                "floor": r.floor,
                "true_m": round(r.true_m, 2),
                "detected_m": round(r.detected_m, 2),
                "trained_m": round(scale * r.detected_m, 2),
                "n_steps": int(r.t_ms.size),
                "dead_reckoning_final_m": round(float(e[-1]), 2) if e.size else None,
            }
            for r, (e, _) in zip(test, dr, strict=True)
        ],
    }


def with_detector(
    params: TrackerParams, detector: Detector, length_model: LengthModel
) -> TrackerParams:
    """``params`` with another step detector and step-length model."""
    steps = replace(params.steps, detector=detector, length_model=length_model)
    return replace(params, steps=steps)
