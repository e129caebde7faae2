"""A recorded walk's steps as the server finds them in its raw motion samples
(``step_tracker``), fed in blocks as a phone would send them; and the steps between its
first and last known position, what placement and the PDR evaluation read."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.walk import Walk
from server.positioning.motion.step_tracker import StepBlock, TrackerParams, initial_tracker, track

STEP_BLOCK_MS = 1000  # raw samples reach the step tracker in blocks of this length
# shorter walks say more about the waypoint spacing than about steps
MIN_ANCHORED_PATH_M = 5.0


def walk_steps(trace: Walk, params: TrackerParams, block_ms: int = STEP_BLOCK_MS) -> StepBlock:
    """Every step the server finds in the walk's raw motion samples (``step_tracker``, the
    samples fed in blocks of ``block_ms`` as a phone would send them), in time order."""
    state = initial_tracker(params)
    blocks: list[StepBlock] = []
    for imu in trace.imu_events(block_ms):
        state, block = track(state, imu, params)
        blocks.append(block)
    return _steps(blocks, None)


def anchored_steps(trace: Walk, params: TrackerParams) -> StepBlock | None:
    """The walk's steps between its first and last waypoint (its anchors); None when it
    has fewer than two or they span less than ``MIN_ANCHORED_PATH_M`` along the waypoints."""
    wp_t = trace.waypoint_t_ms
    if wp_t.size < 2:
        return None
    path_m = float(np.linalg.norm(np.diff(trace.waypoint_xy_m, axis=0), axis=1).sum())
    if path_m < MIN_ANCHORED_PATH_M:
        return None
    steps = walk_steps(trace, params)
    return _steps([steps], (steps.t_ms > wp_t[0]) & (steps.t_ms <= wp_t[-1]))


def _steps(blocks: Sequence[StepBlock], keep: NDArray[np.bool_] | None) -> StepBlock:
    """The blocks joined into one, then (with ``keep``) the steps kept."""

    def cat(name: str, dtype: type[np.generic]) -> NDArray[Any]:
        parts = [np.asarray(getattr(b, name), dtype=dtype) for b in blocks]
        joined = np.concatenate(parts) if parts else np.empty(0, dtype=dtype)
        return joined if keep is None else joined[keep]

    return StepBlock(
        t_ms=cat("t_ms", np.int64),
        length_m=cat("length_m", np.float64),
        heading_rad=cat("heading_rad", np.float64),
        north_rad=cat("north_rad", np.float64),
        status=cat("status", np.int64),
        segment=cat("segment", np.int64),
        magnitude_ut=cat("magnitude_ut", np.float64),
    )
