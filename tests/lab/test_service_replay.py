"""Replay through a service: the survey, magnetic and crowd-upload bodies, and what the
summary says of the uploads."""

from __future__ import annotations

import lzma
from pathlib import Path
from typing import Any

import numpy as np

from lab import service_replay
from lab.training_maps import LabelledField, LabelledScans
from server.api.schemas.maps import MagneticSurveyIn, SurveyIn
from server.positioning.model.events import BleEvent, RadioReading, WifiEvent
from server.positioning.model.walk import trace_from_events


def test_labelled_scans_become_survey_points_on_their_level() -> None:
    wifi = WifiEvent(1_000, (RadioReading("aa:bb:cc:dd:ee:01", -60.0),))
    ble = BleEvent(1_050, (RadioReading("beacon-1", -70.0),))
    walk = trace_from_events([wifi, ble], [(900, 1.0, 2.0), (1_100, 3.0, 2.0)])
    scans = LabelledScans()
    scans.add_trace(walk, 0)
    # a walk timed from its own start goes up on a phone's clock
    points = service_replay.survey_points(scans, [3], offset_ms=service_replay.EPOCH_MS)
    assert points == [
        {
            "x_m": 2.0,
            "y_m": 2.0,
            "floor": 3,
            "t": service_replay.EPOCH_MS + 1_000,
            "wifi": [{"bssid": "aa:bb:cc:dd:ee:01", "rssi_dbm": -60.0}],
            "walk": "trace 1",
        },
        {
            "x_m": 2.5,
            "y_m": 2.0,
            "floor": 3,
            "t": service_replay.EPOCH_MS + 1_050,
            "ble": [{"id": "beacon-1", "rssi_dbm": -70.0}],
            "walk": "trace 1",
        },
    ]
    SurveyIn.model_validate({"points": points})  # what the survey API accepts


def test_magnetometer_samples_become_magnetic_points_by_level() -> None:
    field = LabelledField(
        xy_m={1: [np.array([[0.5, 1.5], [2.0, 1.0]]), np.array([[4.0, 4.0]])]},
        magnitude_ut={1: [np.array([45.0, 47.5]), np.array([50.0])]},
    )
    points = service_replay.magnetic_points(field, [-1, 2])
    assert points == {
        2: [
            {"x_m": 0.5, "y_m": 1.5, "magnitude_ut": 45.0},
            {"x_m": 2.0, "y_m": 1.0, "magnitude_ut": 47.5},
            {"x_m": 4.0, "y_m": 4.0, "magnitude_ut": 50.0},
        ]
    }
    MagneticSurveyIn.model_validate({"points": points[2]})
    assert service_replay.magnetic_points(None, [0]) == {}


def test_crowd_uploads_keep_only_the_end_waypoints(tmp_path: Path) -> None:
    text = "".join(
        f"{t}\tTYPE_WAYPOINT\t{t / 1000:.1f}\t0.0\n{t + 1}\tTYPE_WIFI\tx\n"
        for t in (1_000, 2_000, 3_000)
    )
    plain = tmp_path / "a.txt"
    plain.write_text(text)
    packed = tmp_path / "b.txt.xz"
    packed.write_bytes(lzma.compress(text.encode()))
    uploads = service_replay.crowd_uploads([(0, plain), (1, packed)], [4, 5])
    assert [level for level, _ in uploads] == [4, 5]
    for _, body in uploads:
        lines = body.decode().splitlines()
        assert [line.split("\t")[0] for line in lines if "TYPE_WAYPOINT" in line] == [
            "1000",
            "3000",
        ]
        assert sum("TYPE_WIFI" in line for line in lines) == 3


def test_the_summary_counts_upload_states_and_reasons_without_their_numbers() -> None:
    summary: dict[str, Any] = {
        "engine": "wknn",
        "reference_points": 120,
        "per_floor": {"F1": {"n_points": 3, "magnetic_coverage": 0.5, "magnetic_at_waypoints": 1}},
    }
    reports: list[dict[str, Any]] = [
        {"status": "done", "report": {"steps": 40}},
        {"status": "rejected", "report": {"reason": "only 3 steps between 2 anchors"}},
        {"status": "rejected", "report": {"reason": "only 5 steps between 2 anchors"}},
        {"status": "failed", "report": None},
    ]
    service_replay.summarise_crowd(summary, reports)
    assert summary == {
        "engine": "wknn",
        "map_source": "crowd",
        "per_floor": {"F1": {"n_points": 3}},
        "uploads": {
            "status": {"done": 1, "rejected": 2, "failed": 1},
            "reasons": {"only steps between anchors": 2},
        },
    }
