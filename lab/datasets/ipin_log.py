"""IPIN 2023 Track 3 (smartphone, off-site) GetSensorData logs: one log as a walk.

A venue's logs are ``<venue>/logs/IPIN2023_T3_TrainingTrial<TT>_repetition<RR>.txt[.xz]``
(data: Torres-Sospedra et al., Zenodo 2023, doi:10.5281/zenodo.8362205; the venue is read
by ``lab.datasets.ipin``). A log is ``;``-separated text, one reading per line, the type
first; header lines start with ``%``. Lines read here (times in seconds):

=========  =============================================================================
``ACCE``   AppTimestamp; SensorTimestamp; x; y; z (m/s², gravity included); accuracy
``GYRO``   AppTimestamp; SensorTimestamp; x; y; z (rad/s); accuracy
``MAGN``   AppTimestamp; SensorTimestamp; x; y; z (µT); accuracy
``AHRS``   AppTimestamp; SensorTimestamp; pitch; roll; yaw (deg); Quat(2); Quat(3);
           Quat(4); accuracy. Quat(2..4) are the x, y, z of Android's rotation vector
           (``getQuaternionFromVector``: they reproduce the logged angles)
``PRES``   AppTimestamp; SensorTimestamp; pressure (mbar = hPa); accuracy
``WIFI``   AppTimestamp; SensorTimestamp; SSID; BSSID; frequency (MHz); RSS (dBm)
``BLE4``   AppTimestamp; ``iBeacon``; MAC; RSS (dBm); power; major; minor; UUID (or
           ``Eddystone``; MAC; RSS; ...)
``GNSS``   AppTimestamp; fix time (Unix s); lat; lon (deg); altitude; bearing;
           accuracy (m); speed; satellites in view; in use
``POSI``   AppTimestamp; counter; lat; lon (deg); floor (level); building: ground truth
=========  =============================================================================

Other types (``LIGH``, ``SOUN``, ``PROX``, ...) are skipped and counted per type. Every
log becomes a ``server.positioning.model.walk.Walk``, as an ILC trace does, so the evaluation and
the engines read both datasets alike.

Time base. AppTimestamp is the app's clock, common to all lines, in seconds since the app
started; times here are that clock in integer milliseconds. No epoch offset is added: the
header's "Date of creation" is the phone's wall clock at one-second resolution, and that
clock is off (the first GNSS fix's own time minus creation time minus its AppTimestamp is
+19 s on every SM-A520F log but one, -221 s on every SM-G930F log). AppTimestamp is when
the app read a sample, at 0.1 ms resolution: at 100 Hz two gyroscope samples can share a
millisecond (22 of 23,048 in Trial01 repetition01). The motion streams (ACCE, GYRO, MAGN,
AHRS) and PRES therefore take their SensorTimestamp (the phone's sensor clock, strictly
increasing, the header's advice for integrating inertial data) moved onto the app clock
by the stream's median of ``AppTimestamp - SensorTimestamp``; on the 24 dev logs that
offset drifts by at most 2.3 ms over a log for motion samples (44 ms for PRES), and a
moved time is at most 132 ms from its AppTimestamp (app read latency). The first samples
of a log can thus be some ms before 0 (down to -37 ms). A stream whose moved times are not strictly
increasing or lie more than ``SENSOR_CLOCK_TOLERANCE_MS`` from its app times keeps its
app times (``IpinLog.app_clock_streams`` names it; none of the dev logs has one).

WiFi scans: the rows of one scan are consecutive and share their AppTimestamp (their
SensorTimestamps differ by at most 3 ms on the dev logs; none is a cached older result),
so one ``WifiEvent`` per AppTimestamp, readings keyed by lower-case BSSID; a BSSID listed
twice in a scan keeps its strongest reading. BLE: one row per advertisement, keyed by the
lower-case MAC (the beacon's identity; the iBeacon UUID, major and minor are kept in
``IpinLog.beacons``); rows are grouped into scans as the ILC reader does
(``events.window_ble``, ``ble_window_ms``), or one event per row time with
``ble_window_ms=None``. GNSS: nearly every fix is logged twice (same fix time and values, a
few ms apart); the repeat is dropped.

Positions: POSI latitude/longitude go to the venue's local frame (``ipin_frame``; x
east, y north, metres).

The reader never fails on the content of a log: a line with the wrong number of fields,
a value that is not a finite number or a type that is not four capitals is dropped and
counted in ``bad_lines`` (of ``IpinLog.report``); an ``.xz`` file that ends early keeps
what was read and counts one more bad line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from lab.datasets.ipin_frame import LocalFrame, venue_frame
from server.positioning.model.events import BLE_WINDOW_MS, BleEvent, WifiEvent, window_ble
from server.positioning.model.walk import Walk
from server.storage.text_records import ParseReport, file_id, keep_strongest, open_text, readings

SENSOR_CLOCK_TOLERANCE_MS = 500
"""Largest gap between a sample's SensorTimestamp moved onto the app clock and its
AppTimestamp for a stream to keep sensor times (the dev logs: at most 132 ms)."""

_LOG_NAME = re.compile(r"Trial(\d+)_repetition(\d+)", re.IGNORECASE)
_TYPE = re.compile(r"^[A-Z0-9]{4}$")

# fields per line, the type included
_N_FIELDS_MOTION = 7
_N_FIELDS_AHRS = 10
_N_FIELDS_PRES = 5
_N_FIELDS_WIFI = 7
_N_FIELDS_IBEACON = 9
_N_FIELDS_EDDYSTONE_MIN = 5
_N_FIELDS_GNSS = 11
_N_FIELDS_POSI = 7

_SENSOR_STREAMS = {"ACCE": "accel", "GYRO": "gyro", "MAGN": "magnetic", "AHRS": "rotation"}
_STREAMS = ("accel", "gyro", "magnetic", "rotation", "pressure")


@dataclass(frozen=True, slots=True)
class IBeaconId:
    """What an iBeacon advertises besides its MAC."""

    uuid: str
    major: int
    minor: int


@dataclass(frozen=True, eq=False)
class IpinLog:
    """One GetSensorData log as a walk, with what only IPIN logs carry.

    Attributes
    ----------
    trace : Walk
        The log as a walk: ``waypoint_*`` from POSI lines in the venue frame
        (``waypoint_floor`` their levels; ``floor`` the level of the first as text, ``""``
        without POSI), ``wifi``, ``ble``, the motion streams (``rotation`` from AHRS
        Quat(2..4)), ``pressure`` and ``gnss`` (hdop NaN).
    report : ParseReport
        Lines that could not be read (``bad_lines``) and lines of types not read, per
        type (``skipped_types``).
    trial, repetition : int or None
        From the file name (``...Trial01_repetition02...``); None when it has neither.
    phone : str
        Manufacturer and model from the header (``""`` when absent).
    created : str or None
        The header's "Date of creation", as written.
    waypoint_lat_lon_deg : ndarray, shape (n_wp, 2), float64
        POSI positions as logged, in the order of ``trace.waypoint_t_ms``.
    waypoint_counter, waypoint_building : ndarray, shape (n_wp,), int64
        POSI counter and building id, same order.
    beacons : Mapping of str to IBeaconId
        iBeacon ids by lower-case MAC (the first seen for each MAC).
    line_counts : Mapping of str to int
        Lines read per type (``"ACCE"``, ..., ``"POSI"``); a GNSS repeat counts here.
    gnss_repeats : int
        GNSS lines dropped as a repeat of the fix before them.
    app_clock_streams : frozenset of str
        Sensor streams that kept their app times (see the module docstring).
    """

    trace: Walk
    report: ParseReport
    trial: int | None
    repetition: int | None
    phone: str
    created: str | None
    waypoint_lat_lon_deg: NDArray[np.float64]
    waypoint_counter: NDArray[np.int64]
    waypoint_building: NDArray[np.int64]
    beacons: Mapping[str, IBeaconId]
    line_counts: Mapping[str, int]
    gnss_repeats: int
    app_clock_streams: frozenset[str]

    @property
    def bad_lines(self) -> int:
        """Lines dropped because they could not be read."""
        return self.report.bad_lines


def log_name_ids(path: Path) -> tuple[int, int] | None:
    """``(trial, repetition)`` from a log's file name, or None."""
    match = _LOG_NAME.search(path.name)
    return (int(match.group(1)), int(match.group(2))) if match else None


def _finite(*values: float) -> bool:
    return all(map(math.isfinite, values))


class _LogParser:
    """Accumulates the lines of one log; ``log`` builds the arrays at the end."""

    def __init__(self) -> None:
        self.header: dict[str, str] = {}
        # [app_s, sensor_s, values...] per stream
        self.sensors: dict[str, list[tuple[float, ...]]] = {s: [] for s in _STREAMS}
        self.wifi: dict[int, dict[str, float]] = {}
        self.ble: dict[int, dict[str, float]] = {}
        self.beacons: dict[str, IBeaconId] = {}
        self.gnss: list[tuple[float, float, float, float, float]] = []
        self.gnss_repeats = 0
        self.posi: list[tuple[float, float, float, float, float, float]] = []
        self.counts: dict[str, int] = {}
        self.skipped: dict[str, int] = {}
        self.bad_lines = 0
        self._last_gnss: tuple[float, ...] | None = None

    def feed(self, lines: Iterable[str]) -> None:
        for raw in lines:
            line = raw.strip()
            if not line:
                continue
            if line[0] == "%":
                self._header(line)
                continue
            f = line.split(";")
            if len(f) > 1 and f[-1] == "":  # a trailing ';'
                f.pop()
            kind = f[0]
            try:
                self._record(kind, f)
            except (ValueError, IndexError):
                self.bad_lines += 1
                continue

    def _header(self, line: str) -> None:
        key, sep, value = line[1:].partition(":")
        if sep and key.strip() and value.strip():
            self.header.setdefault(key.strip(), value.strip())

    def _record(self, kind: str, f: list[str]) -> None:
        n = len(f)
        if kind in _SENSOR_STREAMS:
            if kind == "MAGN" and n == _N_FIELDS_MOTION + 1 and f[4] == "":
                del f[4]  # the header's 'Mag_X(uT);;Mag_Y(uT)'
                n -= 1
            width = _N_FIELDS_AHRS if kind == "AHRS" else _N_FIELDS_MOTION
            if n != width:
                raise ValueError(kind)
            xyz = (6, 7, 8) if kind == "AHRS" else (3, 4, 5)
            row = (float(f[1]), float(f[2]), *(float(f[i]) for i in xyz))
            if not _finite(*row):
                raise ValueError(kind)
            self.sensors[_SENSOR_STREAMS[kind]].append(row)
        elif kind == "PRES":
            if n != _N_FIELDS_PRES:
                raise ValueError(kind)
            row = (float(f[1]), float(f[2]), float(f[3]))
            if not _finite(*row):
                raise ValueError(kind)
            self.sensors["pressure"].append(row)
        elif kind == "WIFI":
            if n != _N_FIELDS_WIFI or not f[4]:
                raise ValueError(kind)
            t_s, frequency, rssi = float(f[1]), float(f[5]), float(f[6])
            if not _finite(t_s, frequency, rssi):
                raise ValueError(kind)
            keep_strongest(self.wifi.setdefault(_ms(t_s), {}), f[4].lower(), rssi)
        elif kind == "BLE4":
            self._ble(f)
        elif kind == "GNSS":
            if n != _N_FIELDS_GNSS:
                raise ValueError(kind)
            t_s, fix_s, lat, lon, accuracy = (float(f[i]) for i in (1, 2, 3, 4, 7))
            if not _finite(t_s, fix_s, lat, lon, accuracy):
                raise ValueError(kind)
            fix = (fix_s, lat, lon, accuracy)
            if fix == self._last_gnss:
                self.gnss_repeats += 1
            else:
                self.gnss.append((t_s, lat, lon, accuracy, math.nan))
                self._last_gnss = fix
        elif kind == "POSI":
            if n != _N_FIELDS_POSI:
                raise ValueError(kind)
            row = (float(f[1]), int(f[2]), float(f[3]), float(f[4]), int(f[5]), int(f[6]))
            if not _finite(*row):
                raise ValueError(kind)
            self.posi.append(row)
        elif _TYPE.match(kind):
            self.skipped[kind] = self.skipped.get(kind, 0) + 1
            return
        else:
            raise ValueError(kind)
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def _ble(self, f: list[str]) -> None:
        n = len(f)
        if f[2] == "iBeacon":
            if n != _N_FIELDS_IBEACON:
                raise ValueError("BLE4")
            beacon = IBeaconId(f[8].lower(), int(f[6]), int(f[7]))
        elif f[2] == "Eddystone" and n >= _N_FIELDS_EDDYSTONE_MIN:
            beacon = None
        else:
            raise ValueError("BLE4")
        t_s, rssi = float(f[1]), float(f[4])
        if not f[3] or not _finite(t_s, rssi):
            raise ValueError("BLE4")
        mac = f[3].lower()
        keep_strongest(self.ble.setdefault(_ms(t_s), {}), mac, rssi)
        if beacon is not None:
            self.beacons.setdefault(mac, beacon)

    def log(self, path: Path, frame: LocalFrame, ble_window_ms: int | None) -> IpinLog:
        streams: dict[str, NDArray[np.float64]] = {}
        app_clock: set[str] = set()
        for name in _STREAMS:
            width = 2 if name == "pressure" else 4
            rows = np.asarray(self.sensors[name], dtype=np.float64).reshape(-1, width + 1)
            streams[name], on_app_clock = _on_app_clock(rows)
            if on_app_clock:
                app_clock.add(name)
        wifi = tuple(WifiEvent(t, readings(self.wifi[t])) for t in sorted(self.wifi))
        ble_rows = [BleEvent(t, readings(self.ble[t])) for t in sorted(self.ble)]
        ble = tuple(ble_rows if ble_window_ms is None else window_ble(ble_rows, ble_window_ms))

        posi = np.asarray(self.posi, dtype=np.float64).reshape(-1, 6)
        posi = posi[np.argsort(posi[:, 0], kind="stable")]
        waypoint_t = _ms_array(posi[:, 0])
        waypoint_floor = posi[:, 4].astype(np.int64)
        gnss = np.asarray(self.gnss, dtype=np.float64).reshape(-1, 5)
        gnss[:, 0] = _ms_array(gnss[:, 0])

        times = [waypoint_t, gnss[:, 0], *(a[:, 0] for a in streams.values())]
        times += [np.array([e.t_ms for e in wifi]), np.array([e.t_ms for e in ble_rows])]
        t_all = np.concatenate([np.asarray(t, dtype=np.float64) for t in times])
        trace = Walk(
            path_id=file_id(path),
            floor=str(int(waypoint_floor[0])) if waypoint_floor.size else "",
            waypoint_t_ms=waypoint_t,
            waypoint_xy_m=frame.to_local(posi[:, 2], posi[:, 3]),
            wifi=wifi,
            ble=ble,
            accel=streams["accel"],
            gyro=streams["gyro"],
            magnetic=streams["magnetic"],
            rotation=streams["rotation"],
            uncalibrated=frozenset(),
            t_first_ms=int(t_all.min()) if t_all.size else 0,
            t_last_ms=int(t_all.max()) if t_all.size else 0,
            gnss=gnss,
            pressure=streams["pressure"],
            waypoint_floor=waypoint_floor,
        )
        ids = log_name_ids(path)
        phone = " ".join(self.header[k] for k in ("Manufacturer", "Model") if k in self.header)
        report = ParseReport(
            bad_lines=self.bad_lines,
            skipped_types=MappingProxyType(dict(sorted(self.skipped.items()))),
        )
        return IpinLog(
            trace=trace,
            report=report,
            trial=ids[0] if ids else None,
            repetition=ids[1] if ids else None,
            phone=phone,
            created=self.header.get("Date of creation"),
            waypoint_lat_lon_deg=np.ascontiguousarray(posi[:, 2:4]),
            waypoint_counter=posi[:, 1].astype(np.int64),
            waypoint_building=posi[:, 5].astype(np.int64),
            beacons=MappingProxyType(dict(self.beacons)),
            line_counts=MappingProxyType(dict(sorted(self.counts.items()))),
            gnss_repeats=self.gnss_repeats,
            app_clock_streams=frozenset(app_clock),
        )


def _ms(t_s: float) -> int:
    return round(t_s * 1000.0)


def _ms_array(t_s: NDArray[np.float64]) -> NDArray[np.int64]:
    return np.rint(t_s * 1000.0).astype(np.int64)


def _on_app_clock(rows: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
    """``[app_s, sensor_s, values...]`` rows as ``[t_ms, values...]`` sorted by time.

    Times are the sensor clock moved onto the app clock by the median offset, in integer
    ms; when those are not strictly increasing or stray from the app times by more than
    ``SENSOR_CLOCK_TOLERANCE_MS``, the app times (the flag then is True).
    """
    app_ms = _ms_array(rows[:, 0])
    if rows.shape[0] == 0:
        return np.empty((0, rows.shape[1] - 1)), False
    offset_s = float(np.median(rows[:, 0] - rows[:, 1]))
    order = np.argsort(rows[:, 1], kind="stable")
    sensor_ms = _ms_array(rows[order, 1] + offset_s)
    stray = np.abs(sensor_ms - app_ms[order]).max()
    if np.all(np.diff(sensor_ms) > 0) and stray <= SENSOR_CLOCK_TOLERANCE_MS:
        return np.column_stack([sensor_ms.astype(np.float64), rows[order, 2:]]), False
    order = np.argsort(app_ms, kind="stable")
    return np.column_stack([app_ms[order].astype(np.float64), rows[order, 2:]]), True


def read_log(
    path: Path, frame: LocalFrame | None = None, *, ble_window_ms: int | None = BLE_WINDOW_MS
) -> IpinLog:
    """Read one GetSensorData log (``.txt`` or ``.txt.xz``).

    Parameters
    ----------
    path : Path
        The log file.
    frame : LocalFrame, optional
        The venue frame for POSI positions; by default ``venue_frame`` of the folder
        holding ``references.csv``: the log's folder or the one above it (``logs/``).
    ble_window_ms : int or None
        Span of the BLE scans rows are grouped into (``events.window_ble``); None gives
        one event per row time.

    Returns
    -------
    IpinLog
        Never raises on the content of the file (see the module docstring).

    Raises
    ------
    OSError
        When the file cannot be opened; ``lzma.LZMAError`` when an ``.xz`` file is not xz.
    ValueError
        With no ``frame`` and no ``references.csv`` beside the log or above it.
    """
    if frame is None:
        venue = next(
            (d for d in (path.parent, path.parent.parent) if (d / "references.csv").is_file()),
            None,
        )
        if venue is None:
            raise ValueError(f"{path}: no references.csv beside or above it; pass a frame")
        frame = venue_frame(venue)
    parser = _LogParser()
    try:
        parser.feed(open_text(path))
    except EOFError:  # compressed stream cut short: keep what was read
        parser.bad_lines += 1
    return parser.log(path, frame, ble_window_ms)
