"""IPIN 2023 Track 3 log reader on a real dev log, counted by hand, and on damaged text."""

from __future__ import annotations

import lzma
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from lab.datasets.ipin import IpinVenue
from lab.datasets.ipin_frame import LocalFrame
from lab.datasets.ipin_log import IpinLog, read_log
from tests.support.datasets import IPIN_LOG


@pytest.fixture(scope="module")
def lines(log_path: Path) -> list[list[str]]:
    """The data lines of the log, split by hand."""
    with lzma.open(log_path, "rt", encoding="utf-8") as f:
        return [line.rstrip("\n").split(";") for line in f if line.strip() and line[0] != "%"]


def rows(lines: list[list[str]], kind: str) -> list[list[str]]:
    return [f for f in lines if f[0] == kind]


def test_counts_match_the_file(lines: list[list[str]], log: IpinLog) -> None:
    count = Counter(f[0] for f in lines)
    trace = log.trace
    assert (log.trial, log.repetition, log.phone) == (21, 3, "samsung SM-A520F")
    assert trace.path_id == IPIN_LOG
    assert trace.floor == "-2"
    assert count["POSI"] == trace.waypoint_t_ms.size == 10
    assert trace.waypoint_floor.tolist() == [-2] * 10
    assert log.waypoint_counter.tolist() == list(range(1, 11))
    for kind, stream in [
        ("ACCE", trace.accel),
        ("GYRO", trace.gyro),
        ("MAGN", trace.magnetic),
        ("AHRS", trace.rotation),
        ("PRES", trace.pressure),
    ]:
        assert stream.shape[0] == count[kind] > 0, kind
    assert count["GYRO"] == 15189
    # WiFi: one event per AppTimestamp; each row one reading (no BSSID twice in a scan)
    wifi = rows(lines, "WIFI")
    assert len(trace.wifi) == len({f[1] for f in wifi}) == 38
    assert sum(len(e.readings) for e in trace.wifi) == len(wifi) == count["WIFI"]
    assert {r.emitter for e in trace.wifi for r in e.readings} == {f[4].lower() for f in wifi}
    # GNSS: every fix twice in a row; the repeat dropped
    gnss = [tuple(f[2:5]) for f in rows(lines, "GNSS")]
    assert trace.gnss.shape == (len(set(gnss)), 5) == (count["GNSS"] - log.gnss_repeats, 5)
    assert np.isnan(trace.gnss[:, 4]).all()
    assert dict(log.report.skipped_types) == {"LIGH": count["LIGH"], "SOUN": count["SOUN"]}
    assert log.report.bad_lines == 0
    skipped = log.report.skipped_types
    assert dict(log.line_counts) == {k: v for k, v in count.items() if k not in skipped}


def test_ble_rows_keyed_by_mac(lines: list[list[str]], log_path: Path, venue: IpinVenue) -> None:
    ble = rows(lines, "BLE4")
    per_row = read_log(log_path, venue.frame, ble_window_ms=None)
    assert len(per_row.trace.ble) == len({f[1] for f in ble})
    assert sum(len(e.readings) for e in per_row.trace.ble) == len(ble) == 527
    macs = {f[3].lower() for f in ble}
    assert {r.emitter for e in per_row.trace.ble for r in e.readings} == macs
    assert set(per_row.beacons) == macs
    first = ble[0]
    beacon = per_row.beacons[first[3].lower()]
    assert (beacon.major, beacon.minor, beacon.uuid) == (
        int(first[6]),
        int(first[7]),
        first[8].lower(),
    )
    # by default grouped into scans, as the ILC reader does: fewer events, the same beacons
    windowed = read_log(log_path, venue.frame).trace.ble
    assert 0 < len(windowed) < len(per_row.trace.ble)
    assert {r.emitter for e in windowed for r in e.readings} == macs


def test_times_are_monotone_and_on_the_app_clock(lines: list[list[str]], log: IpinLog) -> None:
    trace = log.trace
    assert log.app_clock_streams == frozenset()
    for name in ("accel", "gyro", "magnetic", "rotation", "pressure"):
        t = getattr(trace, name)[:, 0]
        assert np.all(np.diff(t) > 0), name  # strictly, as ImuEvent needs
    # AppTimestamp alone has ties at 100 Hz; the sensor clock moved onto it has none
    app_gyro_ms = np.rint(np.array([float(f[1]) for f in rows(lines, "GYRO")]) * 1000)
    assert np.count_nonzero(np.diff(app_gyro_ms) == 0) > 0
    assert np.abs(trace.gyro[:, 0] - app_gyro_ms).max() < 200
    # every motion sample goes into exactly one block
    blocks = trace.imu_events()
    for name in ("accel", "gyro", "magnetic"):
        assert sum(getattr(b, name).shape[0] for b in blocks) == getattr(trace, name).shape[0]
    for events in (trace.wifi, trace.ble):
        t_ms = [e.t_ms for e in events]
        assert t_ms == sorted(t_ms)
    assert np.all(np.diff(trace.waypoint_t_ms) >= 0)
    posi_ms = [round(float(f[1]) * 1000) for f in rows(lines, "POSI")]
    assert trace.waypoint_t_ms.tolist() == posi_ms
    assert trace.t_first_ms <= trace.accel[0, 0] <= trace.t_last_ms
    assert trace.t_last_ms >= trace.waypoint_t_ms[-1]


def test_rotation_is_the_quaternion_vector_part(lines: list[list[str]], log: IpinLog) -> None:
    ahrs = rows(lines, "AHRS")
    np.testing.assert_array_equal(
        log.trace.rotation[:, 1:], np.array([[float(v) for v in f[6:9]] for f in ahrs])
    )
    assert np.all(np.sum(log.trace.rotation[:, 1:] ** 2, axis=1) <= 1.0 + 1e-6)


def test_default_frame_is_the_venue_frame(log_path: Path, log: IpinLog) -> None:
    again = read_log(log_path)  # references.csv is found above logs/
    np.testing.assert_array_equal(again.trace.waypoint_xy_m, log.trace.waypoint_xy_m)


GOOD = """\
% Model:                   \tTEST-1
% Date of creation: Wed Jun 14 10:00:58 GMT+02:00 2023
ACCE;0.0100;100.0010;0.1;0.2;9.8;3
ACCE;0.0300;100.0210;0.1;0.2;9.8;3
GYRO;0.0110;100.0011;0.0;0.0;0.1;3
MAGN;0.0120;100.0012;10.0;-20.0;-40.0;0
AHRS;0.0130;100.0013;1.0;2.0;3.0;0.1;0.2;0.3;3
PRES;0.0140;100.0014;976.5;3
WIFI;1.0000;101.0;net;AA:BB:CC:00:00:01;2412;-60
WIFI;1.0000;101.0;net;AA:BB:CC:00:00:02;5200;-70
WIFI;1.0000;101.0;net;AA:BB:CC:00:00:01;2412;-65
BLE4;1.5000;iBeacon;BE:AC:00:00:00:01;-80;0;1;7;UUID-1
GNSS;2.0000;1686729678.0000;49.4610;11.1110;346.0;0.0;9.0;0.0;22;19
GNSS;2.0100;1686729678.0000;49.4610;11.1110;346.0;0.0;9.0;0.0;22;19
LIGH;2.1;100.1;349.0;3
POSI;3.0000;1;49.4611;11.1111;0;100
POSI;9.0000;2;49.4612;11.1112;-1;100
"""
BAD = """\
ACCE;0.0500;100.0410;x;0.2;9.8;3
GYRO;0.0600;100.0510;0.0;0.1;3
MAGN;0.0700;100.0610;nan;-20.0;-40.0;0
WIFI;1.5000;101.5;net;;2412;-60
BLE4;1.6000;Foo;BE:AC:00:00:00:01;-80
POSI;4.0000;3;49.4611;11.1111;zero;100
not a line at all
"""
FRAME = LocalFrame(49.4608575243929, 11.1102840572794)


def _check_good(log: IpinLog) -> None:
    trace = log.trace
    assert log.phone == "TEST-1"
    assert log.created == "Wed Jun 14 10:00:58 GMT+02:00 2023"
    assert trace.accel.shape == (2, 4)
    assert (trace.gyro.shape, trace.magnetic.shape, trace.rotation.shape) == ((1, 4),) * 3
    assert trace.pressure.tolist() == [[14.0, 976.5]]
    np.testing.assert_array_equal(trace.rotation[0, 1:], [0.1, 0.2, 0.3])
    assert len(trace.wifi) == 1
    assert trace.wifi[0].t_ms == 1000
    assert {r.emitter: r.rssi_dbm for r in trace.wifi[0].readings} == {
        "aa:bb:cc:00:00:01": -60.0,  # listed twice: the strongest kept
        "aa:bb:cc:00:00:02": -70.0,
    }
    assert [(e.t_ms, e.readings[0].emitter) for e in trace.ble] == [(1500, "be:ac:00:00:00:01")]
    assert log.beacons["be:ac:00:00:00:01"].minor == 7
    assert trace.gnss.shape == (1, 5)
    assert log.gnss_repeats == 1
    assert trace.waypoint_t_ms.tolist() == [3000, 9000]
    assert trace.waypoint_floor.tolist() == [0, -1]
    assert dict(log.report.skipped_types) == {"LIGH": 1}
    assert (log.trial, log.repetition) == (None, None)


def test_bad_lines_are_counted(tmp_path: Path) -> None:
    path = tmp_path / "damaged.txt"
    path.write_text(GOOD + BAD, encoding="utf-8")
    log = read_log(path, FRAME)
    _check_good(log)
    assert log.bad_lines == len(BAD.splitlines()) == 7


def test_xz_cut_short_keeps_what_was_read(tmp_path: Path) -> None:
    whole = tmp_path / "IPIN2023_T3_TrainingTrial05_repetition02.txt.xz"
    whole.write_bytes(lzma.compress((GOOD * 200).encode()))
    log = read_log(whole, FRAME)
    assert (log.trial, log.repetition, log.bad_lines) == (5, 2, 0)
    cut = tmp_path / "cut.txt.xz"
    cut.write_bytes(whole.read_bytes()[:-200])
    short = read_log(cut, FRAME)
    assert short.bad_lines >= 1
    assert 0 < short.trace.accel.shape[0] <= log.trace.accel.shape[0]


def test_no_frame_and_no_references_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "log.txt"
    path.write_text(GOOD, encoding="utf-8")
    with pytest.raises(ValueError, match=r"references\.csv"):
        read_log(path)
