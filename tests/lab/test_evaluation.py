"""Evaluation harness: the split, the estimate at a waypoint, and a whole run on one floor."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from server.cli import app
from server.datasets.ilc import IlcFloor, IlcSite, IlcTrace, read_site
from server.datasets.uji import Fingerprints
from server.lab import evaluation
from server.positioning.engines import ENGINES, get_engine
from server.positioning.engines.base import FloorRef, SiteMaps
from server.positioning.events import Event, Fix, ImuEvent, RadioReading, StepEvent, WifiEvent
from server.positioning.floorplan_geojson import plan_from_geojson
from server.positioning.magnetic import MagneticMap
from server.positioning.mapping.magnetic_gridding import grid_from_samples, known_share

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SITE2 = DATA / "ilc20-sample" / "site2"
needs_data = pytest.mark.skipif(
    not SITE2.is_dir(), reason="../shared/data is not beside the project"
)


def _site(n_per_floor: tuple[int, ...]) -> IlcSite:
    floors = tuple(
        IlcFloor(
            name=f"F{i + 1}",
            level=i,
            width_m=10.0,
            height_m=10.0,
            plan=None,
            trace_files=tuple(Path(f"f{i}/p{j:03d}.txt") for j in range(n)),
        )
        for i, n in enumerate(n_per_floor)
    )
    return IlcSite("toy", floors)


def test_split_is_deterministic_disjoint_and_complete() -> None:
    site = _site((10, 5, 2, 1))
    a = evaluation.split_site(site, 7, 0.8)
    b = evaluation.split_site(site, 7, 0.8)
    assert a == b
    train, test = set(a.train), set(a.test)
    assert not train & test
    everything = {(i, p) for i, f in enumerate(site.floors) for p in f.trace_files}
    assert train | test == everything
    per_floor_train = [sum(1 for i, _ in a.train if i == f) for f in range(4)]
    assert per_floor_train == [8, 4, 1, 1]  # 80 %, at least one on each side when possible
    other = evaluation.split_site(site, 8, 0.8)
    assert other.train != a.train


def test_split_ignores_listing_order() -> None:
    site = _site((10,))
    shuffled = IlcSite(
        "toy", (IlcFloor("F1", 0, 10.0, 10.0, None, tuple(reversed(site.floors[0].trace_files))),)
    )
    assert evaluation.split_site(site, 3, 0.8) == evaluation.split_site(shuffled, 3, 0.8)


def _fix(t_ms: int, x_m: float, floor: int = 0) -> Fix:
    return Fix(t_ms, x_m, 0.0, floor, None, (4.0, 0.0, 0.0, 4.0), "wifi")


def _trace(**fields: Any) -> IlcTrace:
    none = np.zeros((0, 4))
    default: dict[str, Any] = {
        "path_id": "p",
        "floor": "F1",
        "site_id": None,
        "waypoint_t_ms": np.array([100, 200, 300], dtype=np.int64),
        "waypoint_xy_m": np.array([[0.0, 0.0], [5.0, 0.0], [9.0, 0.0]]),
        "wifi": (),
        "ble": (),
        "accel": none,
        "gyro": none,
        "magnetic": none,
        "rotation": none,
        "uncalibrated": frozenset(),
        "bad_lines": 0,
        "joined_lines": 0,
        "stale_wifi_readings": 0,
        "skipped_types": {},
        "t_first_ms": 0,
        "t_last_ms": 300,
    }
    return IlcTrace(**{**default, **fields})


def test_estimate_is_the_last_fix_at_or_before_the_waypoint() -> None:
    trace = _trace()
    fixes = [_fix(250, 7.0, floor=1), _fix(150, 4.0), _fix(200, 5.5)]
    est = evaluation.estimates_at_waypoints(trace, 0, fixes)
    assert np.isnan(est.est_xy_m[0]).all()  # nothing yet at t=100
    assert est.est_xy_m[1, 0] == 5.5  # the fix at exactly t=200
    assert est.est_xy_m[2, 0] == 7.0
    assert est.est_floor.tolist() == [-1, 0, 1]
    assert est.sigma_m[1] == pytest.approx(2.0)


def test_batches_cut_phone_time() -> None:
    events = [StepEvent(t, 0.7, 0.0) for t in (0, 400, 999, 1000, 2600)]
    cut = evaluation.batches(events, batch_ms=1000)
    assert [[e.t_ms for e in b] for b in cut] == [[0, 400, 999], [1000], [2600]]


@pytest.fixture
def imu_engine(monkeypatch: pytest.MonkeyPatch) -> str:
    """An engine that declares it reads raw IMU samples (step_ekf's code under it)."""
    spec = replace(get_engine("step_ekf"), name="imu_probe", uses=frozenset({"imu", "wifi"}))
    monkeypatch.setitem(ENGINES, spec.name, spec)
    return spec.name


def _scan(t_ms: int) -> WifiEvent:
    return WifiEvent(t_ms, (RadioReading("02:00:00:00:00:01", -60.0),))


def test_imu_blocks_are_replayed_only_to_engines_that_read_them(imu_engine: str) -> None:
    t = np.arange(0, 3000, 20, dtype=np.float64)
    accel = np.column_stack([t, np.zeros_like(t), np.zeros_like(t), np.full_like(t, 9.8)])
    trace = _trace(wifi=(_scan(0), _scan(2000)), accel=accel)
    assert evaluation.trace_events(trace, "step_ekf") == trace.radio_events()
    assert evaluation.trace_events(trace, "wknn") == trace.radio_events()
    events = evaluation.trace_events(trace, imu_engine)
    assert [(type(e).__name__, e.t_ms) for e in events] == [
        ("WifiEvent", 0),
        ("ImuEvent", 0),
        ("ImuEvent", 1000),
        ("WifiEvent", 2000),
        ("ImuEvent", 2000),
    ]
    blocks = [e for e in events if isinstance(e, ImuEvent)]
    np.testing.assert_array_equal(np.concatenate([b.accel for b in blocks]), accel)
    # a replay batch spans as much phone time as a block: one block per batch at most
    for batch in evaluation.batches(events):
        assert sum(isinstance(e, ImuEvent) for e in batch) <= 1


@needs_data
def test_evaluate_ilc_replays_imu_blocks_to_an_engine_that_reads_them(imu_engine: str) -> None:
    seen: dict[str, list[list[Event]]] = {}

    def capture(
        engine: str, _maps: object, _labelled: object, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        seen[engine] = traces
        return [[] for _ in traces]

    for engine in ("wknn", imu_engine):
        evaluation.evaluate_ilc(SITE2 / "F4", engine, replayer=capture)
    assert len(seen["wknn"]) == len(seen[imu_engine]) > 0
    for radio, everything in zip(seen["wknn"], seen[imu_engine], strict=True):
        assert not any(isinstance(e, ImuEvent) for e in radio)
        assert [e for e in everything if not isinstance(e, ImuEvent)] == radio
        blocks = [e for e in everything if isinstance(e, ImuEvent)]
        assert len(blocks) >= 5
        assert all(b.accel.shape[0] > 0 for b in blocks)


@needs_data
def test_evaluate_one_floor_from_the_command_line(tmp_path: Path) -> None:
    out = tmp_path / "out.json"
    plots = tmp_path / "plots"
    result = CliRunner().invoke(
        app,
        [
            "evaluate",
            "ilc",
            str(SITE2 / "F4"),
            "--engine",
            "wknn",
            "--json",
            str(out),
            "--plots",
            str(plots),
        ],
    )
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    site = read_site(SITE2 / "F4")
    n_traces = len(site.floors[0].trace_files)
    assert report["engine"] == "wknn"
    assert report["train_paths"] + report["test_paths"] == n_traces
    assert report["floor_hit_rate"] == 1.0  # one floor: nothing else to pick
    assert report["n_points"] > 0
    assert 0 < report["p50_m"] <= report["p90_m"] <= report["max_m"]
    assert (plots / "error_cdf.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list((plots / "wknn").glob("*.png"))) == report["test_paths"]


@needs_data
def test_evaluate_a_small_site_with_plain_and_xz_traces(tmp_path: Path) -> None:
    """Another site in the ILC layout: two floors, traces as .txt and .txt.xz mixed."""
    import lzma
    import shutil

    site_dir = tmp_path / "mini"
    for floor in ("F1", "F2"):
        source = SITE2 / floor
        target = site_dir / floor / "path_data_files"
        target.mkdir(parents=True)
        for name in ("floor_info.json", "geojson_map.json"):
            shutil.copy(source / name, site_dir / floor / name)
        for i, trace in enumerate(sorted((source / "path_data_files").glob("*.txt.xz"))[:5]):
            if i % 2:
                shutil.copy(trace, target / trace.name)
            else:
                (target / trace.name.removesuffix(".xz")).write_bytes(
                    lzma.decompress(trace.read_bytes())
                )
    out = tmp_path / "out.json"
    result = CliRunner().invoke(
        app, ["evaluate", "ilc", str(site_dir), "--engine", "wknn", "--json", str(out)]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["dataset"] == "ilc:mini"
    assert report["floors"] == 2
    assert report["train_paths"] == 8
    assert report["test_paths"] == 2
    assert report["n_points"] > 0
    per_floor = report["per_floor"]
    assert list(per_floor) == ["F1", "F2"]
    assert sum(f["test_paths"] for f in per_floor.values()) == 2
    assert sum(f["n_points"] for f in per_floor.values()) == report["n_points"]
    assert all("magnetic_coverage" not in f for f in per_floor.values())  # wknn: no field map


def test_engine_params_replace_scalars_by_name() -> None:
    from server.lab.evaluation import engine_params

    params = engine_params("two_stage_ekf", {"k": "8", "partition_radius_m": "5"})
    assert (params.k, params.partition_radius_m) == (8, 5.0)
    assert engine_params("wknn").k == 4
    with pytest.raises(ValueError, match="no parameter 'nope'"):
        engine_params("wknn", {"nope": "1"})
    with pytest.raises(ValueError, match="'k': 'x' is not a int"):
        engine_params("wknn", {"k": "x"})
    assert engine_params("pf_magnetic", {"weighting": "dtw"}).weighting == "dtw"
    with pytest.raises(ValueError, match="'tracker' of two_stage_ekf is not a number"):
        engine_params("two_stage_ekf", {"tracker": "x"})
    with pytest.raises(ValueError, match="k must be at least 1"):
        engine_params("wknn", {"k": "0"})


def _path(
    path_id: str, floor_index: int, rng: np.random.Generator, n: int
) -> evaluation.PathResult:
    truth = rng.uniform(0.0, 30.0, (n, 2))
    est = truth + rng.normal(0.0, 3.0, (n, 2))
    est[0] = np.nan  # no fix yet at the first waypoint
    est_floor = np.where(rng.random(n) < 0.8, floor_index, floor_index + 1)
    estimates = evaluation.WaypointEstimates(
        true_xy_m=truth,
        true_floor=np.full(n, floor_index, dtype=np.int64),
        est_xy_m=est,
        est_floor=est_floor.astype(np.int64),
        sigma_m=np.full(n, 2.0),
    )
    return evaluation.PathResult(path_id, floor_index, estimates, ())


def test_per_floor_figures_add_up_to_the_overall_ones() -> None:
    rng = np.random.default_rng(5)
    paths = [_path("a", 0, rng, 12), _path("b", 1, rng, 7), _path("c", 0, rng, 9)]
    plain = evaluation.summarize(paths, engine="e")
    summary = evaluation.summarize(paths, floor_names=["B1", "F1", "F2"], engine="e")
    assert {k: v for k, v in summary.items() if k != "per_floor"} == plain
    per_floor = summary["per_floor"]
    assert list(per_floor) == ["B1", "F1", "F2"]
    for key in ("n_points", "n_missing", "test_paths"):
        overall = summary.get(key, len(paths))
        assert sum(f[key] for f in per_floor.values()) == overall, key
    for name, index in (("B1", 0), ("F1", 1)):
        on_floor = [p.estimates for p in paths if p.floor_index == index]
        est = np.concatenate([e.est_xy_m for e in on_floor])
        truth = np.concatenate([e.true_xy_m for e in on_floor])
        found = ~np.isnan(est[:, 0])
        errors = np.hypot(*(est[found] - truth[found]).T)
        hits = np.concatenate([e.est_floor == index for e in on_floor])[found]
        assert per_floor[name]["mean_m"] == pytest.approx(float(np.mean(errors)))
        assert per_floor[name]["p90_m"] == pytest.approx(float(np.percentile(errors, 90)))
        assert per_floor[name]["floor_hit_rate"] == pytest.approx(float(np.mean(hits)))
        assert "magnetic_coverage" not in per_floor[name]  # no maps given
    assert per_floor["F2"]["test_paths"] == per_floor["F2"]["n_points"] == 0
    assert per_floor["F2"]["mean_m"] is None


# a 2 m x 4 m corridor along the left edge of a 4 m x 4 m floor
CORRIDOR = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"kind": "outline"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [[[0, 0], [2, 0], [2, 4], [0, 4], [0, 0]]],
            },
        }
    ],
}


def test_magnetic_coverage_counts_known_walkable_cells() -> None:
    plan = plan_from_geojson(CORRIDOR)
    # 1 m cells over the floor: the 8 cells of columns 0 and 1 are walkable; samples fall in
    # three of them, and in one cell beside the corridor
    centres = [(0.5, 0.5), (1.5, 1.5), (0.5, 2.5), (0.5, 2.7), (3.5, 0.5)]
    grid = grid_from_samples(
        centres, [50.0, 51.0, 52.0, 53.0, 54.0], cell_m=1.0, extent=(0.0, 0.0, 4.0, 4.0)
    )
    assert known_share(grid, plan) == 3 / 8
    assert known_share(grid, None) == 4 / 16  # without a plan: all cells
    assert known_share(None, plan) == 0.0
    beside = grid_from_samples([(3.5, 3.5)], [50.0], cell_m=1.0, extent=(3.0, 3.0, 4.0, 4.0))
    # a grid that reaches no walkable cell: the plan's walkable cells count, none known
    assert known_share(beside, plan) == 0.0

    floors = (FloorRef("toy", "F1", 0), FloorRef("toy", "F2", 1))
    maps = SiteMaps(floors, None, "v", plans=(plan, None), magnetic=MagneticMap((grid, None), "v"))
    # two waypoints walked on F1: one in a known cell, one at the centre of an unknown one
    truth = np.array([(0.5, 0.5), (1.5, 3.5)])
    walked = evaluation.PathResult(
        "p",
        0,
        evaluation.WaypointEstimates(
            true_xy_m=truth,
            true_floor=np.zeros(2, dtype=np.int64),
            est_xy_m=truth,
            est_floor=np.zeros(2, dtype=np.int64),
            sigma_m=np.ones(2),
        ),
        (),
    )
    summary = evaluation.summarize([walked], floor_names=["F1", "F2"], maps=maps)
    per_floor = summary["per_floor"]
    assert per_floor["F1"]["magnetic_coverage"] == 3 / 8
    assert per_floor["F1"]["magnetic_at_waypoints"] == 0.5
    assert per_floor["F2"]["magnetic_coverage"] == 0.0  # no training field on that floor
    assert per_floor["F2"]["magnetic_at_waypoints"] is None  # and no waypoint walked there


@needs_data
def test_magnetic_maps_are_drawn_per_floor(tmp_path: Path) -> None:
    site = read_site(SITE2 / "F4")
    split = evaluation.split_site(site, 0, 0.8)
    maps, _, _ = evaluation.build_site_maps(site, split.train[:4], magnetic=True)
    summary = evaluation.summarize([], floor_names=["F4"], maps=maps, engine="pf_magnetic")
    coverage = summary["per_floor"]["F4"]["magnetic_coverage"]
    assert 0.0 < coverage < 1.0  # four walks cover some of the corridors
    run = evaluation.IlcEvaluation(site, maps, split, (), summary)
    written = evaluation.write_ilc_plots([run], tmp_path)
    assert written[1:] == [tmp_path / "magnetic_F4.png"]
    assert written[1].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------- UJIIndoorLoc-style: per-phone offsets

UJI_AP_XY = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0], [15.0, 15.0]])


def _uji_fingerprints(
    xy_m: np.ndarray, phone_id: np.ndarray, offset_db: np.ndarray, rng: np.random.Generator
) -> Fingerprints:
    """Scans on one floor of one building from a log-distance field of five access points,
    each phone reading ``offset_db`` above it, with 2 dB noise."""
    d = np.linalg.norm(xy_m[:, None, :] - UJI_AP_XY[None, :, :], axis=2)
    rssi = -35.0 - 25.0 * np.log10(np.maximum(d, 1.0)) + offset_db[:, None]
    rssi += rng.normal(0.0, 2.0, rssi.shape)
    n = xy_m.shape[0]
    return Fingerprints(
        rssi_dbm=np.round(rssi).astype(np.float32),
        emitters=tuple(f"WAP{j + 1:03d}" for j in range(UJI_AP_XY.shape[0])),
        xy_m=xy_m.astype(np.float64),
        floor=np.zeros(n, dtype=np.int64),
        building=np.zeros(n, dtype=np.int64),
        t_s=np.zeros(n, dtype=np.int64),
        phone_id=phone_id.astype(np.int64),
    )


def _uji_offset_sets() -> tuple[Fingerprints, Fingerprints]:
    """Training: phone 1 (true level) surveys a 3 m grid twice; phone 2 (+8 dB) surveys its
    left third beside it. Test: phone 2 all over the floor, and phone 3 (unknown) a bit."""
    rng = np.random.default_rng(11)
    grid = np.array([(x, y) for x in range(0, 31, 3) for y in range(0, 31, 3)], dtype=float)
    left = grid[grid[:, 0] <= 9.0]
    xy = np.concatenate([grid, grid, left, left])
    phone = np.array([1] * (2 * len(grid)) + [2] * (2 * len(left)))
    train = _uji_fingerprints(xy, phone, np.where(phone == 2, 8.0, 0.0), rng)
    test_xy = rng.uniform(0.0, 30.0, (60, 2))
    test_phone = np.array([2] * 50 + [3] * 10)
    test = _uji_fingerprints(test_xy, test_phone, np.where(test_phone == 2, 8.0, 0.0), rng)
    return train, test


def test_uji_phone_offsets_are_estimated_on_training_and_reduce_the_error() -> None:
    train, test = _uji_offset_sets()
    plain = evaluation.evaluate_uji(train, test, "wknn")
    corrected = evaluation.evaluate_uji(train, test, "wknn", device_offsets=True)
    assert plain["device_offsets_applied"] is False
    assert "device_offsets" not in plain
    offsets = corrected["device_offsets"]
    assert list(offsets) == ["1", "2"]  # phone 3 never appears in training
    difference = offsets["2"]["offset_db"] - offsets["1"]["offset_db"]
    assert difference == pytest.approx(8.0, abs=0.5)
    assert offsets["2"]["n_pairs"] == 4 * 11 * 5  # its spots x the five access points
    assert all(o["std_db"] > 0 for o in offsets.values())
    assert corrected["train_rows_corrected"] == len(train)
    assert corrected["test_rows_known_phone"] == corrected["test_rows_corrected"] == 50
    assert corrected["mean_m"] < 0.8 * plain["mean_m"]


def test_uji_offsets_leave_a_set_of_one_phone_alone() -> None:
    train, test = _uji_offset_sets()
    only = train.phone_id == 1
    one_phone = replace(
        train,
        rssi_dbm=train.rssi_dbm[only],
        xy_m=train.xy_m[only],
        floor=train.floor[only],
        building=train.building[only],
        t_s=train.t_s[only],
        phone_id=train.phone_id[only],
    )
    corrected = evaluation.evaluate_uji(one_phone, test, "wknn", device_offsets=True)
    plain = evaluation.evaluate_uji(one_phone, test, "wknn")
    assert corrected["device_offsets"] == {}  # nothing co-located: nothing to estimate
    assert corrected["test_rows_corrected"] == 0
    assert corrected["mean_m"] == plain["mean_m"]


def _write_uji_csv(fingerprints: Fingerprints, path: Path) -> None:
    header = [*fingerprints.emitters, "LONGITUDE", "LATITUDE", "FLOOR", "BUILDINGID"]
    header += ["SPACEID", "RELATIVEPOSITION", "USERID", "PHONEID", "TIMESTAMP"]
    rssi = np.where(np.isnan(fingerprints.rssi_dbm), 100.0, fingerprints.rssi_dbm)
    rows = np.column_stack(
        [
            rssi,
            fingerprints.xy_m,
            fingerprints.floor,
            fingerprints.building,
            np.zeros((len(fingerprints), 3)),
            fingerprints.phone_id,
            fingerprints.t_s,
        ]
    )
    lines = [",".join(header)] + [",".join(f"{v:g}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")


def test_evaluate_uji_with_device_offsets_from_the_command_line(tmp_path: Path) -> None:
    train, test = _uji_offset_sets()
    _write_uji_csv(train, tmp_path / "train.csv")
    _write_uji_csv(test, tmp_path / "test.csv")
    out = tmp_path / "out.json"
    args = ["evaluate", "uji", str(tmp_path / "train.csv"), str(tmp_path / "test.csv")]
    result = CliRunner().invoke(app, [*args, "--device-offsets", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "per-phone RSS offsets" in result.output
    report = json.loads(out.read_text())
    assert report["device_offsets_applied"] is True
    assert set(report["device_offsets"]) == {"1", "2"}
    assert report["test_rows_corrected"] == 50


def test_walks_along_one_route_share_a_cross_validation_group() -> None:
    from server.services.traces import trace_from_events

    wifi = WifiEvent(1_000, (RadioReading("aa:bb", -60.0),))
    walk = trace_from_events([wifi], [(900, 1.0, 2.0), (1_100, 2.0, 2.0)])
    scans = evaluation.LabelledScans()
    scans.add_trace(walk, 0, group=3)
    scans.add_trace(walk, 0, group=3)
    scans.add_trace(walk, 0)
    scans.add_trace(walk, 0)
    assert len(scans.path) == 4
    assert scans.path[0] == scans.path[1]
    assert len({scans.path[1], scans.path[2], scans.path[3]}) == 3
