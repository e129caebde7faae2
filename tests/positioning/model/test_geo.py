"""Local positions in WGS84: checked against geodesics on the WGS84 ellipsoid computed by
geographiclib, an implementation independent of the one the service uses."""

from __future__ import annotations

import math

import pymap3d
import pytest
from geographiclib.geodesic import Geodesic
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.model.geo import GeoReference, heading_from_north_deg, to_world


def geodesic_target(ref: GeoReference, x_m: float, y_m: float) -> tuple[float, float]:
    """Where a walk of ``hypot(x, y)`` metres from the origin, at the bearing of the local
    direction (x, y), ends on the ellipsoid."""
    bearing = math.degrees(math.atan2(x_m, y_m) + ref.rotation_rad)
    end = Geodesic.WGS84.Direct(
        ref.origin_lat_deg, ref.origin_lon_deg, bearing, math.hypot(x_m, y_m)
    )
    return end["lat2"], end["lon2"]


def apart_m(a: tuple[float, float], b: tuple[float, float]) -> float:
    return float(Geodesic.WGS84.Inverse(a[0], a[1], b[0], b[1])["s12"])


@given(
    lat=st.floats(-80.0, 80.0),
    lon=st.floats(-180.0, 180.0),
    rotation=st.floats(-math.pi, math.pi),
    x=st.floats(-500.0, 500.0),
    y=st.floats(-500.0, 500.0),
)
def test_a_local_point_lies_where_the_geodesic_ends(
    lat: float, lon: float, rotation: float, x: float, y: float
) -> None:
    ref = GeoReference(lat, lon, rotation)
    assert apart_m(to_world(x, y, ref), geodesic_target(ref, x, y)) < 0.1


def test_the_origin_and_the_axes() -> None:
    ref = GeoReference(22.3043, 114.1795)  # north-up: y is north, x is east
    assert to_world(0.0, 0.0, ref) == pytest.approx((22.3043, 114.1795), abs=1e-12)
    north = to_world(0.0, 100.0, ref)
    east = to_world(100.0, 0.0, ref)
    assert north[0] > ref.origin_lat_deg
    assert north[1] == pytest.approx(ref.origin_lon_deg, abs=1e-12)
    assert east[1] > ref.origin_lon_deg
    assert apart_m(north, (ref.origin_lat_deg, ref.origin_lon_deg)) == pytest.approx(100, abs=0.01)
    # a building turned so that its y axis points east: local +y is east, +x is south
    turned = GeoReference(22.3043, 114.1795, math.pi / 2)
    assert apart_m(to_world(0.0, 100.0, turned), east) < 0.01
    assert to_world(100.0, 0.0, turned)[0] < ref.origin_lat_deg


@pytest.mark.parametrize(
    ("heading_rad", "rotation_rad", "expected_deg"),
    [
        (0.0, 0.0, 0.0),
        (math.pi / 2, 0.0, 90.0),
        (-math.pi / 2, 0.0, 270.0),
        (0.0, math.radians(30), 30.0),
        (math.pi, math.radians(30), 210.0),
        (math.radians(350), math.radians(20), 10.0),
    ],
)
def test_headings_from_north(heading_rad: float, rotation_rad: float, expected_deg: float) -> None:
    assert heading_from_north_deg(heading_rad, rotation_rad) == pytest.approx(
        expected_deg, abs=1e-9
    )


def test_a_heading_a_hair_west_of_north_is_not_360() -> None:
    assert heading_from_north_deg(-1e-17, 0.0) == 0.0


@settings(max_examples=200, deadline=None)
@given(
    lat=st.floats(-89.0, 89.0),
    lon=st.floats(-180.0, 180.0),
    rotation=st.floats(-7.0, 7.0),
    x=st.floats(-3000.0, 3000.0),
    y=st.floats(-3000.0, 3000.0),
)
def test_the_closed_form_is_pymap3ds_exact_transform(
    lat: float, lon: float, rotation: float, x: float, y: float
) -> None:
    """``to_world``'s closed form against ``pymap3d.enu2geodetic``: the same point, to
    well under a millimetre (1e-10 degrees)."""
    ref = GeoReference(lat, lon, rotation)
    c, s = math.cos(rotation), math.sin(rotation)
    want_lat, want_lon, _ = pymap3d.enu2geodetic(x * c + y * s, -x * s + y * c, 0.0, lat, lon, 0.0)
    got_lat, got_lon = to_world(x, y, ref)
    assert got_lat == pytest.approx(float(want_lat), abs=1e-10)
    assert (got_lon - float(want_lon) + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-10)
