"""How good a floor's maps are: coverage, cells, freshness, emitters."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import Field

from server.api.schemas.common import LAX_ARRAY, Strict


class MapVersionRef(Strict):
    id: str
    version: int


class Percentiles(Strict):
    p10: float
    p50: float
    p90: float


class MapCoverage(Strict):
    radio: float | None = Field(
        description="share of the walkable 1 m cells (centre walkable) holding a reference "
        "point of this floor; without a plan, of the 1 m cells of the reference points' "
        "bounding box; null when the plan has no walkable cell"
    )
    magnetic: float | None = Field(
        description="share of the walkable cells of the magnetic grid's lattice (0.5 m, "
        "centre walkable) whose field is known; without a plan, of the grid's own cells"
    )
    walkable_area_known: bool = Field(
        description="the floor has a usable plan, so the shares are over its walkable area"
    )


class RadioCellsQuality(Strict):
    n_reference_points: int = Field(description="reference points of this floor")
    readings_per_rp: Percentiles | None = Field(
        description="RSS readings (all emitters) folded into a reference point"
    )
    emitters_per_rp: Percentiles | None = Field(description="emitters heard at a reference point")
    var_db2: Percentiles | None = Field(
        description="RSS variance (dB²) over reference point x emitter entries with at least "
        "2 readings"
    )


class MagneticCellsQuality(Strict):
    known_cells: int = Field(description="grid cells with a known field")
    samples_per_cell: Percentiles | None = Field(description="samples per known cell")
    var_ut2: Percentiles | None = Field(
        description="field magnitude variance (µT²) over cells with at least 2 samples"
    )


class MapFreshness(Strict):
    newest: datetime | None = Field(description="creation time of the newest survey point")
    oldest: datetime | None = Field(description="creation time of the oldest survey point")
    n_cells: int = Field(description="1 m cells holding survey points")
    cell_age_days: Percentiles | None = Field(
        description="per 1 m cell with survey points: days since its newest point was created"
    )
    n_points: int = Field(description="survey points of this floor")
    n_surveyed_points: int = Field(description="points surveyed through the admin API")
    n_uploads: int = Field(description="distinct uploads that contributed points")


class EmitterPositionOut(Strict):
    kind: Literal["wifi", "ble"]
    key: str = Field(description="lower-cased BSSID or beacon id")
    x_m: float
    y_m: float
    xy_std_m: Annotated[tuple[float, float], LAX_ARRAY] | None = Field(
        description="standard deviations of x and y from the fit; null when the noise cannot "
        "be estimated (exactly 4 readings)"
    )
    p0_dbm: float = Field(description="RSS at 1 m")
    exponent: float = Field(description="path-loss exponent")
    n: int = Field(description="readings fitted")
    residual_rms_db: float


class EmitterQuality(Strict):
    seen: int = Field(description="emitters heard at a reference point of this floor")
    fixed: int = Field(
        description="WiFi APs identified as fixed on this floor from the timed survey "
        "readings (heard on 4+ days, once above -55 dBm, strong readings clustered in "
        "under 100 m²)"
    )
    retired: int = Field(
        description="seen emitters that no survey point of this floor heard in the "
        "retired_after_days days before the floor's newest survey point"
    )
    positions: list[EmitterPositionOut] = Field(
        description="log-distance fits of the max_emitters most-read emitters, where the "
        "readings determine one"
    )
    unlocated: int = Field(
        description="emitters among the max_emitters most-read whose fit is under-determined"
    )


class MapQualityRead(Strict):
    floor_id: str
    radio_map: MapVersionRef | None = Field(description="the building's latest radio map")
    magnetic_map: MapVersionRef | None = Field(description="the floor's latest magnetic map")
    coverage: MapCoverage
    radio_cells: RadioCellsQuality
    magnetic_cells: MagneticCellsQuality
    freshness: MapFreshness
    emitters: EmitterQuality


class PointGeometry(Strict):
    type: Literal["Point"] = "Point"
    coordinates: tuple[float, float] = Field(description="x, y in metres of the floor frame")


class PlannedPointProperties(Strict):
    kind: Literal["reference_point"] = "reference_point"
    rule: Literal["ap_line", "coverage"] = Field(
        description="ap_line: marked along a grid line through a located access point "
        "(Algorithm 1 of Wang et al.); coverage: a walkable point no mark was within a noise "
        "distance of"
    )
    surveyed: bool = Field(
        description="the current radio map has a reference point within one grid gap"
    )


class PlannedPoint(Strict):
    type: Literal["Feature"] = "Feature"
    geometry: PointGeometry
    properties: PlannedPointProperties


class SurveyPlanSummary(Strict):
    floor_id: str
    n_points: int
    n_surveyed: int = Field(description="planned points the current map already has")
    grid_m: float = Field(description="gap of the grid the points were chosen on")
    noise_db: float = Field(description="RSS noise δ the noise distance follows from")
    noise_source: Literal["map", "default", "given"] = Field(
        description="map: the median RSS standard deviation of the floor's radio map; default: "
        "4 dB (no repeated readings); given: a constant noise distance was asked for"
    )
    n_access_points: int = Field(description="access points located by their path loss")
    expected_error_m: float = Field(
        description="mean distance from a walkable grid point to its nearest planned point: "
        "the error of a nearest-point fix once the plan is surveyed"
    )
    expected_error_p90_m: float


class SurveyPlanRead(Strict):
    """Where to put reference points on a floor, as a GeoJSON FeatureCollection."""

    type: Literal["FeatureCollection"] = "FeatureCollection"
    features: list[PlannedPoint]
    properties: SurveyPlanSummary


class CoverageCells(Strict):
    """Per figure, the grid's cells as rows (south to north) of columns (west to east):
    ``readings[i][j]`` is the cell ``[x0 + j c, x0 + (j + 1) c) x [y0 + i c, y0 + (i + 1) c)``
    with ``(x0, y0) = origin_m`` and ``c = cell_m``."""

    in_area: list[list[bool]] = Field(
        description="the cell overlaps the plan's walkable area (every cell without a plan)"
    )
    readings: list[list[int]] = Field(
        description="RSS readings (all emitters) folded into the radio map's reference "
        "points in the cell"
    )
    points: list[list[int]] = Field(description="survey points in the cell")
    emitters: list[list[int]] = Field(
        description="distinct emitters heard at the reference points in the cell"
    )
    var_db2: list[list[float | None]] = Field(
        description="mean RSS variance (dB²) of the cell's reference point x emitter entries "
        "with at least 2 readings; null without one"
    )
    age_days: list[list[float | None]] = Field(
        description="days since the newest survey point of the cell was made; null without one"
    )
    nearest_rp_m: list[list[float | None]] = Field(
        description="distance d from the cell's centre to the floor's nearest reference "
        "point; null when the floor has none"
    )
    expected_error_m: list[list[float | None]] = Field(
        description="RMS radial error of a radio fix at the cell's centre, sqrt(2σ² + d²): σ "
        "the fix-error table's per-axis error of a scan matching the emitters heard at the "
        "nearest reference point (the better of WiFi and BLE), d the distance to it (the "
        "map has nothing nearer); null when the floor has no reference point"
    )


class CoverageGridRead(Strict):
    """Where a floor's radio map is thin: a grid of square cells over its walkable area
    (without a plan, over the box of its reference points and survey points)."""

    floor_id: str
    radio_map: MapVersionRef | None = Field(description="the building's latest radio map")
    fix_error: Literal["learned", "default"] = Field(
        description="learned: the fix-error table learned with the radio map; default: the "
        "table used when none was learned (no map, or none learned for it)"
    )
    walkable_area_known: bool = Field(description="the grid is laid over the floor's plan")
    origin_m: Annotated[tuple[float, float], LAX_ARRAY] = Field(
        description="x, y of the south-west corner of cell [0][0] (m, floor frame)"
    )
    cell_m: float = Field(description="side of a cell (m)")
    rows: int = Field(description="cells along y; 0 for a floor with neither plan nor data")
    cols: int = Field(description="cells along x")
    cells: CoverageCells
