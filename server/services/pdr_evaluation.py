"""How far the phone walked by our step detection, against the ILC 2.0 waypoints.

For each trace, the steps found in its raw accelerometer samples between its first and
last waypoint give a walked distance; the waypoint polyline gives the true distance (a
lower bound: people do not walk exactly straight between waypoints). The per-trace error
is ``detected / true - 1``.

The step-length model (Weinberg's K of ``papers/002_*`` eq 8 or Mansour's m of
``papers/003_*`` eq 1, with its clamp) is scaled the way Cui trains K (their Table 2): one
factor, the median ratio of true to detected distance over the training traces of the
split only, then applied unchanged to the test traces. Both the paper model and the
trained one are reported.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.datasets.ilc import IlcTrace, read_site, read_trace
from server.positioning.pdr import PdrParams, Steps, detect_steps, initial_detector, step_lengths
from server.services.evaluation import split_site

Progress = Callable[[str, int, int], None]

MIN_PATH_M = 5.0  # shorter walks say more about the waypoint spacing than about steps
BLOCK_MS = 1000  # samples go to the detector in blocks, as a phone would send them


@dataclass(frozen=True)
class TraceDistance:
    path_id: str
    floor: str
    true_m: float
    detected_m: float  # with the paper constant
    n_steps: int
    duration_s: float


def trace_steps(trace: IlcTrace, params: PdrParams, block_ms: int = BLOCK_MS) -> Steps:
    """All steps of a trace, its accelerometer fed in blocks of ``block_ms``."""
    state = initial_detector()
    parts: list[Steps] = []
    accel = trace.accel
    if accel.shape[0] == 0:
        return Steps(np.empty(0, np.int64), np.empty(0), np.empty(0))
    edges = np.arange(accel[0, 0], accel[-1, 0] + block_ms, block_ms)
    cuts = np.searchsorted(accel[:, 0], edges[1:], side="left")
    for block in np.split(accel, cuts):
        state, found = detect_steps(state, block, params)
        parts.append(found)
    return Steps(
        np.concatenate([p.t_ms for p in parts]),
        np.concatenate([p.accel_range for p in parts]),
        np.concatenate([p.gravity for p in parts]),
    )


def trace_distance(trace: IlcTrace, params: PdrParams) -> TraceDistance | None:
    """Detected and true walked distance between the first and last waypoint; None when
    the trace has under two waypoints or walks less than ``MIN_PATH_M``."""
    wp_t = trace.waypoint_t_ms
    if wp_t.size < 2:
        return None
    true_m = float(np.linalg.norm(np.diff(trace.waypoint_xy_m, axis=0), axis=1).sum())
    if true_m < MIN_PATH_M:
        return None
    steps = trace_steps(trace, params)
    inside = (steps.t_ms > wp_t[0]) & (steps.t_ms <= wp_t[-1])
    lengths = step_lengths(steps, params)
    return TraceDistance(
        path_id=trace.path_id,
        floor=trace.floor,
        true_m=true_m,
        detected_m=float(lengths[inside].sum()),
        n_steps=int(inside.sum()),
        duration_s=float(wp_t[-1] - wp_t[0]) / 1000.0,
    )


def _distances(
    paths: Sequence[tuple[int, Path]],
    floors: Sequence[str],
    params: PdrParams,
    what: str,
    progress: Progress | None,
) -> list[TraceDistance]:
    out: list[TraceDistance] = []
    for done, (index, path) in enumerate(paths, start=1):
        found = trace_distance(read_trace(path, floors[index]), params)
        if found is not None:
            out.append(found)
        if progress is not None:
            progress(what, done, len(paths))
    return out


def _errors(rows: Sequence[TraceDistance], scale: float) -> NDArray[np.float64]:
    return np.array([scale * r.detected_m / r.true_m - 1.0 for r in rows])


def _summary(errors: NDArray[np.float64]) -> dict[str, float]:
    a = np.abs(errors)
    return {
        "median_abs_error": float(np.median(a)),
        "mean_abs_error": float(np.mean(a)),
        "p90_abs_error": float(np.quantile(a, 0.9)),
        "median_signed_error": float(np.median(errors)),
    }


def evaluate_step_distance(
    site_dir: Path,
    params: PdrParams,
    *,
    split_seed: int = 0,
    train_fraction: float = 0.8,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Per-trace distance error of step detection on an ILC site's test traces.

    Returns a JSON-ready dict: the settings, the trained scale, summaries with the paper
    constant and with the trained one, and the per-trace rows of the test traces.
    """
    site = read_site(site_dir)
    split = split_site(site, split_seed, train_fraction)
    floors = [f.name for f in site.floors]
    train = _distances(split.train, floors, params, "train", progress)
    test = _distances(split.test, floors, params, "test", progress)
    if not train or not test:
        raise ValueError("the split left no usable training or test trace")
    # trained like papers/002_* Table 2: one constant for the population of walkers
    scale = float(np.median([r.true_m / r.detected_m for r in train if r.detected_m > 0]))
    return {
        "detector": params.detector,
        "length_model": params.length_model,
        "split_seed": split_seed,
        "train_fraction": train_fraction,
        "n_train": len(train),
        "n_test": len(test),
        "trained_scale": scale,
        "paper": _summary(_errors(test, 1.0)),
        "trained": _summary(_errors(test, scale)),
        "traces": [
            {
                "path_id": r.path_id,
                "floor": r.floor,
                "true_m": round(r.true_m, 2),
                "detected_m": round(r.detected_m, 2),
                "trained_m": round(scale * r.detected_m, 2),
                "n_steps": r.n_steps,
                "duration_s": round(r.duration_s, 1),
            }
            for r in test
        ],
    }
