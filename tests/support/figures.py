"""What the tests of the lab's figures share: a floor plan with every kind of GeoJSON
geometry (and some broken ones), a noisy walk on it, and the check of a written PNG.

Import it after ``pytest.importorskip("matplotlib")``: it reads PNGs with matplotlib.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.image import imread

from lab.plot_canvas import DPI

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

PLAN: dict[str, Any] = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"kind": "outline"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [
                    [[0, 0], [30, 0], [30, 20], [0, 20], [0, 0]],
                    [[12, 8], [12, 12], [18, 12], [18, 8], [12, 8]],  # an atrium
                ],
            },
        },
        {
            "type": "Feature",
            "properties": {"kind": "unit", "name": "shops"},
            "geometry": {
                "type": "MultiPolygon",
                "coordinates": [
                    [[[1, 1], [8, 1], [8, 6], [1, 6], [1, 1]]],
                    [[[22, 1], [29, 1], [29, 6], [22, 6], [22, 1]]],
                ],
            },
        },
        {
            "type": "Feature",
            "properties": {},
            "geometry": {"type": "LineString", "coordinates": [[0, 10], [10, 10]]},
        },
        {
            "type": "Feature",
            "properties": None,
            "geometry": {"type": "Point", "coordinates": [5, 5]},
        },
        {"type": "Feature", "properties": {"kind": "unit"}, "geometry": None},
        {
            "type": "Feature",
            "properties": {},
            "geometry": {"type": "LineString", "coordinates": [[0, 1], [2, 3, 4]]},  # ragged
        },
        {
            "type": "Feature",
            "properties": {"kind": "unit"},
            "geometry": {"type": "Polygon", "coordinates": [[]]},  # empty ring: skipped
        },
        {
            "type": "Feature",
            "properties": {"kind": 3},
            "geometry": {
                "type": "GeometryCollection",
                "geometries": [
                    {"type": "MultiLineString", "coordinates": [[[20, 18, 0], [28, 18, 0]]]}
                ],
            },
        },
    ],
}


def assert_png(path: Path, width_in: float, height_in: float) -> None:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    image = imread(path)
    assert image.shape[:2] == (round(height_in * DPI), round(width_in * DPI))


def walk() -> tuple[np.ndarray, np.ndarray]:
    truth = np.array([(2.0, 8.0), (25.0, 8.0), (25.0, 15.0), (5.0, 15.0)])
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 3.0, 40)
    leg = np.minimum(t.astype(int), 2)
    est = truth[leg] + (t - leg)[:, None] * (truth[leg + 1] - truth[leg])
    return truth, est + rng.normal(0.0, 1.0, est.shape)
