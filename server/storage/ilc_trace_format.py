"""Indoor Location Competition 2.0 (Microsoft / XYZ10) phone traces: one path file as a walk.

A site's path files are ``<site>/<floor>/path_data_files/<id>.txt`` (also ``<id>.txt.xz``;
the site layout is read by ``lab.datasets.ilc``). A trace is tab separated, one record
per line: ``unix_ms <TAB> TYPE_... <TAB> values``; header lines start with ``#`` and carry
``key:value`` pairs (``SiteID``, ``FloorName``, ``startTime`` ...). Records read here:

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
is dropped and counted in ``bad_lines`` (of ``IlcWalk.report``, a ``records.ParseReport``).
A line holding several records run together (a newline lost in the file) is split where a
13-digit timestamp followed by a TAB and ``TYPE_`` starts again, and its records are read
normally (counted in ``joined_lines``). A compressed file that ends early keeps the records
read up to that point and counts one more bad line. ``parse_trace_text`` reads strictly
instead (uploads): the first record it cannot read raises ``TraceFormatError``.

WiFi scans: the rows of one scan share the first-column timestamp (the scan time) and
become one ``WifiEvent``, each reading with its age (the scan time less the row's
``last_seen``, ``RadioReading.age_ms``). Android also returns cached results (rows whose
``last_seen`` is older than the scan); by default they are kept (matching discounts them
by their age), and ``wifi_max_age_ms`` drops them (see ``WIFI_MAX_AGE_MS``). A BSSID listed
twice in one scan (one radio announcing several SSIDs) keeps its strongest reading, as
``fingerprints.scan_vector`` does.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.events import BleEvent, WifiEvent, window_ble
from server.positioning.model.walk import Walk
from server.storage.text_records import ParseReport, file_id, keep_strongest, open_text, readings

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


@dataclass(frozen=True, eq=False, kw_only=True)
class IlcWalk(Walk):
    """One path file as read: the walk it records, its header's site and the reader's report.

    WiFi readings are keyed by lower-case BSSID, BLE ones by the beacon's MAC in lower case
    (``"<uuid>:<major>:<minor>"`` when a row has no MAC). A motion stream with no
    calibrated record comes from the uncalibrated one with its bias estimate subtracted
    (what Android's calibrated value is) and is named in ``uncalibrated``. On site2 the
    two are logged at the same times; the magnetometer stand-in is nearly always the
    calibrated value, the accelerometer and gyroscope ones often hold a neighbouring sample
    (correlation 0.8-0.99 with the calibrated stream): close, not identical. ILC files
    carry no satellite fixes, barometer or per-waypoint floors.

    Attributes
    ----------
    site_id : str or None
        ``SiteID`` of the header, if present.
    report : ParseReport
        What the reader could not read, ran together, dropped as stale or skipped.
    """

    site_id: str | None
    report: ParseReport

    @property
    def bad_lines(self) -> int:
        """Records dropped because they could not be read (``report.bad_lines``)."""
        return self.report.bad_lines


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
    """Accumulates the records of one trace; ``walk`` builds the arrays at the end.
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
        self.wifi_age: dict[int, dict[str, int]] = {}  # ms since last seen, as self.wifi
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
                scan, bssid = self.wifi.setdefault(t, {}), f[3].lower()
                if scan.get(bssid, -math.inf) < rssi:  # strongest per BSSID, with its age
                    scan[bssid] = rssi
                    self.wifi_age.setdefault(t, {})[bssid] = max(t - int(f[6]), 0)
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

    def walk(self, path_id: str, floor: str) -> IlcWalk:
        waypoints = self._rows(self.waypoints, 3)
        streams = {s: self._rows(self.sensors[s], 4) for s in _STREAMS}
        uncalibrated = set()
        for stream, rows in self.uncal.items():
            if streams[stream].shape[0] == 0 and rows:
                streams[stream] = self._rows(rows, 4)
                uncalibrated.add(stream)
        wifi = tuple(
            WifiEvent(t, readings(self.wifi[t], self.wifi_age[t])) for t in sorted(self.wifi)
        )
        ble = tuple(window_ble([BleEvent(t, readings(self.ble[t])) for t in sorted(self.ble)]))
        t_all = [waypoints[:, 0], *(a[:, 0] for a in streams.values())]
        t_all.append(np.asarray(self.radio_t, dtype=np.float64))
        t_concat = np.concatenate(t_all)
        return IlcWalk(
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
            t_first_ms=int(t_concat.min()) if t_concat.size else 0,
            t_last_ms=int(t_concat.max()) if t_concat.size else 0,
            report=ParseReport(
                bad_lines=self.bad_lines,
                joined_lines=self.joined_lines,
                stale_wifi_readings=self.stale_wifi,
                skipped_types=MappingProxyType(dict(sorted(self.skipped.items()))),
            ),
        )

    def _rows(self, rows: Sequence[tuple[float, ...]], width: int) -> NDArray[np.float64]:
        """Rows as an (n, width) array sorted by time; non-finite rows dropped as bad."""
        a = np.asarray(rows, dtype=np.float64).reshape(-1, width)
        finite = np.isfinite(a).all(axis=1)
        if not finite.all():
            self.bad_lines += int(np.count_nonzero(~finite))
            a = a[finite]
        return a[np.argsort(a[:, 0], kind="stable")]


def read_trace(
    path: Path, floor: str | None = None, *, wifi_max_age_ms: int | None = WIFI_MAX_AGE_MS
) -> IlcWalk:
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
    IlcWalk
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
    return parser.walk(file_id(path), floor)


def parse_trace_text(
    text: str,
    path_id: str,
    floor: str | None = None,
    *,
    wifi_max_age_ms: int | None = WIFI_MAX_AGE_MS,
) -> IlcWalk:
    """Read one trace from its text, strictly: the first record that cannot be read raises
    :class:`TraceFormatError` with its line number (for uploads, where the sender should
    hear what is wrong). ``floor`` defaults to the header's ``FloorName``."""
    parser = _TraceParser(wifi_max_age_ms, strict=True)
    parser.feed(text.splitlines())
    return parser.walk(path_id, floor if floor is not None else parser.header.get("FloorName", ""))


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
