"""``indoorpos evaluate``: ILC, IPIN and UJI runs from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lab.datasets.ilc import read_site
from lab.datasets.uji import Fingerprints
from server.cli.main import app
from tests.support.datasets import DATA_DIR
from tests.support.lab_fakes import uji_offset_sets

SITE2 = DATA_DIR / "ilc20-sample" / "site2"
IPIN_VENUE = DATA_DIR / "ipin2023-track3-dev"
needs_data = pytest.mark.skipif(
    not SITE2.is_dir(), reason="../shared/data is not beside the project"
)
needs_ipin = pytest.mark.skipif(
    not IPIN_VENUE.is_dir(), reason="../shared/data is not beside the project"
)


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


@needs_ipin
def test_cli_refuses_an_unknown_parameter() -> None:
    result = CliRunner().invoke(
        app, ["evaluate", "ipin", str(IPIN_VENUE), "--engine", "wknn", "--param", "nope=1"]
    )
    assert result.exit_code == 2
    assert "nope" in result.output


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
    train, test = uji_offset_sets()
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
