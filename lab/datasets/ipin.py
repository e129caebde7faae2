"""The IPIN 2023 Track 3 (smartphone, off-site) venue: its logs, beacons and landmarks.

Layout of a venue (as under ``../shared/data/ipin2023-track3-dev/``; data: Torres-Sospedra
et al., Zenodo 2023, doi:10.5281/zenodo.8362205)::

    <venue>/logs/IPIN2023_T3_TrainingTrial<TT>_repetition<RR>.txt[.xz]   one phone log
    <venue>/BLE_Locations.csv     bleID, Lat, Lon, floor: the installed iBeacons
    <venue>/references.csv        pointID, Lat, Lon: landmarks of the venue

A venue is listed here, its logs are not read: ``ipin_log.read_log`` reads one, in the
venue's frame (``ipin_frame.venue_frame``). A floor's extent is the box of the landmarks
and beacons with a margin of ``VENUE_MARGIN_M``.

Beacons: ``BLE_Locations.csv`` names beacons ``BLE1`` ... ``BLE6``; the logs name them by
MAC (``BE:AC:20:23:00:01`` ... ``:06``, minor 1 ... 6), and the numbers do not match by
place (on the dev logs the 20 strongest readings of ``:02`` centre 3 m from BLE3, those
of ``:03`` 1 m from BLE2), so no beacon of the file is tied to a MAC here.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from lab.datasets.ilc import IlcFloor, IlcSite
from lab.datasets.ipin_frame import LocalFrame, read_csv, references, venue_frame
from lab.datasets.ipin_log import log_name_ids
from server.storage.text_records import file_id

VENUE_LEVELS = (-2, -1, 0)
"""Floors of the IPIN 2023 venue (Museum Industriekultur, Nuremberg): 0, -1 and -2."""

VENUE_MARGIN_M = 5.0
"""Margin around the landmarks and beacons that makes a floor's extent."""


@dataclass(frozen=True, slots=True)
class LogFile:
    """One log of a venue, not read."""

    path: Path
    trial: int
    repetition: int

    @property
    def log_id(self) -> str:
        """File name without ``.txt`` / ``.txt.xz``."""
        return file_id(self.path)


@dataclass(frozen=True, slots=True)
class Beacon:
    """An installed beacon of ``BLE_Locations.csv``."""

    beacon_id: str
    level: int
    lat_deg: float
    lon_deg: float
    x_m: float
    y_m: float


@dataclass(frozen=True, eq=False)
class IpinVenue:
    """A venue: its frame, floors, logs, beacons and landmarks.

    Attributes
    ----------
    name : str
        Directory name.
    frame : LocalFrame
        ``venue_frame``: shared by every log.
    floors : tuple of IlcFloor
        By level (``VENUE_LEVELS`` and the beacons' floors), named by the level
        (``"-2"``, ``"-1"``, ``"0"``); all of one extent ``[0, width_m] x [0, height_m]``
        (landmarks and beacons with ``VENUE_MARGIN_M``); no plans, no trace files.
    logs : tuple of LogFile
        ``logs/*.txt`` and ``*.txt.xz``, by (trial, repetition).
    beacons : tuple of Beacon
        In file order.
    references_xy_m : Mapping of str to tuple of float
        Landmark positions by point id, in the frame.
    """

    name: str
    frame: LocalFrame
    floors: tuple[IlcFloor, ...]
    logs: tuple[LogFile, ...]
    beacons: tuple[Beacon, ...]
    references_xy_m: Mapping[str, tuple[float, float]]

    @property
    def site(self) -> IlcSite:
        """The venue as an ILC site (its floors), for what builds maps per floor."""
        return IlcSite(self.name, self.floors)

    def floor_index(self, level: int) -> int:
        """Index of a level in ``floors``; -1 when the venue has no such floor."""
        levels = [f.level for f in self.floors]
        return levels.index(level) if level in levels else -1


def read_venue(path: Path, levels: Iterable[int] = VENUE_LEVELS) -> IpinVenue:
    """Read a venue folder (``logs/``, ``BLE_Locations.csv``, ``references.csv``).

    Parameters
    ----------
    path : Path
        The venue folder.
    levels : iterable of int
        Floors of the venue; the beacons' floors are added.

    Returns
    -------
    IpinVenue
        Logs are listed, not read (``read_log(log.path, venue.frame)``).

    Raises
    ------
    ValueError
        A log whose name gives no trial and repetition, or a CSV value that is not a
        number. ``OSError`` when a CSV file or ``logs/`` is missing.
    """
    frame = venue_frame(path)
    landmarks = references(path)
    ref_xy = frame.to_local([p[0] for p in landmarks.values()], [p[1] for p in landmarks.values()])
    rows = read_csv(path / "BLE_Locations.csv")
    ble_xy = frame.to_local([float(r["Lat"]) for r in rows], [float(r["Lon"]) for r in rows])
    beacons = tuple(
        Beacon(r["bleID"], int(r["floor"]), float(r["Lat"]), float(r["Lon"]), float(x), float(y))
        for r, (x, y) in zip(rows, ble_xy.tolist(), strict=True)
    )
    corner = np.vstack([ref_xy, ble_xy]).max(axis=0) + VENUE_MARGIN_M
    width_m, height_m = float(corner[0]), float(corner[1])
    floors = tuple(
        IlcFloor(str(level), level, width_m, height_m, None, ())
        for level in sorted(set(levels) | {b.level for b in beacons})
    )
    logs = []
    for file in sorted((path / "logs").iterdir()):
        if not (file.is_file() and file.name.endswith((".txt", ".txt.xz"))):
            continue
        ids = log_name_ids(file)
        if ids is None:
            raise ValueError(f"{file}: the name gives no Trial<NN>_repetition<NN>")
        logs.append(LogFile(file, *ids))
    logs.sort(key=lambda log: (log.trial, log.repetition, log.path.name))
    return IpinVenue(
        name=path.resolve().name,
        frame=frame,
        floors=floors,
        logs=tuple(logs),
        beacons=beacons,
        references_xy_m=MappingProxyType(
            {k: (float(x), float(y)) for k, (x, y) in zip(landmarks, ref_xy.tolist(), strict=True)}
        ),
    )
