"""Indoor Location Competition 2.0 reader on the real site2 sample, clean and damaged."""

from __future__ import annotations

import itertools
import tempfile
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from matplotlib.path import Path as PolygonPath
from numpy.typing import NDArray

from server.datasets.ilc import (
    WIFI_MAX_AGE_MS,
    IlcTrace,
    floor_level,
    read_site,
    read_trace,
)
from server.positioning.events import ImuEvent, RadioReading, WifiEvent

SAMPLE_ID = "5dd5206850e04e0006f56460"  # site2/F4, also uncompressed in sample_raw/
SITE2_FLOORS = ("B1", "F1", "F2", "F3", "F4", "F5", "F6", "F7", "F8")


@pytest.fixture(scope="module")
def raw_path(ilc_dir: Path) -> Path:
    return ilc_dir / "sample_raw" / f"{SAMPLE_ID}.txt"


@pytest.fixture(scope="module")
def raw_lines(raw_path: Path) -> list[str]:
    return raw_path.read_text(encoding="utf-8").splitlines()


@pytest.fixture(scope="module")
def raw_trace(raw_path: Path) -> IlcTrace:
    return read_trace(raw_path)


def records(lines: list[str], kind: str) -> list[list[str]]:
    """Fields of the data lines of one type, split by hand."""
    return [f for f in (line.split("\t") for line in lines) if len(f) > 1 and f[1] == kind]


def test_txt_and_xz_give_the_same_trace(ilc_dir: Path, raw_trace: IlcTrace) -> None:
    xz = read_trace(ilc_dir / "site2" / "F4" / "path_data_files" / f"{SAMPLE_ID}.txt.xz")
    assert (raw_trace.path_id, xz.path_id) == (SAMPLE_ID, SAMPLE_ID)
    assert (raw_trace.floor, xz.floor) == ("F4", "F4")  # header FloorName / directory name
    assert raw_trace.site_id == xz.site_id == "5dbc1d84c1eb61796cf7c010"
    for name in ("waypoint_t_ms", "waypoint_xy_m", "accel", "gyro", "magnetic", "rotation"):
        np.testing.assert_array_equal(getattr(raw_trace, name), getattr(xz, name))
    assert raw_trace.wifi == xz.wifi
    assert raw_trace.ble == xz.ble
    assert raw_trace.skipped_types == xz.skipped_types


def test_sample_trace_contents(raw_trace: IlcTrace, raw_lines: list[str]) -> None:
    tr = raw_trace
    assert tr.bad_lines == 0
    assert tr.joined_lines == 0
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
    assert tr.skipped_types == {
        "TYPE_BLU4": 209,
        "TYPE_BLUE": 209,
        "TYPE_DIST1": 1,
        "TYPE_DIST2": 1,
        "TYPE_SENSOR_MAGNETIC_FIELD_ACCURACY_CHANGED": 1,
    }
    assert 6000 < tr.duration_ms < 7000


def test_wifi_rows_are_grouped_by_scan_time(
    raw_path: Path, raw_trace: IlcTrace, raw_lines: list[str]
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
    n_fresh = sum(len(e.readings) for e in filtered.wifi)
    assert n_fresh + filtered.stale_wifi_readings <= len(rows)  # a BSSID twice: merged
    # by default cached rows are kept
    assert WIFI_MAX_AGE_MS is None
    assert raw_trace.stale_wifi_readings == 0
    assert sum(len(e.readings) for e in raw_trace.wifi) > n_fresh


def test_beacons_and_merged_radio_events(raw_trace: IlcTrace) -> None:
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
    tmp_path: Path, raw_trace: IlcTrace, raw_lines: list[str]
) -> None:
    damaged_lines, n_bad = damage(raw_lines)
    path = tmp_path / f"{SAMPLE_ID}.txt"
    path.write_text("\n".join(damaged_lines), encoding="utf-8")  # no final newline
    tr = read_trace(path)
    clean = raw_trace
    assert tr.bad_lines == n_bad
    assert tr.joined_lines == 1
    assert tr.skipped_types == {**clean.skipped_types, "TYPE_FOO": 1}
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
    assert tr.bad_lines >= 1
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
    assert tr.bad_lines + n_read + tr.stale_wifi_readings <= len(rows) + text.count("TYPE_")


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


def test_read_site_lists_site2(ilc_dir: Path) -> None:
    site = read_site(ilc_dir / "site2")
    assert site.name == "site2"
    assert tuple(f.name for f in site.floors) == SITE2_FLOORS
    assert tuple(f.level for f in site.floors) == tuple(range(-1, 8))
    assert sum(len(f.trace_files) for f in site.floors) == 417
    for floor in site.floors:
        assert floor.trace_files
        assert list(floor.trace_files) == sorted(floor.trace_files)
        assert all(p.name.endswith(".txt.xz") for p in floor.trace_files)
        assert floor.width_m > 100.0
        assert floor.height_m > 100.0
        assert floor.plan is not None
        kinds = [ft["properties"]["kind"] for ft in floor.plan["features"]]
        assert kinds[0] == "outline"
        assert set(kinds[1:]) == {"unit"}
        outline = np.concatenate([np.asarray(p[0]) for p in outline_polygons(floor.plan)])
        np.testing.assert_allclose(outline.min(axis=0), [0.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(outline.max(axis=0), [floor.width_m, floor.height_m])


def test_read_site_on_a_floor_directory(ilc_dir: Path) -> None:
    site = read_site(ilc_dir / "site2" / "F4")
    assert site.name == "site2"
    (floor,) = site.floors
    assert (floor.name, floor.level, len(floor.trace_files)) == ("F4", 3, 26)


def test_read_site_names_the_bad_floor_directory(tmp_path: Path) -> None:
    (tmp_path / "F1" / "path_data_files").mkdir(parents=True)
    (tmp_path / "Mezzanine" / "path_data_files").mkdir(parents=True)
    with pytest.raises(ValueError, match="Mezzanine"):
        read_site(tmp_path)
    with pytest.raises(ValueError, match="no floor directories"):
        read_site(tmp_path / "F1" / "path_data_files")


def outline_polygons(plan: dict[str, Any]) -> list[list[list[list[float]]]]:
    geometry = plan["features"][0]["geometry"]
    if geometry["type"] == "Polygon":
        return [geometry["coordinates"]]
    polygons: list[list[list[list[float]]]] = geometry["coordinates"]
    return polygons


def inside(polygon: list[list[list[float]]], xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Inside the exterior ring and outside every hole."""
    result = PolygonPath(np.asarray(polygon[0])).contains_points(xy)
    for hole in polygon[1:]:
        result &= ~PolygonPath(np.asarray(hole)).contains_points(xy)
    return result


@pytest.mark.parametrize("floor_name", ["B1", "F1", "F8"])
def test_waypoints_lie_inside_the_floor_outline(ilc_dir: Path, floor_name: str) -> None:
    site = read_site(ilc_dir / "site2" / floor_name)
    (floor,) = site.floors
    assert floor.plan is not None
    units = [
        ft["geometry"]["coordinates"]
        for ft in floor.plan["features"][1:]
        if ft["geometry"]["type"] == "Polygon"
    ]
    for path in floor.trace_files[:3]:
        xy = read_trace(path).waypoint_xy_m
        assert xy.shape[0] > 0
        in_outline = np.zeros(xy.shape[0], dtype=bool)
        for polygon in outline_polygons(floor.plan):
            in_outline |= inside(polygon, xy)
        assert in_outline.all(), f"{path.name}: waypoints outside the outline"
        in_unit = Counter(int(i) for u in units for i in np.flatnonzero(inside(u, xy)))
        assert not in_unit, f"{path.name}: waypoints inside shops"


def test_uncalibrated_stream_stands_in_for_a_missing_calibrated_one(
    tmp_path: Path, raw_trace: IlcTrace, raw_lines: list[str]
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


def streams_of(trace: IlcTrace) -> dict[str, NDArray[np.float64]]:
    return {
        "accel": trace.accel,
        "gyro": trace.gyro,
        "magnetic": trace.magnetic,
        "rotation": trace.rotation,
    }


def joined(blocks: list[ImuEvent], sensor: str) -> NDArray[np.float64]:
    return np.concatenate([b.sensors()[sensor] for b in blocks])


@pytest.mark.parametrize("block_ms", [1, 250, 1000, 60_000])
def test_imu_blocks_hold_every_sample_once(raw_trace: IlcTrace, block_ms: int) -> None:
    blocks = raw_trace.imu_events(block_ms)
    t0 = min(a[0, 0] for a in streams_of(raw_trace).values())
    starts = [b.t_ms for b in blocks]
    assert starts[0] == t0
    assert all(b > a for a, b in itertools.pairwise(starts))
    assert all((s - t0) % block_ms == 0 for s in starts)
    for block in blocks:
        times = [a[:, 0] for a in block.sensors().values() if a.shape[0]]
        assert times, "a block without samples"
        for t in times:
            assert block.t_ms <= t[0]
            assert t[-1] < block.t_ms + block_ms
            assert np.all(np.diff(t) > 0)
        assert block.pressure.shape == (0, 2)
        assert block.magnetic_calibrated
    for name, samples in streams_of(raw_trace).items():
        got = joined(blocks, name)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got[:, :4], samples)
    # the sample trace: 6.5 s of phone time
    if block_ms == 1000:
        assert len(blocks) == 7


def test_imu_blocks_complete_the_rotation_quaternion(raw_trace: IlcTrace) -> None:
    rotation = joined(raw_trace.imu_events(), "rotation")
    assert rotation.shape == (raw_trace.rotation.shape[0], 5)
    xyz, w = rotation[:, 1:4], rotation[:, 4]
    assert np.all(w >= 0)
    np.testing.assert_allclose(w, np.sqrt(1.0 - np.sum(xyz**2, axis=1)))
    np.testing.assert_allclose(np.linalg.norm(rotation[:, 1:], axis=1), 1.0, atol=1e-7)


def test_imu_blocks_of_an_uncalibrated_magnetometer_are_calibrated(
    tmp_path: Path, raw_lines: list[str]
) -> None:
    # the reader subtracts the phone's hard-iron estimate from uncalibrated records
    path = tmp_path / "no_magnetometer.txt"
    kept = [line for line in raw_lines if "\tTYPE_MAGNETIC_FIELD\t" not in line]
    path.write_text("\n".join(kept) + "\n", encoding="utf-8")
    tr = read_trace(path)
    assert tr.uncalibrated == frozenset({"magnetic"})
    blocks = tr.imu_events()
    assert all(b.magnetic_calibrated for b in blocks)
    np.testing.assert_array_equal(joined(blocks, "magnetic"), tr.magnetic)


def test_imu_blocks_keep_one_sample_per_millisecond(raw_trace: IlcTrace) -> None:
    # a second row at the time of row 10, other values: the first one is kept
    repeated = np.insert(raw_trace.accel, 11, raw_trace.accel[10] + [0.0, 1.0, 1.0, 1.0], axis=0)
    blocks = replace(raw_trace, accel=repeated).imu_events()
    np.testing.assert_array_equal(joined(blocks, "accel"), raw_trace.accel)


def test_imu_blocks_need_a_positive_length(raw_trace: IlcTrace) -> None:
    with pytest.raises(ValueError, match="block_ms"):
        raw_trace.imu_events(0)


def test_trace_without_motion_samples_has_no_imu_blocks(raw_trace: IlcTrace) -> None:
    none = np.zeros((0, 4))
    still = replace(raw_trace, accel=none, gyro=none, magnetic=none, rotation=none)
    assert still.imu_events() == []
    assert still.events(imu=True) == still.radio_events()


def test_events_merge_scans_and_imu_blocks_by_time(raw_trace: IlcTrace) -> None:
    assert raw_trace.events() == raw_trace.radio_events()
    assert raw_trace.events(imu=False) == raw_trace.radio_events()
    blocks = raw_trace.imu_events()
    # a scan at the very start of a block comes before it
    scan_at_block = WifiEvent(blocks[2].t_ms, (RadioReading("02:00:00:00:00:01", -50.0),))
    trace = replace(raw_trace, wifi=(*raw_trace.wifi, scan_at_block))
    merged = trace.events(imu=True)
    assert [e.t_ms for e in merged] == sorted(e.t_ms for e in merged)
    assert [e for e in merged if not isinstance(e, ImuEvent)] == trace.radio_events()
    merged_blocks = [e for e in merged if isinstance(e, ImuEvent)]
    assert [b.t_ms for b in merged_blocks] == [b.t_ms for b in blocks]
    assert merged.index(scan_at_block) + 1 == next(
        i for i, e in enumerate(merged) if e.t_ms == scan_at_block.t_ms and isinstance(e, ImuEvent)
    )
