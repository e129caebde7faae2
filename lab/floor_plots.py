"""Figures on a floor's plan: the plan itself (GeoJSON outlines, units and lines in the
building's metric frame, ``draw_plan`` and ``floor_axes``, which the tracks of
``evaluation_plots`` are drawn on too), a floor's survey plan and its magnetic map.

matplotlib is needed to draw them (``plot_canvas``).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lab.plot_canvas import figure, save
from server.positioning.magnetic.field_grid import MagneticGrid

if TYPE_CHECKING:
    from matplotlib.axes import Axes

FloatArray = NDArray[np.float64]


def _coords(positions: Any) -> FloatArray:
    """GeoJSON positions as (n, 2) x, y; empty when they are not a list of positions."""
    try:
        array = np.asarray(positions, dtype=np.float64)
    except (TypeError, ValueError):  # ragged or not numbers: not drawn
        return np.zeros((0, 2))
    if array.ndim != 2 or array.shape[1] < 2:
        return np.zeros((0, 2))
    return array[:, :2]


def _geometry_parts(geometry: Any) -> Iterator[tuple[str, list[FloatArray]]]:
    """("polygon", rings) and ("line", [points]) parts of a GeoJSON geometry in metres."""
    if not isinstance(geometry, Mapping):
        return
    kind = geometry.get("type")
    coords: Any = geometry.get("coordinates")
    if kind == "Polygon":
        yield "polygon", [_coords(ring) for ring in coords]
    elif kind == "MultiPolygon":
        for polygon in coords:
            yield "polygon", [_coords(ring) for ring in polygon]
    elif kind == "LineString":
        yield "line", [_coords(coords)]
    elif kind == "MultiLineString":
        for line in coords:
            yield "line", [_coords(line)]
    elif kind == "GeometryCollection":
        for part in geometry.get("geometries", ()):
            yield from _geometry_parts(part)
    # points and unknown types are not drawn


# floor plan styles by properties.kind: (face colour, edge colour, line width, z-order)
_STYLES: dict[str, tuple[str, str, float, float]] = {
    "outline": ("none", "0.15", 1.4, 2.0),
    "unit": ("0.9", "0.6", 0.6, 1.0),
}
_OTHER = ("none", "0.55", 0.8, 1.0)


def draw_plan(ax: Axes, plan: Mapping[str, Any]) -> None:
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    for feature in plan.get("features", ()):
        if not isinstance(feature, Mapping):
            continue
        properties = feature.get("properties") or {}
        kind = properties.get("kind")
        style = _STYLES.get(kind, _OTHER) if isinstance(kind, str) else _OTHER
        facecolor, edgecolor, linewidth, zorder = style
        for part, arrays in _geometry_parts(feature.get("geometry")):
            rings = [a for a in arrays if a.shape[0] >= 2]
            if not rings:
                continue
            if part == "line":
                ax.plot(rings[0][:, 0], rings[0][:, 1], "-", color=edgecolor, lw=linewidth)
                continue
            # rings as one compound path: holes (wound the other way, RFC 7946) stay empty
            path = MplPath.make_compound_path(*(MplPath(ring, closed=True) for ring in rings))
            patch = PathPatch(
                path, facecolor=facecolor, edgecolor=edgecolor, linewidth=linewidth, zorder=zorder
            )
            ax.add_patch(patch)


def floor_axes(ax: Axes, title: str) -> None:
    """Metres of the floor frame at equal scale, the title, a legend when anything is
    labelled."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(title)
    if ax.get_legend_handles_labels()[1]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")


def plot_survey_plan(
    out: Path,
    *,
    title: str,
    plan: Mapping[str, Any] | None,
    points_xy_m: ArrayLike,
    from_aps: ArrayLike,
    surveyed: ArrayLike,
    rp_xy_m: ArrayLike,
    ap_xy_m: ArrayLike,
) -> Path:
    """A floor's reference-point placement plan (``mapping.survey_plan``) on its plan:
    the current map's reference points (grey), the located access points (triangles), the
    planned points marked along the access points' grid lines and by the coverage pass,
    filled where the current map already has them."""
    fig = figure(10.0, 7.0)
    ax = fig.add_subplot()
    if plan:
        draw_plan(ax, plan)
    rps = _coords(rp_xy_m)
    if rps.size:
        ax.plot(rps[:, 0], rps[:, 1], ".", color="0.65", ms=2, zorder=4, label="current RPs")
    pts = _coords(points_xy_m)
    line = np.asarray(from_aps, dtype=bool).reshape(-1)
    done = np.asarray(surveyed, dtype=bool).reshape(-1)
    for rule, colour, label in ((line, "tab:orange", "AP lines"), (~line, "tab:blue", "coverage")):
        for have, fill in ((done, colour), (~done, "none")):
            sel = rule & have
            if sel.any():
                state = "surveyed" if fill != "none" else "to survey"
                ax.plot(
                    pts[sel, 0],
                    pts[sel, 1],
                    "o",
                    mec=colour,
                    mfc=fill,
                    ms=4,
                    zorder=6,
                    label=f"{label}, {state}",
                )
    aps = _coords(ap_xy_m)
    if aps.size:
        ax.plot(aps[:, 0], aps[:, 1], "^", color="tab:red", ms=6, zorder=7, label="located APs")
    floor_axes(ax, title)
    return save(fig, out)


def plot_magnetic_grid(
    out: Path,
    *,
    title: str,
    plan: Mapping[str, Any] | None,
    grid: MagneticGrid,
) -> Path:
    """The floor plan with a floor's magnetic map: the mean field magnitude per cell.

    Parameters
    ----------
    out : Path
        PNG file to write; its directory is created when missing.
    title : str
    plan : mapping, optional
        GeoJSON FeatureCollection in the building's metric frame, drawn as in
        ``plot_track``; the plan's unit fills lie over the map, its outline on top.
    grid : MagneticGrid
        Cell ``(row, col)`` is drawn over ``[x0 + col c, x0 + (col + 1) c) x
        [y0 + row c, y0 + (row + 1) c)``; unknown (NaN) cells are left transparent.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    RuntimeError
        When matplotlib is not installed.
    """
    fig = figure(8.0, 6.0)
    ax = fig.add_subplot()
    if plan is not None:
        draw_plan(ax, plan)
    ny, nx = grid.magnitude.shape
    x0, y0 = grid.origin_m
    magnitude_ut = np.ma.masked_invalid(grid.magnitude.astype(np.float64))
    image = ax.imshow(
        magnitude_ut,
        origin="lower",  # row 0 is the lowest y
        extent=(x0, x0 + nx * grid.cell_m, y0, y0 + ny * grid.cell_m),
        interpolation="nearest",
        cmap="viridis",
        zorder=0.5,
    )
    fig.colorbar(image, ax=ax, label="field magnitude |B| (µT)", shrink=0.8)
    floor_axes(ax, title)
    return save(fig, out)
