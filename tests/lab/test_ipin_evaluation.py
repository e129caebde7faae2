"""IPIN leave-one-trial-out evaluation: floor parts of a trace, and a cheap run on 3 logs."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lab import ipin_evaluation
from lab.datasets.ipin import read_venue
from lab.datasets.ipin_log import read_log

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
VENUE = DATA / "ipin2023-track3-dev"
needs_data = pytest.mark.skipif(
    not VENUE.is_dir(), reason="../shared/data is not beside the project"
)


@pytest.fixture(scope="module")
def run() -> ipin_evaluation.IpinEvaluation:
    # trials 01 and 02 walk the same floor; trial 21 is two floors down
    return ipin_evaluation.evaluate_ipin(VENUE, "wknn", trials={1, 2, 21}, repetitions={1})


@needs_data
def test_summary_keys_and_finite_errors(run: ipin_evaluation.IpinEvaluation) -> None:
    s = run.summary
    for key in ("n_points", "mean_m", "p50_m", "p75_m", "floor_hit_rate", "ipin_score_m"):
        assert key in s
    assert (s["engine"], s["logs"], s["trials"], s["repetitions"]) == ("wknn", 3, [1, 2, 21], [1])
    assert s["n_points"] == 14 + 12 + 10
    assert s["n_missing"] == 0
    assert math.isfinite(s["mean_m"])
    assert math.isfinite(s["ipin_score_m"])
    assert s["ipin_score_m"] >= s["p75_m"]  # penalties only add
    assert set(s["per_log"]) == {p.path_id for p in run.paths}
    for figures in s["per_log"].values():
        assert math.isfinite(figures["ipin_score_m"])
        assert math.isfinite(figures["mean_m"])
    assert set(s["per_floor"]) == {"-2", "-1", "0"}
    assert s["per_floor"]["-2"]["test_paths"] == 1
    assert s["folds"]["21"]["map_logs"] == 2
    assert s["folds"]["21"]["test_logs"] == 1
    assert s["folds"]["21"]["reference_points"] > 0
    for path in run.paths:
        assert np.isfinite(path.estimates.est_xy_m).all()


@needs_data
def test_truth_floors_are_the_posi_floors(run: ipin_evaluation.IpinEvaluation) -> None:
    by_id = {p.path_id: p for p in run.paths}
    deep = "IPIN2023_T3_TrainingTrial21_repetition01"
    assert by_id[deep].estimates.true_floor.tolist() == [0] * 10  # level -2: index 0
    assert by_id["IPIN2023_T3_TrainingTrial01_repetition01"].floor_index == 2  # level 0
    # trial 21's maps hold floor 0 only: every estimate is two floors off, 2 x 15 m
    figures = run.summary["per_log"][deep]
    assert figures["floor_hit_rate"] == 0.0
    assert figures["ipin_score_m"] >= 2 * ipin_evaluation.IPIN_FLOOR_PENALTY_M


@needs_data
def test_floor_parts_cut_at_floor_changes() -> None:
    venue = read_venue(VENUE)
    log = read_log(venue.logs[0].path, venue.frame)
    levels = np.array([0, 0, 0, -1, -1, 0, 0, 0, 0, 0, 0, 5, 0, 0], dtype=np.int64)
    trace = replace(log.trace, waypoint_floor=levels)
    parts = list(ipin_evaluation.floor_parts(trace, venue))
    assert [(i, p.waypoint_t_ms.size) for i, p in parts] == [(2, 3), (1, 2), (2, 6), (2, 2)]
    assert parts[1][1].waypoint_t_ms.tolist() == trace.waypoint_t_ms[3:5].tolist()
    # a trace without per-waypoint floors is one part on its floor
    whole = replace(log.trace, waypoint_floor=np.empty(0, dtype=np.int64))
    assert [(i, p is whole) for i, p in ipin_evaluation.floor_parts(whole, venue)] == [(2, True)]
