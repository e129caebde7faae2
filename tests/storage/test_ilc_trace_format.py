"""Indoor Location Competition 2.0 trace reader on the real site2 sample, clean and damaged."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.storage.ilc_trace_format import WIFI_MAX_AGE_MS, IlcWalk, floor_level, read_trace
from tests.support.datasets import SAMPLE_ID


def records(lines: list[str], kind: str) -> list[list[str]]:
    """Fields of the data lines of one type, split by hand."""
    return [f for f in (line.split("\t") for line in lines) if len(f) > 1 and f[1] == kind]


def test_txt_and_xz_give_the_same_trace(ilc_dir: Path, raw_trace: IlcWalk) -> None:
    xz = read_trace(ilc_dir / "site2" / "F4" / "path_data_files" / f"{SAMPLE_ID}.txt.xz")
    assert (raw_trace.path_id, xz.path_id) == (SAMPLE_ID, SAMPLE_ID)
    assert (raw_trace.floor, xz.floor) == ("F4", "F4")  # header FloorName / directory name
    assert raw_trace.site_id == xz.site_id == "5dbc1d84c1eb61796cf7c010"
    for name in ("waypoint_t_ms", "waypoint_xy_m", "accel", "gyro", "magnetic", "rotation"):
        np.testing.assert_array_equal(getattr(raw_trace, name), getattr(xz, name))
    assert raw_trace.wifi == xz.wifi
    assert raw_trace.ble == xz.ble
    assert raw_trace.report.skipped_types == xz.report.skipped_types


def test_sample_trace_contents(raw_trace: IlcWalk, raw_lines: list[str]) -> None:
    tr = raw_trace
    assert tr.report.bad_lines == 0
    assert tr.report.joined_lines == 0
    # waypoints: 4 in the file, the last one written after the sensors; sorted on reading
    assert tr.waypoint_t_ms.dtype == np.int64
    assert tr.waypoint_xy_m.shape == (4, 2)
    assert np.all(np.diff(tr.waypoint_t_ms) > 0)
    np.testing.assert_allclose(tr.waypoint_xy_m[0], [157.4365, 76.44891])
    # sensors: 316 of each, [t, x, y, z], sorted by time; all calibrated records present
    for stream in (tr.accel, tr.gyro, tr.magnetic, tr.rotation):
        assert stream.shape == (316, 4)
        assert stream.dtype == np.float64
        assert np.all(np.diff(stream[:, 0]) >= 0)
    assert tr.uncalibrated == frozenset()
    np.testing.assert_allclose(tr.accel[0], [1574248434607, -0.35372925, 0.63990784, 5.7099457])
    assert tr.report.skipped_types == {
        "TYPE_BLU4": 209,
        "TYPE_BLUE": 209,
        "TYPE_DIST1": 1,
        "TYPE_DIST2": 1,
        "TYPE_SENSOR_MAGNETIC_FIELD_ACCURACY_CHANGED": 1,
    }
    assert 6000 < tr.duration_ms < 7000


def test_wifi_rows_are_grouped_by_scan_time(
    raw_path: Path, raw_trace: IlcWalk, raw_lines: list[str]
) -> None:
    rows = records(raw_lines, "TYPE_WIFI")
    scan_times = sorted({int(f[0]) for f in rows})
    assert len(scan_times) == 3
    assert [e.t_ms for e in raw_trace.wifi] == scan_times
    max_age_ms = 2000
    filtered = read_trace(raw_path, wifi_max_age_ms=max_age_ms)
    for event in filtered.wifi:
        fresh = [
            f for f in rows if int(f[0]) == event.t_ms and event.t_ms - int(f[6]) <= max_age_ms
        ]
        strongest = {f[3]: max(float(g[4]) for g in fresh if g[3] == f[3]) for f in fresh}
        assert {(r.emitter, r.rssi_dbm) for r in event.readings} == set(strongest.items())
        assert len({r.emitter for r in event.readings}) == len(event.readings)
    # each reading carries its age: the scan time less the row's last-seen time (of the
    # strongest row of its BSSID)
    for event in raw_trace.wifi:
        here = [f for f in rows if int(f[0]) == event.t_ms]
        for r in event.readings:
            best = max((f for f in here if f[3] == r.emitter), key=lambda f: float(f[4]))
            assert r.age_ms == event.t_ms - int(best[6])
    assert any(r.age_ms and r.age_ms > 2000 for e in raw_trace.wifi for r in e.readings)
    n_fresh = sum(len(e.readings) for e in filtered.wifi)
    assert n_fresh + filtered.report.stale_wifi_readings <= len(rows)  # a BSSID twice: merged
    # by default cached rows are kept
    assert WIFI_MAX_AGE_MS is None
    assert raw_trace.report.stale_wifi_readings == 0
    assert sum(len(e.readings) for e in raw_trace.wifi) > n_fresh


def test_beacons_and_merged_radio_events(raw_trace: IlcWalk) -> None:
    assert len(raw_trace.ble) == 1
    (beacon,) = raw_trace.ble
    assert beacon.t_ms == 1574248436014
    # keyed by the MAC: the iBeacon id is shared by many beacons
    assert beacon.readings[0].emitter == "7c:58:5a:21:c9:65"
    assert beacon.readings[0].rssi_dbm == -96.0
    events = raw_trace.radio_events()
    assert len(events) == len(raw_trace.wifi) + len(raw_trace.ble)
    assert [e.t_ms for e in events] == sorted(e.t_ms for e in events)


def damage(lines: list[str]) -> tuple[list[str], int]:
    """The sample with the defects seen in the wild; returns (lines, bad records added).

    - an accelerometer line and the magnetometer line after it run together (no newline);
    - a non-numeric gyroscope value, a NaN rotation value, a non-numeric WiFi RSSI;
    - an unknown record type, a line without any TAB, a non-numeric timestamp;
    - a last line cut in the middle of a number (no final newline).
    """
    out = list(lines)
    kinds = [line.split("\t")[1] if "\t" in line else "" for line in out]
    i = kinds.index("TYPE_ACCELEROMETER")
    assert kinds[i + 1] == "TYPE_MAGNETIC_FIELD"
    out[i : i + 2] = [out[i] + out[i + 1]]
    kinds[i : i + 2] = ["joined"]

    def corrupt(kind: str, field: int, value: str, nth: int = 0) -> None:
        index = [j for j, k in enumerate(kinds) if k == kind][nth]
        fields = out[index].split("\t")
        fields[field] = value
        out[index] = "\t".join(fields)

    corrupt("TYPE_GYROSCOPE", 3, "0.0l9836426")
    corrupt("TYPE_ROTATION_VECTOR", 2, "NaN")
    corrupt("TYPE_WIFI", 4, "-4x")  # the first row: the strongest, fresh, BSSID unique
    out.insert(40, "1574248434700\tTYPE_FOO\t1\t2")
    out.insert(50, "garbage without any tab")
    out.insert(60, "15742484347OO\tTYPE_WAYPOINT\t1.0\t2.0")
    last_accel = [line for line in lines if "\tTYPE_ACCELEROMETER\t" in line][-1]
    out.append(last_accel[: len(last_accel) // 2])
    return out, 6


def test_damaged_trace_keeps_the_good_records(
    tmp_path: Path, raw_trace: IlcWalk, raw_lines: list[str]
) -> None:
    damaged_lines, n_bad = damage(raw_lines)
    path = tmp_path / f"{SAMPLE_ID}.txt"
    path.write_text("\n".join(damaged_lines), encoding="utf-8")  # no final newline
    tr = read_trace(path)
    clean = raw_trace
    assert tr.bad_lines == tr.report.bad_lines == n_bad
    assert tr.report.joined_lines == 1
    assert tr.report.skipped_types == {**clean.report.skipped_types, "TYPE_FOO": 1}
    # both joined records kept; one bad gyroscope and one bad rotation record dropped
    np.testing.assert_array_equal(tr.accel, clean.accel)
    np.testing.assert_array_equal(tr.magnetic, clean.magnetic)
    assert tr.gyro.shape[0] == clean.gyro.shape[0] - 1
    assert tr.rotation.shape[0] == clean.rotation.shape[0] - 1
    np.testing.assert_array_equal(tr.waypoint_t_ms, clean.waypoint_t_ms)
    np.testing.assert_array_equal(tr.waypoint_xy_m, clean.waypoint_xy_m)
    assert [e.t_ms for e in tr.wifi] == [e.t_ms for e in clean.wifi]
    dropped = set(clean.wifi[0].readings) - set(tr.wifi[0].readings)
    assert [r.emitter for r in dropped] == ["78:44:fd:9b:9e:45"]
    assert tr.wifi[1:] == clean.wifi[1:]
    assert tr.ble == clean.ble


def test_damaged_xz_stream_keeps_what_was_read(tmp_path: Path, ilc_dir: Path) -> None:
    source = ilc_dir / "site2" / "F4" / "path_data_files" / f"{SAMPLE_ID}.txt.xz"
    data = source.read_bytes()
    cut = tmp_path / source.name
    cut.write_bytes(data[: len(data) // 2])
    tr = read_trace(cut)
    full = read_trace(source)
    assert tr.report.bad_lines >= 1
    assert 0 < tr.accel.shape[0] < full.accel.shape[0]


line_fields = st.lists(
    st.text(alphabet="0123456789.-eE:TYPE_WIFIACL\t #", max_size=14), min_size=0, max_size=11
)
known_types = st.sampled_from(
    [
        "TYPE_WAYPOINT",
        "TYPE_WIFI",
        "TYPE_BEACON",
        "TYPE_ACCELEROMETER",
        "TYPE_GYROSCOPE_UNCALIBRATED",
    ]
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["1574248434607", "", "157424843460x"]), known_types, line_fields
        ),
        max_size=30,
    )
)
def test_arbitrary_lines_never_raise(rows: list[tuple[str, str, list[str]]]) -> None:
    text = "\n".join("\t".join([t, kind, *fields]) for t, kind, fields in rows)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.txt"
        path.write_text(text, encoding="utf-8")
        tr = read_trace(path)
    n_read = (
        tr.waypoint_t_ms.size
        + sum(a.shape[0] for a in (tr.accel, tr.gyro, tr.magnetic, tr.rotation))
        + sum(len(e.readings) for e in tr.wifi)
        + sum(len(e.readings) for e in tr.ble)
    )
    assert tr.report.bad_lines + n_read + tr.report.stale_wifi_readings <= len(rows) + text.count(
        "TYPE_"
    )


def test_uncalibrated_stream_stands_in_for_a_missing_calibrated_one(
    tmp_path: Path, raw_trace: IlcWalk, raw_lines: list[str]
) -> None:
    path = tmp_path / "no_magnetometer.txt"
    kept = [line for line in raw_lines if "\tTYPE_MAGNETIC_FIELD\t" not in line]
    path.write_text("\n".join(kept) + "\n", encoding="utf-8")
    tr = read_trace(path)
    assert tr.uncalibrated == frozenset({"magnetic"})
    np.testing.assert_array_equal(tr.magnetic[:, 0], raw_trace.magnetic[:, 0])
    # x, y, z minus the hard-iron estimate of TYPE_MAGNETIC_FIELD_UNCALIBRATED records ...
    uncal = np.array(
        [[float(v) for v in f[2:8]] for f in records(raw_lines, "TYPE_MAGNETIC_FIELD_UNCALIBRATED")]
    )
    np.testing.assert_allclose(tr.magnetic[:, 1:], uncal[:, :3] - uncal[:, 3:])
    # ... which is Android's calibrated value (14 of 948 values here differ: the logger
    # paired a neighbouring sample)
    same = np.abs(tr.magnetic[:, 1:] - raw_trace.magnetic[:, 1:]).max(axis=1) < 1e-4
    assert same.mean() > 0.95
    np.testing.assert_array_equal(tr.gyro, raw_trace.gyro)


@pytest.mark.parametrize(
    ("name", "level"),
    [("B2", -2), ("B1", -1), ("F1", 0), ("F2", 1), ("F8", 7), ("1F", 0), ("L3", 2), ("b1", -1)],
)
def test_floor_level(name: str, level: int) -> None:
    assert floor_level(name) == level


@pytest.mark.parametrize("name", ["F0", "Mezzanine", "F", ""])
def test_floor_level_refuses_unknown_names(name: str) -> None:
    with pytest.raises(ValueError, match="level"):
        floor_level(name)
