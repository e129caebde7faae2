"""UJIIndoorLoc-style evaluation: per-phone RSS offsets."""

from __future__ import annotations

import pytest

from lab import uji_evaluation
from tests.support.lab_fakes import uji_offset_sets


def test_uji_phone_offsets_are_estimated_on_training_and_reduce_the_error() -> None:
    train, test = uji_offset_sets()
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
    train, test = uji_offset_sets()
    only = train.phone_id == 1
    one_phone = train.rows(only)
    corrected = uji_evaluation.evaluate_uji(one_phone, test, "wknn", device_offsets=True)
    plain = uji_evaluation.evaluate_uji(one_phone, test, "wknn")
    assert corrected["device_offsets"] == {}  # nothing co-located: nothing to estimate
    assert corrected["test_rows_corrected"] == 0
    assert corrected["mean_m"] == plain["mean_m"]


def test_uji_fixes_report_radii_learned_on_the_training_spots() -> None:
    train, test = uji_offset_sets()
    kinds, matched, errors = uji_evaluation.held_out_errors(train)
    assert len(kinds) == len(matched) == len(errors) > 0
    assert all(m >= 1 for m in matched)
    report = uji_evaluation.evaluate_uji(train, test, "wknn")
    assert 0.0 <= report["within_68"] <= report["within_95"] <= 1.0
