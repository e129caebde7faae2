"""What an engine may know of a site: its floors, its maps, its anchors and the models
learned from its maps' training data."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from server.positioning.magnetic.field_grid import MagneticMap
from server.positioning.model.geo import GeoReference
from server.positioning.plan.anchors import Anchor
from server.positioning.plan.floor_plan import FloorPlan
from server.positioning.plan.navigation_graph import FloorGraph
from server.positioning.plan.zones import NO_ZONES, ZoneIndex
from server.positioning.radio import fix_error
from server.positioning.radio.accuracy_indicators import FaiMaps
from server.positioning.radio.fingerprints import RadioMap
from server.positioning.radio.fix_error import FixErrorModel
from server.positioning.radio.scan_matching import ScanMap


@dataclass(frozen=True, slots=True)
class FloorRef:
    """One floor of a site; engines refer to floors by index into ``SiteMaps.floors``."""

    building_id: str
    floor_id: str
    level: int
    rotation_rad: float = 0.0  # bearing of the building's y axis, clockwise from north
    geo: GeoReference | None = None  # where the building sits on the Earth, when it is known


@dataclass(frozen=True)
class SiteMaps:
    """Everything an engine may read about a site: its floors and its maps."""

    floors: tuple[FloorRef, ...]
    radio: RadioMap | None
    version: str  # changes whenever any map of the site changes
    anchors: tuple[Anchor, ...] = ()
    plans: tuple[FloorPlan | None, ...] = ()  # per floor index; missing or None: no plan
    magnetic: MagneticMap | None = None
    # dB a device model reads above the map's common level (subtracted from its scans
    # before they reach an engine; services.device_offsets)
    device_offsets: Mapping[str, float] = field(default_factory=dict)
    # how far a radio fix is from the truth by its evidence (learned from the map's
    # training data where it was; fix_error.DEFAULT otherwise)
    fix_error: FixErrorModel = fix_error.DEFAULT
    # what the fingerprinting accuracy indicators read of the radio map (fai_ekf); None:
    # not built, the indicators that need it are not computed
    fai: FaiMaps | None = None
    # per floor index: the reference-point graph (navigation_graph; map_markov); missing or
    # None: none built
    graphs: tuple[FloorGraph | None, ...] = ()
    # the surveyed scans themselves, matched scan by scan (scan_matching); None: not
    # built, scans are matched against the radio map's cells
    scans: ScanMap | None = None
    # hPa between adjacent floors (barometer.floor_spacing, from the map's walks that
    # changed floor); None: barometer.DEFAULT_SPACING_HPA
    floor_spacing_hpa: float | None = None
    # the site's zones (no engine reads them: the service says which a fix is in)
    zones: ZoneIndex = NO_ZONES
    # per floor index: the plan as sent (GeoJSON), and a digest of them all (the routing
    # graph is built once per digest; no engine reads them)
    plan_geojson: tuple[Mapping[str, Any] | None, ...] = ()
    plan_digest: str = ""
