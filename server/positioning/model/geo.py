"""Where a building's local frame sits on the Earth, and a local position in WGS84.

A building is geo-referenced by its origin's latitude and longitude and the bearing ``θ``
(``rotation_rad``) of its y axis, clockwise from north. A local point ``(x, y)`` (metres)
lies in the east-north-up tangent plane at the origin at::

    e = x cos θ + y sin θ,        n = -x sin θ + y cos θ

(the inverse of the GNSS anchors' formula in ``mapping.anchors``), and ``(e, n, 0)`` becomes
latitude and longitude through the exact ENU-to-geodetic transform on the WGS84 ellipsoid
(heights 0: the transform ``pymap3d.enu2geodetic`` makes, which the lab's IPIN venue frame
uses): ENU to Earth-centred coordinates by the origin's rotation, then to latitude and
longitude by Heikkinen's closed form (Heikkinen 1982; Zhu 1994, "Conversion of Earth-centered
Earth-fixed coordinates to geodetic coordinates", IEEE TAES 30(3)), exact up to rounding,
in plain floating point: a few microseconds a point where pymap3d's array calls take a few
hundred (every fix of a geo-referenced building goes through it). A heading clockwise from
the building's y axis is, from north, that heading plus ``θ``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

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


_A = 6378137.0  # WGS84 semi-major axis (m)
_F = 1.0 / 298.257223563  # flattening
_B = _A * (1.0 - _F)
_E2 = _F * (2.0 - _F)  # first eccentricity squared
_EP2 = _E2 / (1.0 - _E2)  # second eccentricity squared


@lru_cache(maxsize=256)
def _frame(ref: GeoReference) -> tuple[float, ...]:
    """The origin in Earth-centred coordinates and the sines and cosines of its latitude,
    longitude and the building's rotation."""
    lat, lon = math.radians(ref.origin_lat_deg), math.radians(ref.origin_lon_deg)
    sin_lat, cos_lat, sin_lon, cos_lon = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    n = _A / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)  # prime vertical radius of curvature
    x0, y0, z0 = n * cos_lat * cos_lon, n * cos_lat * sin_lon, n * (1.0 - _E2) * sin_lat
    c, s = math.cos(ref.rotation_rad), math.sin(ref.rotation_rad)
    return x0, y0, z0, sin_lat, cos_lat, sin_lon, cos_lon, c, s


def to_world(x_m: float, y_m: float, ref: GeoReference) -> tuple[float, float]:
    """The WGS84 ``(latitude, longitude)`` in degrees of the local point ``(x_m, y_m)``."""
    x0, y0, z0, sin_lat, cos_lat, sin_lon, cos_lon, c, s = _frame(ref)
    east, north = x_m * c + y_m * s, -x_m * s + y_m * c
    # ENU (up 0) to Earth-centred
    x = x0 - sin_lon * east - sin_lat * cos_lon * north
    y = y0 + cos_lon * east - sin_lat * sin_lon * north
    z = z0 + cos_lat * north
    # Earth-centred to geodetic: Heikkinen's closed form
    r = math.hypot(x, y)
    f = 54.0 * _B * _B * z * z
    g = r * r + (1.0 - _E2) * z * z - _E2 * (_A * _A - _B * _B)
    cc = _E2 * _E2 * f * r * r / (g * g * g)
    ss = math.cbrt(1.0 + cc + math.sqrt(cc * cc + 2.0 * cc))
    p = f / (3.0 * (ss + 1.0 / ss + 1.0) ** 2 * g * g)
    q = math.sqrt(1.0 + 2.0 * _E2 * _E2 * p)
    r0 = -(p * _E2 * r) / (1.0 + q) + math.sqrt(
        _A * _A / 2.0 * (1.0 + 1.0 / q)
        - p * (1.0 - _E2) * z * z / (q * (1.0 + q))
        - p * r * r / 2.0
    )
    v = math.sqrt((r - _E2 * r0) ** 2 + (1.0 - _E2) * z * z)
    z_0 = _B * _B * z / (_A * v)
    lat = math.degrees(math.atan2(z + _EP2 * z_0, r))
    lon = math.degrees(math.atan2(y, x))
    return lat, lon


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
