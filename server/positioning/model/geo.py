"""Where a building's local frame sits on the Earth, and a local position in WGS84.

A building is geo-referenced by its origin's latitude and longitude and the bearing ``θ``
(``rotation_rad``) of its y axis, clockwise from north. A local point ``(x, y)`` (metres)
lies in the east-north-up tangent plane at the origin at::

    e = x cos θ + y sin θ,        n = -x sin θ + y cos θ

(the inverse of the GNSS anchors' formula in ``mapping.anchors``), and ``(e, n, 0)`` becomes
latitude and longitude through the exact ENU-to-geodetic transform on the WGS84 ellipsoid
(``pymap3d.enu2geodetic``, heights 0: the transform the lab's IPIN venue frame uses). A
heading clockwise from the building's y axis is, from north, that heading plus ``θ``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pymap3d


@dataclass(frozen=True)
class GeoReference:
    """Where a building's local frame sits on the Earth."""

    origin_lat_deg: float
    origin_lon_deg: float
    rotation_rad: float = 0.0  # bearing of the building's y axis, clockwise from north

    def __post_init__(self) -> None:
        if not (math.isfinite(self.origin_lat_deg) and -90.0 < self.origin_lat_deg < 90.0):
            raise ValueError(f"origin_lat_deg must be in (-90, 90), got {self.origin_lat_deg}")
        if not (math.isfinite(self.origin_lon_deg) and -180.0 <= self.origin_lon_deg <= 180.0):
            raise ValueError(f"origin_lon_deg must be in [-180, 180], got {self.origin_lon_deg}")
        if not math.isfinite(self.rotation_rad):
            raise ValueError(f"rotation_rad must be finite, got {self.rotation_rad}")


def to_world(x_m: float, y_m: float, ref: GeoReference) -> tuple[float, float]:
    """The WGS84 ``(latitude, longitude)`` in degrees of the local point ``(x_m, y_m)``."""
    c, s = math.cos(ref.rotation_rad), math.sin(ref.rotation_rad)
    east, north = x_m * c + y_m * s, -x_m * s + y_m * c
    lat, lon, _ = pymap3d.enu2geodetic(
        east, north, 0.0, ref.origin_lat_deg, ref.origin_lon_deg, 0.0
    )
    return float(lat), float(lon)


def heading_from_north_deg(heading_rad: float, rotation_rad: float) -> float:
    """A heading clockwise from the building's y axis as degrees clockwise from north, in
    [0, 360), for a building whose y axis has the bearing ``rotation_rad``."""
    degrees = math.degrees(heading_rad + rotation_rad) % 360.0
    return 0.0 if degrees >= 360.0 else degrees  # a tiny negative sum rounds up to 360


def to_local(lat_deg: float, lon_deg: float, ref: GeoReference) -> tuple[float, float]:
    """The local ``(x_m, y_m)`` of a WGS84 point: the inverse of :func:`to_world`."""
    east, north, _ = pymap3d.geodetic2enu(
        lat_deg, lon_deg, 0.0, ref.origin_lat_deg, ref.origin_lon_deg, 0.0
    )
    c, s = math.cos(ref.rotation_rad), math.sin(ref.rotation_rad)
    return float(east * c - north * s), float(east * s + north * c)
