"""UJIIndoorLoc and UJI long-term WiFi readers on the real files."""

from __future__ import annotations

import csv
import lzma
import tarfile
from pathlib import Path

import numpy as np
import pytest

from lab.datasets.uji import (
    PHONE_GALAXY_A5_2017,
    PHONE_GALAXY_S3,
    Fingerprints,
    LongTermFingerprints,
    read_uji_longterm,
    read_ujiindoorloc,
)


@pytest.fixture(scope="module")
def training(uji_dir: Path) -> Fingerprints:
    return read_ujiindoorloc(uji_dir / "trainingData.csv.xz")


def first_rows(path: Path, n: int) -> list[list[str]]:
    """Header and the first ``n`` rows, read with the csv module."""
    with lzma.open(path, "rt", encoding="utf-8", newline="") as f:
        reader = csv.reader(f)
        return [row for _, row in zip(range(n + 1), reader, strict=False)]


def test_training_set_shape_and_labels(training: Fingerprints) -> None:
    fp = training
    assert len(fp) == 19_937
    assert fp.rssi_dbm.shape == (19_937, 520)
    assert fp.rssi_dbm.dtype == np.float32
    assert fp.emitters[0] == "WAP001"
    assert fp.emitters[-1] == "WAP520"
    assert set(np.unique(fp.floor)) == {0, 1, 2, 3, 4}
    assert set(np.unique(fp.building)) == {0, 1, 2}
    assert fp.xy_m.shape == (19_937, 2)
    # Web-Mercator metres of the Jaume I campus (Castellón, about 0.07° W, 40° N)
    assert np.all((fp.xy_m[:, 0] > -7_700.0) & (fp.xy_m[:, 0] < -7_250.0))
    assert np.all((fp.xy_m[:, 1] > 4_864_700.0) & (fp.xy_m[:, 1] < 4_865_050.0))
    assert np.all((fp.t_s > 1_369_000_000) & (fp.t_s < 1_372_000_000))  # June 2013
    assert fp.phone_id.dtype == np.int64


def test_not_heard_becomes_nan(uji_dir: Path, training: Fingerprints) -> None:
    heard = training.rssi_dbm[~np.isnan(training.rssi_dbm)]
    assert heard.size > 0
    assert heard.min() >= -104.0
    assert heard.max() <= 0.0
    rows = first_rows(uji_dir / "trainingData.csv.xz", 200)
    header, body = rows[0], rows[1:]
    raw = np.array([[float(v) for v in row[:520]] for row in body])
    assert header[:520] == list(training.emitters)
    np.testing.assert_array_equal(np.isnan(training.rssi_dbm[:200]), raw == 100.0)
    np.testing.assert_array_equal(training.rssi_dbm[:200][raw != 100.0], raw[raw != 100.0])
    np.testing.assert_array_equal(training.xy_m[:200, 0], [float(r[520]) for r in body])
    np.testing.assert_array_equal(training.t_s[:200], [int(r[528]) for r in body])


def test_validation_set(uji_dir: Path) -> None:
    fp = read_ujiindoorloc(uji_dir / "validationData.csv.xz")
    assert fp.rssi_dbm.shape == (1_111, 520)
    assert set(np.unique(fp.floor)) <= {0, 1, 2, 3, 4}
    assert set(np.unique(fp.building)) == {0, 1, 2}


def test_plain_csv_reads_like_xz(tmp_path: Path, uji_dir: Path, training: Fingerprints) -> None:
    rows = first_rows(uji_dir / "trainingData.csv.xz", 25)
    plain = tmp_path / "part.csv"
    plain.write_text("\r\n".join(",".join(r) for r in rows) + "\r\n", encoding="utf-8")
    fp = read_ujiindoorloc(plain)
    np.testing.assert_array_equal(fp.rssi_dbm, training.rssi_dbm[:25])
    np.testing.assert_array_equal(fp.xy_m, training.xy_m[:25])
    np.testing.assert_array_equal(fp.floor, training.floor[:25])
    assert fp.emitters == training.emitters


def test_missing_column_is_named(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("WAP001,LONGITUDE,LATITUDE,FLOOR\n-50,1,2,0\n", encoding="utf-8")
    with pytest.raises(ValueError, match="BUILDINGID"):
        read_ujiindoorloc(path)


@pytest.fixture(scope="module")
def month2(longterm_dir: Path) -> LongTermFingerprints:
    return read_uji_longterm(longterm_dir / "db.tar.xz", month=2)


def test_longterm_one_month(month2: LongTermFingerprints) -> None:
    fp = month2
    # one training set of 576 and five test sets, the fourth with 816 rows
    assert fp.rssi_dbm.shape == (576 + 4 * 576 + 816, 620)
    assert fp.emitters[0] == "AP001"
    assert fp.emitters[-1] == "AP620"
    assert set(np.unique(fp.month)) == {2}
    assert np.count_nonzero(fp.split == "trn") == 576
    assert list(np.unique(fp.set_no[fp.split == "tst"])) == [1, 2, 3, 4, 5]
    assert set(np.unique(fp.floor)) == {3, 5}
    assert set(np.unique(fp.building)) == {0}
    assert set(np.unique(fp.phone_id)) == {PHONE_GALAXY_S3}
    assert np.all(np.isnan(fp.rssi_dbm) | (fp.rssi_dbm < 0.0))
    assert 0.9 < np.isnan(fp.rssi_dbm).mean() < 1.0
    assert np.all((fp.xy_m > -1.0) & (fp.xy_m < 40.0))  # library frame, metres
    assert np.all(np.diff(fp.t_ms[fp.split == "trn"]) > 0)
    np.testing.assert_array_equal(fp.t_s, fp.t_ms // 1000)
    # July 2016, local clock read as UTC
    assert np.all((fp.t_ms >= 1_467_331_200_000) & (fp.t_ms < 1_470_009_600_000))
    assert fp.point.min() == 1
    assert set(np.unique(fp.repetition)) == {1, 2, 3, 4, 5, 6}
    # a point is one place: every row of a (split, set, point) shares its coordinates
    trn = fp.split == "trn"
    for point in np.unique(fp.point[trn])[:10]:
        rows = trn & (fp.point == point)
        assert np.ptp(fp.xy_m[rows], axis=0).max() == 0.0


def test_longterm_split_and_directory_layout(
    tmp_path: Path, longterm_dir: Path, month2: LongTermFingerprints
) -> None:
    with tarfile.open(longterm_dir / "db.tar.xz") as tar:
        members = [m for m in tar if m.name.startswith("db/02/")]
        tar.extractall(tmp_path, members=members, filter="data")
    test = read_uji_longterm(tmp_path / "db", month=2, split="tst")
    assert isinstance(test, LongTermFingerprints)
    expected = month2.split == "tst"
    np.testing.assert_array_equal(test.rssi_dbm, month2.rssi_dbm[expected])
    np.testing.assert_array_equal(test.xy_m, month2.xy_m[expected])
    np.testing.assert_array_equal(test.t_ms, month2.t_ms[expected])
    with pytest.raises(ValueError, match="no set"):
        read_uji_longterm(tmp_path, month=3)


def test_longterm_last_month_has_the_second_phone(longterm_dir: Path) -> None:
    fp = read_uji_longterm(longterm_dir, month=25, split="trn")  # the folder of db.tar.xz
    assert fp.rssi_dbm.shape == (2 * 576, 620)
    assert list(fp.phone_id[fp.set_no == 1][:1]) == [PHONE_GALAXY_S3]
    assert set(np.unique(fp.phone_id[fp.set_no == 2])) == {PHONE_GALAXY_A5_2017}
