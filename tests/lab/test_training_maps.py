"""Maps from training traces: labelled scans and their cross-validation groups."""

from __future__ import annotations

from lab import training_maps
from server.positioning.model.events import RadioReading, WifiEvent


def test_walks_along_one_route_share_a_cross_validation_group() -> None:
    from server.positioning.model.walk import trace_from_events

    wifi = WifiEvent(1_000, (RadioReading("aa:bb", -60.0),))
    walk = trace_from_events([wifi], [(900, 1.0, 2.0), (1_100, 2.0, 2.0)])
    scans = training_maps.LabelledScans()
    scans.add_trace(walk, 0, group=3)
    scans.add_trace(walk, 0, group=3)
    scans.add_trace(walk, 0)
    scans.add_trace(walk, 0)
    groups = scans.surveyed().groups().tolist()
    assert len(groups) == 4
    assert groups[0] == groups[1]
    assert len({groups[1], groups[2], groups[3]}) == 3
