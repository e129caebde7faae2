"""Indoor Location Competition 2.0 sites: floors, floor names and plans on the site2 sample."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.path import Path as PolygonPath
from numpy.typing import NDArray

from lab.datasets.ilc import read_site
from server.storage.ilc_trace_format import read_trace

SITE2_FLOORS = ("B1", "F1", "F2", "F3", "F4", "F5", "F6", "F7", "F8")


def test_read_site_lists_site2(ilc_dir: Path) -> None:
    site = read_site(ilc_dir / "site2")
    assert site.name == "site2"
    assert tuple(f.name for f in site.floors) == SITE2_FLOORS
    assert tuple(f.level for f in site.floors) == tuple(range(-1, 8))
    assert sum(len(f.trace_files) for f in site.floors) == 417
    for floor in site.floors:
        assert floor.trace_files
        assert list(floor.trace_files) == sorted(floor.trace_files)
        assert all(p.name.endswith(".txt.xz") for p in floor.trace_files)
        assert floor.width_m > 100.0
        assert floor.height_m > 100.0
        assert floor.plan is not None
        kinds = [ft["properties"]["kind"] for ft in floor.plan["features"]]
        assert kinds[0] == "outline"
        assert set(kinds[1:]) == {"unit"}
        outline = np.concatenate([np.asarray(p[0]) for p in outline_polygons(floor.plan)])
        np.testing.assert_allclose(outline.min(axis=0), [0.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(outline.max(axis=0), [floor.width_m, floor.height_m])


def test_read_site_on_a_floor_directory(ilc_dir: Path) -> None:
    site = read_site(ilc_dir / "site2" / "F4")
    assert site.name == "site2"
    (floor,) = site.floors
    assert (floor.name, floor.level, len(floor.trace_files)) == ("F4", 3, 26)


def test_read_site_names_the_bad_floor_directory(tmp_path: Path) -> None:
    (tmp_path / "F1" / "path_data_files").mkdir(parents=True)
    (tmp_path / "Mezzanine" / "path_data_files").mkdir(parents=True)
    with pytest.raises(ValueError, match="Mezzanine"):
        read_site(tmp_path)
    with pytest.raises(ValueError, match="no floor directories"):
        read_site(tmp_path / "F1" / "path_data_files")


def outline_polygons(plan: dict[str, Any]) -> list[list[list[list[float]]]]:
    geometry = plan["features"][0]["geometry"]
    if geometry["type"] == "Polygon":
        return [geometry["coordinates"]]
    polygons: list[list[list[list[float]]]] = geometry["coordinates"]
    return polygons


def inside(polygon: list[list[list[float]]], xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Inside the exterior ring and outside every hole."""
    result = PolygonPath(np.asarray(polygon[0])).contains_points(xy)
    for hole in polygon[1:]:
        result &= ~PolygonPath(np.asarray(hole)).contains_points(xy)
    return result


@pytest.mark.parametrize("floor_name", ["B1", "F1", "F8"])
def test_waypoints_lie_inside_the_floor_outline(ilc_dir: Path, floor_name: str) -> None:
    site = read_site(ilc_dir / "site2" / floor_name)
    (floor,) = site.floors
    assert floor.plan is not None
    units = [
        ft["geometry"]["coordinates"]
        for ft in floor.plan["features"][1:]
        if ft["geometry"]["type"] == "Polygon"
    ]
    for path in floor.trace_files[:3]:
        xy = read_trace(path).waypoint_xy_m
        assert xy.shape[0] > 0
        in_outline = np.zeros(xy.shape[0], dtype=bool)
        for polygon in outline_polygons(floor.plan):
            in_outline |= inside(polygon, xy)
        assert in_outline.all(), f"{path.name}: waypoints outside the outline"
        in_unit = Counter(int(i) for u in units for i in np.flatnonzero(inside(u, xy)))
        assert not in_unit, f"{path.name}: waypoints inside shops"
