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
from server.positioning.engines import ENGINES, get_engine
from server.positioning.events import Event, Fix, ImuEvent, RadioReading, StepEvent, WifiEvent
from server.services import evaluation

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


def test_engine_params_replace_scalars_by_name() -> None:
    from server.services.evaluation import engine_params

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
