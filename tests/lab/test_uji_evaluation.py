"""UJIIndoorLoc-style evaluation: per-phone RSS offsets."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from server.cli import app
from server.datasets.uji import Fingerprints
from server.lab import uji_evaluation

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
    plain = uji_evaluation.evaluate_uji(train, test, "wknn")
    corrected = uji_evaluation.evaluate_uji(train, test, "wknn", device_offsets=True)
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
    corrected = uji_evaluation.evaluate_uji(one_phone, test, "wknn", device_offsets=True)
    plain = uji_evaluation.evaluate_uji(one_phone, test, "wknn")
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
