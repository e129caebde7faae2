"""PDR alone on recorded traces: walked distance and dead reckoning from the first
waypoint (the full-site figures are in bench/accuracy.md)."""

from __future__ import annotations

import numpy as np

from lab.pdr_evaluation import TraceSteps, dead_reckon, trace_steps, with_detector
from server.positioning.motion.step_tracker import TrackerParams
from server.storage.ilc_trace_format import read_trace
from tests.support.datasets import dataset_dir

T0 = 1_700_000_000_000


def test_a_recorded_walk_is_measured_within_a_third() -> None:
    floor = dataset_dir("ilc20-sample") / "site2" / "F1" / "path_data_files"
    path = sorted(floor.iterdir())[0]
    trace = read_trace(path, "F1")
    for detector, length in (("mansour", "mansour"), ("cui", "weinberg")):
        steps = trace_steps(trace, with_detector(TrackerParams(), detector, length))  # type: ignore[arg-type]
        assert steps is not None
        # the paper models run long on this site (bench/accuracy.md); a third is generous
        assert 0.67 < steps.detected_m / steps.true_m < 1.5, (detector, steps.detected_m)
        assert np.all(np.diff(steps.t_ms) >= 200)  # no two steps closer than a gait cycle
        errors, walked = dead_reckon(steps, 1.0)
        assert errors.shape == walked.shape == (trace.waypoint_t_ms.size - 1,)
        assert np.all(np.diff(walked) >= 0)


def test_dead_reckoning_by_hand() -> None:
    """Four 1 m steps, the first before north is known, the last without a heading: only
    the middle two move, east (the relative heading turned onto north at step 2)."""
    steps = TraceSteps(
        path_id="p",
        floor="F1",
        true_m=4.0,
        t_ms=np.array([T0 + 500 * i for i in range(1, 5)], dtype=np.int64),
        length_m=np.ones(4),
        heading_rad=np.array([0.0, 0.0, 0.0, np.nan]),  # a relative source; the last: none
        north_rad=np.array([np.nan, np.pi / 2, np.pi / 2, np.nan]),
        status=np.zeros(4, dtype=np.int64),
        segment=np.zeros(4, dtype=np.int64),
        waypoint_t_ms=np.array([T0, T0 + 1000, T0 + 2500], dtype=np.int64),
        waypoint_xy_m=np.array([[0.0, 0.0], [2.0, 1.0], [4.0, 0.0]]),
    )
    errors, walked = dead_reckon(steps, 0.5)
    # after 2 steps at 0.5 m: (0.5, 0) against (2, 1); after 4: (1, 0) against (4, 0)
    np.testing.assert_allclose(errors, [np.hypot(1.5, 1.0), 3.0])
    np.testing.assert_allclose(walked, [1.0, 2.0])
