"""ILC evaluation: a whole run on one floor, and what the replayer is given."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from server.cli import app
from server.datasets.ilc import read_site
from server.lab import ilc_evaluation
from server.positioning.events import Event, Fix, ImuEvent

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SITE2 = DATA / "ilc20-sample" / "site2"
needs_data = pytest.mark.skipif(
    not SITE2.is_dir(), reason="../shared/data is not beside the project"
)


@needs_data
def test_evaluate_ilc_replays_imu_blocks_to_an_engine_that_reads_them(imu_engine: str) -> None:
    seen: dict[str, list[list[Event]]] = {}

    def capture(
        engine: str, _maps: object, _labelled: object, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        seen[engine] = traces
        return [[] for _ in traces]

    for engine in ("wknn", imu_engine):
        ilc_evaluation.evaluate_ilc(SITE2 / "F4", engine, replayer=capture)
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
