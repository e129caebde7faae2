"""The local metric frame of an IPIN 2023 Track 3 venue.

Latitude/longitude go to the venue's local frame (x east, y north, metres), the
East-North plane tangent to the WGS-84 ellipsoid at the venue origin
(``pymap3d.geodetic2enu``, height 0: at 350 m above the ellipsoid the scale differs by
5e-5, 6 mm over the venue). The origin is the south-west corner of the bounding box of
the venue's ``references.csv`` landmarks (``pointID, Lat, Lon``; ``venue_frame``), so
every log of a venue shares one frame and the walked area has positive coordinates (all
34 POSI landmarks of the dev logs lie inside that box).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class LocalFrame:
    """A local East-North frame tangent to the WGS-84 ellipsoid at an origin.

    Attributes
    ----------
    origin_lat_deg, origin_lon_deg : float
        Geodetic origin (degrees).
    origin_h_m : float
        Ellipsoidal height of the origin; points are taken at this height too.
    """

    origin_lat_deg: float
    origin_lon_deg: float
    origin_h_m: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.origin_lat_deg) and -90.0 < self.origin_lat_deg < 90.0):
            raise ValueError(f"origin_lat_deg must be in (-90, 90), got {self.origin_lat_deg}")
        if not (math.isfinite(self.origin_lon_deg) and -180.0 <= self.origin_lon_deg <= 180.0):
            raise ValueError(f"origin_lon_deg must be in [-180, 180], got {self.origin_lon_deg}")

    def to_local(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
        """WGS-84 latitude/longitude to local metres.

        Parameters
        ----------
        lat_deg, lon_deg : array_like, shape (n,)

        Returns
        -------
        ndarray, shape (n, 2), float64
            ``(x east, y north)`` in metres.
        """
        lat = np.asarray(lat_deg, dtype=np.float64).reshape(-1)
        lon = np.asarray(lon_deg, dtype=np.float64).reshape(-1)
        if lat.shape != lon.shape:
            raise ValueError(f"lon_deg must have shape {lat.shape}, got {lon.shape}")
        if lat.size == 0:
            return np.empty((0, 2))
        east, north, _ = pymap3d.geodetic2enu(
            lat, lon, self.origin_h_m, self.origin_lat_deg, self.origin_lon_deg, self.origin_h_m
        )
        return np.column_stack([np.asarray(east, np.float64), np.asarray(north, np.float64)])

    def to_geodetic(self, xy_m: ArrayLike) -> NDArray[np.float64]:
        """Local metres back to WGS-84 (the inverse of ``to_local``).

        Parameters
        ----------
        xy_m : array_like, shape (n, 2)

        Returns
        -------
        ndarray, shape (n, 2), float64
            ``(lat_deg, lon_deg)``.
        """
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if xy.shape[0] == 0:
            return np.empty((0, 2))
        lat, lon, _ = pymap3d.enu2geodetic(
            xy[:, 0],
            xy[:, 1],
            np.zeros(xy.shape[0]),
            self.origin_lat_deg,
            self.origin_lon_deg,
            self.origin_h_m,
        )
        return np.column_stack([np.asarray(lat, np.float64), np.asarray(lon, np.float64)])


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a venue CSV file, keys and values stripped."""
    with path.open(encoding="utf-8", newline="") as f:
        return [{k.strip(): (v or "").strip() for k, v in row.items()} for row in csv.DictReader(f)]


def references(venue_dir: Path) -> dict[str, tuple[float, float]]:
    """The venue's landmarks, ``(lat_deg, lon_deg)`` by point id, in file order."""
    rows = read_csv(venue_dir / "references.csv")
    return {r["pointID"]: (float(r["Lat"]), float(r["Lon"])) for r in rows}


def venue_frame(venue_dir: Path) -> LocalFrame:
    """The local frame of a venue: origin at the south-west corner of the bounding box of
    its ``references.csv`` landmarks, height 0.

    Raises
    ------
    OSError
        When ``references.csv`` cannot be read.
    ValueError
        When it holds no landmark or a value that is not a number.
    """
    points = np.array(list(references(venue_dir).values()), dtype=np.float64).reshape(-1, 2)
    if points.shape[0] == 0 or not np.isfinite(points).all():
        raise ValueError(f"{venue_dir / 'references.csv'}: no landmarks")
    return LocalFrame(float(points[:, 0].min()), float(points[:, 1].min()))
