"""Indoor Location Competition 2.0 (Microsoft / XYZ10) traces, floors and floor plans.

Layout of a site (as in the upstream repository and the sample under
``../shared/data/ilc20-sample/``)::

    <site>/<floor>/floor_info.json            {"map_info": {"width": .., "height": ..}} in metres
    <site>/<floor>/geojson_map.json           floor plan, WGS-84 lon/lat
    <site>/<floor>/path_data_files/<id>.txt   one phone trace (also ``<id>.txt.xz``)

A trace is tab separated, one record per line: ``unix_ms <TAB> TYPE_... <TAB> values``;
header lines start with ``#`` and carry ``key:value`` pairs (``SiteID``, ``FloorName``,
``startTime`` ...). Records read here:

=================================  ===============================================
``TYPE_WAYPOINT``                  x, y: ground truth in metres of the floor-map frame
``TYPE_ACCELEROMETER``             x, y, z, accuracy (m/s²)
``TYPE_GYROSCOPE``                 x, y, z, accuracy (rad/s)
``TYPE_MAGNETIC_FIELD``            x, y, z, accuracy (µT)
``TYPE_ROTATION_VECTOR``           x, y, z, accuracy (unit quaternion, vector part)
``TYPE_*_UNCALIBRATED``            x, y, z, bias_x, bias_y, bias_z, accuracy
``TYPE_WIFI``                      ssid, bssid, rssi (dBm), frequency (MHz), last_seen (ms)
``TYPE_BEACON``                    uuid, major, minor, tx_power, rssi (dBm), distance,
                                   mac, t (ms)
=================================  ===============================================

Other types (``TYPE_DIST1``, ``TYPE_BLUE``, ``TYPE_BLU4``,
``TYPE_SENSOR_MAGNETIC_FIELD_ACCURACY_CHANGED`` ...) are undocumented upstream; they are
skipped and counted per type.

The reader never fails on the content of a trace. A record with the wrong number of
fields, a timestamp that is not a decimal integer or a value that is not a finite number
is dropped and counted in ``bad_lines``. A line holding several records run together (a
newline lost in the file) is split where a 13-digit timestamp followed by a TAB and
``TYPE_`` starts again, and its records are read normally (counted in ``joined_lines``).
A compressed file that ends early keeps the records read up to that point and counts one
more bad line.

WiFi scans: the rows of one scan share the first-column timestamp (the scan time) and
become one ``WifiEvent``. Android also returns cached results (rows whose ``last_seen``
is older than the scan); by default they are kept, and ``wifi_max_age_ms`` drops them
(see ``WIFI_MAX_AGE_MS`` for the figures and why the default keeps them). A BSSID listed
twice in one scan (one radio announcing several SSIDs) keeps its strongest reading, as
``fingerprint.scan_vector`` does.

Floor plans: ``geojson_map.json`` is converted into the waypoint frame. The bounding box
of its first feature (the floor outline) maps linearly onto ``[0, width] x [0, height]``
of ``floor_info.json``: x grows with longitude from the minimum longitude, y with
latitude from the minimum latitude (checked on every site2 floor: all 3,054 waypoints
fall inside the outline and none inside a unit).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.datasets.records import keep_strongest, open_text, readings
from server.positioning.events import (
    BleEvent,
    Event,
    ImuEvent,
    WifiEvent,
    window_ble,
)

WIFI_MAX_AGE_MS: int | None = None
"""Oldest ``last_seen`` kept in a WiFi scan, in ms before the scan time (None: keep all).

Measured on site2 (every 10th trace): scans come every 2.0 s (median gap 2,005 ms); rows
first reported in a scan are 0.5-2 s old (the histogram drops sharply after 2 s), while
every row that repeats the previous scan's ``last_seen`` of the same BSSID (a cached
result, 39 % of all rows) is more than 2 s old. A 2,000 ms limit keeps the fresh rows and
drops all the repeats (63 % of all rows). Yet cached rows still say which access points
are near: on an inner validation split of site2's training paths (20 % of them, seed 5;
never the test paths) WKNN had a mean error of 16.8 m keeping every row against 17.7 m
with a 4 s limit, so the default keeps them.
"""

UPLOAD_RSSI_DBM = (-130.0, 0.0)
"""RSS a strict read (an upload) accepts, as the wire API does."""
UPLOAD_ID_CHARS = 64
"""Longest BSSID or beacon MAC a strict read accepts (printable ASCII, as the wire API)."""
UPLOAD_MAX_COORD_M = 100_000.0
"""Largest waypoint coordinate a strict read accepts (as the wire API's coordinates)."""

IMU_BLOCK_MS = 1000
"""Phone time covered by one ``ImuEvent`` of ``IlcTrace.imu_events``: a phone posting raw
samples about once a second (as the evaluation replays batches)."""

_RECORD_START = re.compile(r"(?=\d{13}\tTYPE_)")

# fields per record, timestamp and type included
_N_FIELDS_SENSOR = 6
_N_FIELDS_UNCALIBRATED = 9
_N_FIELDS_WAYPOINT = 4
_N_FIELDS_WIFI = 7
_N_FIELDS_BEACON = 10

_SENSOR_STREAMS = {
    "TYPE_ACCELEROMETER": "accel",
    "TYPE_GYROSCOPE": "gyro",
    "TYPE_MAGNETIC_FIELD": "magnetic",
    "TYPE_ROTATION_VECTOR": "rotation",
}
_UNCALIBRATED_STREAMS = {
    "TYPE_ACCELEROMETER_UNCALIBRATED": "accel",
    "TYPE_GYROSCOPE_UNCALIBRATED": "gyro",
    "TYPE_MAGNETIC_FIELD_UNCALIBRATED": "magnetic",
}
_STREAMS = ("accel", "gyro", "magnetic", "rotation")
_PLAN_FOREIGN_FRAME_KEYS = ("center", "point", "points")  # lon/lat or Web-Mercator values


@dataclass(frozen=True, eq=False)
class IlcTrace:
    """One phone trace.

    Attributes
    ----------
    path_id : str
        File name without ``.txt`` / ``.txt.xz``.
    floor : str
        Floor name, e.g. ``"F1"`` (the directory name; see ``read_trace``).
    site_id : str or None
        ``SiteID`` of the header, if present.
    waypoint_t_ms : ndarray, shape (n_wp,), int64
        Ground-truth times, sorted.
    waypoint_xy_m : ndarray, shape (n_wp, 2), float64
        Ground-truth positions in the floor-map frame (x east, y north), metres.
    wifi : tuple of WifiEvent
        One event per scan, sorted by time; readings keyed by lower-case BSSID.
    ble : tuple of BleEvent
        Beacon rows grouped into scans of ``events.BLE_WINDOW_MS`` (``window_ble``: one
        event per window, each beacon at its mean RSS), sorted by time; readings keyed by
        the beacon's MAC in lower case (``"<uuid>:<major>:<minor>"`` when a row has no
        MAC).
    accel, gyro, magnetic, rotation : ndarray, shape (n, 4), float64
        ``[t_ms, x, y, z]`` rows sorted by time: m/s², rad/s, µT, rotation-vector
        quaternion (x, y, z). Calibrated records; a stream with no calibrated record
        comes from the uncalibrated one with its bias estimate subtracted (what Android's
        calibrated value is) and is named in ``uncalibrated``. On site2 the two are
        logged at the same times; the magnetometer stand-in is nearly always the
        calibrated value, the accelerometer and gyroscope ones often hold a neighbouring
        sample (correlation 0.8-0.99 with the calibrated stream): close, not identical.
    uncalibrated : frozenset of str
        Streams (``"accel"``, ``"gyro"``, ``"magnetic"``) taken from uncalibrated records.
    bad_lines : int
        Records dropped because they could not be read.
    joined_lines : int
        Lines that held several records run together (their records were read).
    stale_wifi_readings : int
        WiFi rows dropped as older than ``WIFI_MAX_AGE_MS`` at their scan time.
    skipped_types : Mapping of str to int
        Records of types this reader does not read, per type.
    t_first_ms, t_last_ms : int
        First and last timestamp of the records read (0 and 0 when there are none).
    gnss : ndarray, shape (n_fix, 5), float64
        ``[t_ms, lat_deg, lon_deg, accuracy_m, hdop]`` satellite fixes (ILC files carry
        none; walks made of our own events and IPIN logs may); hdop NaN where unknown.
    pressure : ndarray, shape (n_p, 2), float64
        ``[t_ms, hPa]`` barometer rows sorted by time (ILC files carry none).
    waypoint_floor : ndarray, shape (n_wp,) or (0,), int64
        Level of each waypoint (0 ground floor, negative below) where the file gives one
        per waypoint (IPIN ``POSI`` lines); empty when the whole trace is on ``floor``.
    """

    path_id: str
    floor: str
    site_id: str | None
    waypoint_t_ms: NDArray[np.int64]
    waypoint_xy_m: NDArray[np.float64]
    wifi: tuple[WifiEvent, ...]
    ble: tuple[BleEvent, ...]
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64]
    magnetic: NDArray[np.float64]
    rotation: NDArray[np.float64]
    uncalibrated: frozenset[str]
    bad_lines: int
    joined_lines: int
    stale_wifi_readings: int
    skipped_types: Mapping[str, int]
    t_first_ms: int
    t_last_ms: int
    gnss: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 5)))
    pressure: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 2)))
    waypoint_floor: NDArray[np.int64] = field(default_factory=lambda: np.empty(0, dtype=np.int64))

    @property
    def duration_ms(self) -> int:
        """Time from the first to the last record read, in ms."""
        return self.t_last_ms - self.t_first_ms

    def radio_events(self) -> list[WifiEvent | BleEvent]:
        """WiFi and BLE events merged and sorted by time (stable: WiFi first on ties)."""
        events: list[WifiEvent | BleEvent] = [*self.wifi, *self.ble]
        events.sort(key=lambda e: e.t_ms)
        return events

    def imu_events(self, block_ms: int = IMU_BLOCK_MS) -> list[ImuEvent]:
        """The motion samples cut into blocks of ``block_ms`` phone time, as a phone that
        sends raw samples would post them.

        Block ``k`` holds the samples of every stream with ``t0 + k * block_ms <= t <
        t0 + (k + 1) * block_ms``, ``t0`` being the first sample of any stream, and its
        ``t_ms`` is that start; blocks without any sample are left out. Each sample is in
        exactly one block, except one logged at the same millisecond as the previous
        sample of its stream (the event model needs increasing times; site2 has none).

        Rotation rows gain ``w = sqrt(1 - x² - y² - z²)`` (clipped at 0), as Android's
        ``SensorManager.getQuaternionFromVector`` completes a three-value rotation vector.
        ``magnetic_calibrated`` is always true: a stream taken from uncalibrated records
        (see ``uncalibrated``) had the phone's hard-iron estimate subtracted on reading.

        Raises
        ------
        ValueError
            When ``block_ms`` is not positive.
        """
        if block_ms <= 0:
            raise ValueError(f"block_ms must be positive, not {block_ms}")
        accel, gyro, magnetic, rotation = (
            _increasing(a)
            for a in (self.accel, self.gyro, self.magnetic, _with_scalar_part(self.rotation))
        )
        streams = (accel, gyro, magnetic, rotation)
        firsts = [a[0, 0] for a in streams if a.shape[0]]
        if not firsts:
            return []
        t0 = int(min(firsts))
        block_of = [(a[:, 0].astype(np.int64) - t0) // block_ms for a in streams]
        blocks = np.unique(np.concatenate(block_of))
        # piece i of a stream: its samples in blocks[i] (blocks[1:] are where pieces start)
        pieces = [
            np.split(a, np.searchsorted(b, blocks[1:]))
            for a, b in zip(streams, block_of, strict=True)
        ]
        return [
            ImuEvent(t0 + k * block_ms, accel=ac, gyro=gy, magnetic=ma, rotation=ro)
            for k, ac, gy, ma, ro in zip(blocks.tolist(), *pieces, strict=True)
        ]

    def events(self, imu: bool = False, block_ms: int = IMU_BLOCK_MS) -> list[Event]:
        """Radio events and, with ``imu``, the blocks of ``imu_events(block_ms)``, sorted
        by time (stable: on a tie WiFi, then BLE, then the block).

        A block is placed at its start: a scan taken while its samples were logged comes
        after the whole block, as in a batch a phone posts.
        """
        events: list[Event] = [*self.radio_events()]
        if imu:
            events += self.imu_events(block_ms)
        events.sort(key=lambda e: e.t_ms)
        return events


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


_LEVEL_PATTERNS: tuple[tuple[re.Pattern[str], int, int], ...] = (
    # (pattern, sign, offset): level = sign * number + offset
    (re.compile(r"^B(\d+)F?$", re.IGNORECASE), -1, 0),  # B1, B2F -> -1, -2
    (re.compile(r"^(\d+)B$", re.IGNORECASE), -1, 0),  # 1B -> -1
    (re.compile(r"^[FL](\d+)$", re.IGNORECASE), 1, -1),  # F1, L1 -> 0
    (re.compile(r"^(\d+)F$", re.IGNORECASE), 1, -1),  # 1F -> 0
)


def floor_level(name: str) -> int:
    """Level of a floor from its name: ``"B2"`` -> -2, ``"B1"`` -> -1, ``"F1"`` -> 0.

    Also ``"1F"`` -> 0, ``"L1"`` -> 0, ``"1B"`` / ``"B1F"`` -> -1 (case-insensitive).

    Raises
    ------
    ValueError
        The name follows none of these patterns, or numbers floor 0 (``"F0"``, ``"B0"``).
    """
    for pattern, sign, offset in _LEVEL_PATTERNS:
        match = pattern.match(name.strip())
        if match is not None and int(match.group(1)) > 0:
            return sign * int(match.group(1)) + offset
    raise ValueError(f"cannot tell the level of floor {name!r}: expected B1, F1, 1F or L1")


def _path_id(path: Path) -> str:
    name = path.name
    for suffix in (".xz", ".txt"):
        name = name.removesuffix(suffix)
    return name


def _is_uint(text: str) -> bool:
    return text.isascii() and text.isdigit()


class TraceFormatError(ValueError):
    """A record a strict read refuses: the 1-based line number and what is wrong."""

    def __init__(self, line: int, reason: str) -> None:
        super().__init__(f"line {line}: {reason}")
        self.line = line
        self.reason = reason


class _Refused(ValueError):
    """A record that parsed but holds a value a strict read does not accept."""


class _TraceParser:
    """Accumulates the records of one trace; ``trace`` builds the arrays at the end.
    ``strict`` raises :class:`TraceFormatError` on the first unreadable record instead of
    counting it."""

    def __init__(self, wifi_max_age_ms: int | None, strict: bool = False) -> None:
        self.wifi_max_age_ms = wifi_max_age_ms
        self.strict = strict
        self.line_no = 0
        self.header: dict[str, str] = {}
        self.waypoints: list[tuple[float, float, float]] = []
        self.sensors: dict[str, list[tuple[float, float, float, float]]] = {s: [] for s in _STREAMS}
        self.uncal: dict[str, list[tuple[float, float, float, float]]] = {
            s: [] for s in _UNCALIBRATED_STREAMS.values()
        }
        # scan time -> emitter -> strongest rssi
        self.wifi: dict[int, dict[str, float]] = {}
        self.ble: dict[int, dict[str, float]] = {}
        self.radio_t: list[int] = []  # scan times of rows read, stale ones included
        self.bad_lines = 0
        self.joined_lines = 0
        self.stale_wifi = 0
        self.skipped: dict[str, int] = {}

    def feed(self, lines: Iterable[str]) -> None:
        for raw in lines:
            self.line_no += 1
            line = raw.rstrip("\r\n")
            if not line.strip():
                continue
            if "TYPE_" in line and (line[0] == "#" or line.count("TYPE_") > 1):
                pieces = [p for p in _RECORD_START.split(line) if p]
                if len(pieces) > 1:
                    self.joined_lines += 1
            else:
                pieces = [line]
            for piece in pieces:
                if piece[0] == "#":
                    self._header(piece)
                else:
                    self._record(piece.rstrip())

    def _header(self, line: str) -> None:
        for token in line[1:].split("\t"):
            key, sep, value = token.partition(":")
            if sep:
                self.header[key.strip()] = value.strip()

    def _record(self, line: str) -> None:
        f = line.split("\t")
        if len(f) < 2:
            self._bad("not a record: expected 'unix_ms<TAB>TYPE_...<TAB>values'")
            return
        kind = f[1]
        n = len(f)
        try:
            if not _is_uint(f[0]):
                raise ValueError(f[0])
            t = int(f[0])
            if kind in _SENSOR_STREAMS:
                if n != _N_FIELDS_SENSOR:
                    raise ValueError(kind)
                row = (t, float(f[2]), float(f[3]), float(f[4]))
                if self.strict and not all(map(math.isfinite, row)):
                    raise ValueError(kind)
                self.sensors[_SENSOR_STREAMS[kind]].append(row)
            elif kind in _UNCALIBRATED_STREAMS:
                if n != _N_FIELDS_UNCALIBRATED:
                    raise ValueError(kind)
                row = (
                    t,
                    float(f[2]) - float(f[5]),
                    float(f[3]) - float(f[6]),
                    float(f[4]) - float(f[7]),
                )
                if self.strict and not all(map(math.isfinite, row)):
                    raise ValueError(kind)
                self.uncal[_UNCALIBRATED_STREAMS[kind]].append(row)
            elif kind == "TYPE_WIFI":
                if n != _N_FIELDS_WIFI or not f[3] or not _is_uint(f[6]):
                    raise ValueError(kind)
                rssi = float(f[4])
                if not math.isfinite(rssi):
                    raise ValueError(f[4])
                if self.strict:
                    self._check_emitter("bssid", f[3])
                    self._check_rssi(rssi)
                self.radio_t.append(t)
                if self.wifi_max_age_ms is not None and t - int(f[6]) > self.wifi_max_age_ms:
                    self.stale_wifi += 1
                    return
                keep_strongest(self.wifi.setdefault(t, {}), f[3].lower(), rssi)
            elif kind == "TYPE_BEACON":
                if n != _N_FIELDS_BEACON or not (f[2] and _is_uint(f[3]) and _is_uint(f[4])):
                    raise ValueError(kind)
                rssi = float(f[6])
                if not math.isfinite(rssi):
                    raise ValueError(f[6])
                if self.strict:
                    self._check_emitter("mac", f[8] or f"{f[2]}:{f[3]}:{f[4]}")
                    self._check_rssi(rssi)
                self.radio_t.append(t)
                # the MAC is the beacon: one iBeacon id is often shared by hundreds of
                # beacons on every floor (site2: one id covers 318 MACs on all 9 floors)
                emitter = (f[8] or f"{f[2]}:{f[3]}:{f[4]}").lower()
                keep_strongest(self.ble.setdefault(t, {}), emitter, rssi)
            elif kind == "TYPE_WAYPOINT":
                if n != _N_FIELDS_WAYPOINT:
                    raise ValueError(kind)
                x, y = float(f[2]), float(f[3])
                if self.strict and not (
                    abs(x) <= UPLOAD_MAX_COORD_M and abs(y) <= UPLOAD_MAX_COORD_M
                ):
                    raise _Refused(
                        f"TYPE_WAYPOINT ({f[2]}, {f[3]}): coordinates must be finite and "
                        f"within {UPLOAD_MAX_COORD_M:g} m"
                    )
                self.waypoints.append((t, x, y))
            elif kind.startswith("TYPE_"):
                self.skipped[kind] = self.skipped.get(kind, 0) + 1
            else:
                raise ValueError(kind)
        except _Refused as exc:
            self._bad(str(exc))
        except ValueError:
            self._bad(f"unreadable {kind[:40]!r} record ({n} fields)")

    @staticmethod
    def _check_rssi(rssi: float) -> None:
        lo, hi = UPLOAD_RSSI_DBM
        if not lo <= rssi <= hi:
            raise _Refused(f"rssi {rssi:g} dBm is outside {lo:g}..{hi:g} dBm")

    @staticmethod
    def _check_emitter(name: str, value: str) -> None:
        if not (0 < len(value) <= UPLOAD_ID_CHARS and value.isascii() and value.isprintable()):
            raise _Refused(
                f"{name} must be 1 to {UPLOAD_ID_CHARS} printable ASCII characters "
                f"(got {len(value)} characters)"
            )
        if " " in value:
            raise _Refused(f"{name} must not hold spaces")

    def _bad(self, reason: str) -> None:
        if self.strict:
            raise TraceFormatError(self.line_no, reason)
        self.bad_lines += 1

    def trace(self, path_id: str, floor: str) -> IlcTrace:
        waypoints = self._rows(self.waypoints, 3)
        streams = {s: self._rows(self.sensors[s], 4) for s in _STREAMS}
        uncalibrated = set()
        for stream, rows in self.uncal.items():
            if streams[stream].shape[0] == 0 and rows:
                streams[stream] = self._rows(rows, 4)
                uncalibrated.add(stream)
        wifi = tuple(WifiEvent(t, readings(self.wifi[t])) for t in sorted(self.wifi))
        ble = tuple(window_ble([BleEvent(t, readings(self.ble[t])) for t in sorted(self.ble)]))
        t_all = [waypoints[:, 0], *(a[:, 0] for a in streams.values())]
        t_all.append(np.asarray(self.radio_t, dtype=np.float64))
        t_concat = np.concatenate(t_all)
        return IlcTrace(
            path_id=path_id,
            floor=floor,
            site_id=self.header.get("SiteID"),
            waypoint_t_ms=waypoints[:, 0].astype(np.int64),
            waypoint_xy_m=np.ascontiguousarray(waypoints[:, 1:]),
            wifi=wifi,
            ble=ble,
            accel=streams["accel"],
            gyro=streams["gyro"],
            magnetic=streams["magnetic"],
            rotation=streams["rotation"],
            uncalibrated=frozenset(uncalibrated),
            bad_lines=self.bad_lines,
            joined_lines=self.joined_lines,
            stale_wifi_readings=self.stale_wifi,
            skipped_types=MappingProxyType(dict(sorted(self.skipped.items()))),
            t_first_ms=int(t_concat.min()) if t_concat.size else 0,
            t_last_ms=int(t_concat.max()) if t_concat.size else 0,
        )

    def _rows(self, rows: Sequence[tuple[float, ...]], width: int) -> NDArray[np.float64]:
        """Rows as an (n, width) array sorted by time; non-finite rows dropped as bad."""
        a = np.asarray(rows, dtype=np.float64).reshape(-1, width)
        finite = np.isfinite(a).all(axis=1)
        if not finite.all():
            self.bad_lines += int(np.count_nonzero(~finite))
            a = a[finite]
        return a[np.argsort(a[:, 0], kind="stable")]


def _with_scalar_part(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 4) ``[t, x, y, z]`` rotation-vector rows as (n, 5) ``[t, x, y, z, w]``."""
    w = np.sqrt(np.clip(1.0 - np.sum(rotation[:, 1:4] ** 2, axis=1), 0.0, None))
    return np.column_stack([rotation[:, :4], w])


def _increasing(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """Time-sorted rows without those at the same time as the row before."""
    keep = np.ones(samples.shape[0], dtype=bool)
    keep[1:] = np.diff(samples[:, 0]) > 0
    return samples if keep.all() else samples[keep]


def read_trace(
    path: Path, floor: str | None = None, *, wifi_max_age_ms: int | None = WIFI_MAX_AGE_MS
) -> IlcTrace:
    """Read one trace (``.txt`` or ``.txt.xz``).

    Parameters
    ----------
    path : Path
        The trace file.
    floor : str, optional
        Floor name to record. By default the name of the directory holding
        ``path_data_files/``, else the header's ``FloorName``, else ``""``.
    wifi_max_age_ms : int, optional
        WiFi rows seen longer ago than this at their scan time are dropped; None keeps all.

    Returns
    -------
    IlcTrace
        Never raises on the content of the file (see the module docstring); raises
        ``OSError`` when the file cannot be opened and ``lzma.LZMAError`` when an ``.xz``
        file is not xz data at all.
    """
    parser = _TraceParser(wifi_max_age_ms)
    lines = open_text(path)
    try:
        parser.feed(lines)
    except EOFError:  # compressed stream cut short: keep what was read
        parser.bad_lines += 1
    if floor is None:
        if path.parent.name == "path_data_files":
            floor = path.parent.parent.name
        else:
            floor = parser.header.get("FloorName", "")
    return parser.trace(_path_id(path), floor)


def parse_trace_text(
    text: str,
    path_id: str,
    floor: str | None = None,
    *,
    wifi_max_age_ms: int | None = WIFI_MAX_AGE_MS,
) -> IlcTrace:
    """Read one trace from its text, strictly: the first record that cannot be read raises
    :class:`TraceFormatError` with its line number (for uploads, where the sender should
    hear what is wrong). ``floor`` defaults to the header's ``FloorName``."""
    parser = _TraceParser(wifi_max_age_ms, strict=True)
    parser.feed(text.splitlines())
    return parser.trace(path_id, floor if floor is not None else parser.header.get("FloorName", ""))


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
        read (``read_trace`` each of ``floor.trace_files``).

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
