"""The IPIN venue frame against geodesics on the WGS-84 ellipsoid, on the dev venue."""

from __future__ import annotations

import numpy as np
from geographiclib.geodesic import Geodesic

from lab.datasets.ipin import IpinVenue
from lab.datasets.ipin_frame import LocalFrame
from lab.datasets.ipin_log import IpinLog


def _geodesic_east_north(frame: LocalFrame, lat: float, lon: float) -> tuple[float, float]:
    """East and north of a point from the frame origin: geodesic distance and azimuth on
    the WGS-84 ellipsoid (GeographicLib), an independent way to the same metres."""
    g = Geodesic.WGS84.Inverse(frame.origin_lat_deg, frame.origin_lon_deg, lat, lon)
    azimuth = np.radians(g["azi1"])
    return float(g["s12"] * np.sin(azimuth)), float(g["s12"] * np.cos(azimuth))


def test_positions_match_geodesics(log: IpinLog, venue: IpinVenue) -> None:
    frame = venue.frame
    points = [
        (tuple(latlon), tuple(xy))
        for latlon, xy in zip(log.waypoint_lat_lon_deg, log.trace.waypoint_xy_m, strict=True)
    ]
    points += [((b.lat_deg, b.lon_deg), (b.x_m, b.y_m)) for b in venue.beacons]
    for (lat, lon), (x, y) in points:
        east, north = _geodesic_east_north(frame, lat, lon)
        assert abs(x - east) < 0.1
        assert abs(y - north) < 0.1
    # the frame is the venue's whatever reads the log, and it inverts
    latlon = frame.to_geodetic(log.trace.waypoint_xy_m)
    np.testing.assert_allclose(latlon, log.waypoint_lat_lon_deg, atol=1e-9)
    assert frame.to_local([], []).shape == (0, 2)
