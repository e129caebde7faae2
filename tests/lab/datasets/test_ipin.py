"""The IPIN 2023 Track 3 dev venue: its logs, floors, beacons and landmarks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lab.datasets.ipin import VENUE_LEVELS, IpinVenue
from lab.datasets.ipin_log import IpinLog, log_name_ids


def test_venue(venue: IpinVenue, log: IpinLog) -> None:
    assert len(venue.logs) == 24
    assert {(f.trial, f.repetition) for f in venue.logs} == {
        (t, r) for t in (1, 2, 3, 21, 22, 23) for r in (1, 2, 3, 4)
    }
    assert [f.level for f in venue.floors] == sorted(VENUE_LEVELS) == [-2, -1, 0]
    assert [f.name for f in venue.floors] == ["-2", "-1", "0"]
    assert venue.floor_index(-2) == 0
    assert venue.floor_index(1) == -1
    assert venue.site.floors == venue.floors
    assert [b.beacon_id for b in venue.beacons] == [f"BLE{i}" for i in range(1, 7)]
    assert [b.level for b in venue.beacons] == [0, 0, -2, -2, -2, -2]
    assert len(venue.references_xy_m) == 9
    floor = venue.floors[0]
    xy = np.array([*venue.references_xy_m.values(), *((b.x_m, b.y_m) for b in venue.beacons)])
    xy = np.vstack([xy, log.trace.waypoint_xy_m])
    assert np.all(xy >= -1e-6)  # the origin is the landmarks' south-west corner
    assert np.all(xy < (floor.width_m, floor.height_m))
    assert log_name_ids(Path("IPIN2023_T3_TrainingTrial07_repetition12.txt")) == (7, 12)
    assert log_name_ids(Path("notes.txt")) is None
