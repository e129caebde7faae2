"""Indoor Location Competition 2.0 (Microsoft / XYZ10) sites: floors and floor plans.

Layout of a site (as in the upstream repository and the sample under
``../shared/data/ilc20-sample/``)::

    <site>/<floor>/floor_info.json            {"map_info": {"width": .., "height": ..}} in metres
    <site>/<floor>/geojson_map.json           floor plan, WGS-84 lon/lat
    <site>/<floor>/path_data_files/<id>.txt   one phone trace (also ``<id>.txt.xz``)

A site is listed here, its traces are not read: ``ilc_trace_format.read_trace`` reads one.

Floor plans: ``geojson_map.json`` is converted into the waypoint frame. The bounding box
of its first feature (the floor outline) maps linearly onto ``[0, width] x [0, height]``
of ``floor_info.json``: x grows with longitude from the minimum longitude, y with
latitude from the minimum latitude (checked on every site2 floor: all 3,054 waypoints
fall inside the outline and none inside a unit).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.storage.ilc_trace_format import floor_level

_PLAN_FOREIGN_FRAME_KEYS = ("center", "point", "points")  # lon/lat or Web-Mercator values


@dataclass(frozen=True, eq=False)
class IlcFloor:
    """One floor of a site.

    Attributes
    ----------
    name : str
        Directory name, e.g. ``"B1"``, ``"F2"``.
    level : int
        ``floor_level(name)``: 0 for the ground floor, negative below.
    width_m, height_m : float
        Extent of the floor-map frame (``floor_info.json``); NaN when the file is absent.
    plan : dict or None
        GeoJSON FeatureCollection in metres of the floor-map frame; the first feature is
        the outline (``properties.kind == "outline"``), the others are units (shops,
        rooms: ``properties.kind == "unit"``). Walkable area: outline minus units.
        ``None`` when ``geojson_map.json`` or the floor size is missing.
    trace_files : tuple of Path
        ``path_data_files/*.txt`` and ``*.txt.xz``, sorted by name.
    """

    name: str
    level: int
    width_m: float
    height_m: float
    plan: dict[str, Any] | None
    trace_files: tuple[Path, ...]


@dataclass(frozen=True, eq=False)
class IlcSite:
    """A site: its floors ordered by level."""

    name: str
    floors: tuple[IlcFloor, ...]


def read_site(path: Path) -> IlcSite:
    """Read the floors of a site directory, or of a single floor directory.

    Parameters
    ----------
    path : Path
        ``<site>/`` with ``<floor>/`` subdirectories, or one ``<site>/<floor>/``
        (recognised by its ``path_data_files/`` or ``floor_info.json``).

    Returns
    -------
    IlcSite
        Named after the site directory; floors sorted by level. Traces are listed, not
        read (``ilc_trace_format.read_trace`` each of ``floor.trace_files``).

    Raises
    ------
    ValueError
        No floor directory found, a floor name whose level cannot be told (the message
        names the directory), or a floor plan that is not the expected GeoJSON.
    """
    if _is_floor_dir(path):
        site_name, floor_dirs = path.resolve().parent.name, [path]
    else:
        site_name = path.resolve().name
        floor_dirs = sorted(p for p in path.iterdir() if p.is_dir() and _is_floor_dir(p))
        if not floor_dirs:
            raise ValueError(f"{path}: no floor directories (with path_data_files/)")
    floors = [_read_floor(d) for d in floor_dirs]
    floors.sort(key=lambda f: (f.level, f.name))
    return IlcSite(name=site_name, floors=tuple(floors))


def _is_floor_dir(path: Path) -> bool:
    return (path / "path_data_files").is_dir() or (path / "floor_info.json").is_file()


def _read_floor(path: Path) -> IlcFloor:
    try:
        level = floor_level(path.name)
    except ValueError as err:
        raise ValueError(f"floor directory {path}: {err}") from None
    width_m = height_m = math.nan
    info_path = path / "floor_info.json"
    if info_path.is_file():
        try:
            map_info = json.loads(info_path.read_text(encoding="utf-8"))["map_info"]
            width_m, height_m = float(map_info["width"]), float(map_info["height"])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{info_path}: no map_info width/height ({err!r})") from None
    plan = None
    plan_path = path / "geojson_map.json"
    if plan_path.is_file() and math.isfinite(width_m) and math.isfinite(height_m):
        geojson = json.loads(plan_path.read_text(encoding="utf-8"))
        try:
            plan = plan_to_metres(geojson, width_m, height_m)
        except (KeyError, IndexError, TypeError, ValueError) as err:
            raise ValueError(f"{plan_path}: not a floor plan ({err!r})") from None
    traces_dir = path / "path_data_files"
    trace_files: tuple[Path, ...] = ()
    if traces_dir.is_dir():
        trace_files = tuple(
            sorted(
                p
                for p in traces_dir.iterdir()
                if p.is_file() and p.name.endswith((".txt", ".txt.xz"))
            )
        )
    return IlcFloor(path.name, level, width_m, height_m, plan, trace_files)


def plan_to_metres(geojson: Mapping[str, Any], width_m: float, height_m: float) -> dict[str, Any]:
    """Convert an ILC ``geojson_map.json`` (lon/lat) into the waypoint frame (metres).

    The bounding box of the first feature's coordinates maps linearly onto
    ``[0, width_m] x [0, height_m]``: x from the minimum longitude, y from the minimum
    latitude. Properties are copied, without ``center``, ``point`` and ``points``
    (positions in lon/lat or Web-Mercator, which would disagree with the geometry), and
    with ``kind`` set to ``"outline"`` on the first feature and ``"unit"`` on the others.

    Parameters
    ----------
    geojson : mapping
        A FeatureCollection whose first feature is the floor outline.
    width_m, height_m : float
        ``map_info`` of ``floor_info.json``.

    Returns
    -------
    dict
        A FeatureCollection with the same geometry types, coordinates in metres,
        ``bbox = [0, 0, width_m, height_m]`` and ``source_lonlat_bbox = [lon_min,
        lat_min, lon_max, lat_max]`` (the box that maps onto ``bbox``).
    """
    features = geojson["features"]
    lonlat = _coordinates(features[0]["geometry"]["coordinates"])
    lo = lonlat.min(axis=0)
    span = lonlat.max(axis=0) - lo
    if not (np.all(np.isfinite(span)) and np.all(span > 0)):
        raise ValueError("the first feature has an empty bounding box")
    scale = np.array([width_m, height_m]) / span

    def convert(coordinates: Any) -> Any:
        if _is_position(coordinates):  # a Point
            return ((np.asarray(coordinates[:2], dtype=np.float64) - lo) * scale).tolist()
        if coordinates and _is_position(coordinates[0]):  # a ring or a line
            positions = np.array([c[:2] for c in coordinates], dtype=np.float64)
            return ((positions - lo) * scale).tolist()
        return [convert(c) for c in coordinates]

    out = []
    for index, feature in enumerate(features):
        properties = {
            k: v
            for k, v in (feature.get("properties") or {}).items()
            if k not in _PLAN_FOREIGN_FRAME_KEYS
        }
        properties["kind"] = "outline" if index == 0 else "unit"
        geometry = feature["geometry"]
        out.append(
            {
                "type": "Feature",
                "geometry": {
                    "type": geometry["type"],
                    "coordinates": convert(geometry["coordinates"]),
                },
                "properties": properties,
            }
        )
    return {
        "type": "FeatureCollection",
        "bbox": [0.0, 0.0, width_m, height_m],
        # the lon/lat box that maps onto bbox, so the conversion can be undone
        "source_lonlat_bbox": [*lo.tolist(), *(lo + span).tolist()],
        "features": out,
    }


def _coordinates(nested: Any) -> NDArray[np.float64]:
    """All positions of a GeoJSON coordinates array as (n, 2) lon/lat."""
    points: list[list[float]] = []
    stack = [nested]
    while stack:
        item = stack.pop()
        if _is_position(item):
            points.append([float(item[0]), float(item[1])])
        else:
            stack.extend(item)
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


def _is_position(item: Any) -> bool:
    return (
        isinstance(item, list)
        and len(item) >= 2
        and all(isinstance(v, int | float) for v in item[:2])
    )
