"""Signature quality check (``papers/003_*`` IV-D) and fixed-AP identification (IV-E1)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.mapping.signatures import (
    FEW_APS,
    FEW_DAYS,
    FEW_READINGS,
    FEW_STRONG_POSITIONS,
    FIXED,
    KEPT,
    NOT_HEARD,
    NOT_STRONG,
    OUTLIER,
    SPREAD,
    WEAK,
    FixedApParams,
    SignatureQC,
    check_signatures,
    identify_fixed_aps,
    iqr_inliers,
)

T0 = 1_700_000_000_000
DAY = 86_400_000
# eight readings of one AP in one cell: Q1 = -62.25, Q3 = -58.75, IQR = 3.5,
# fence [-67.5, -53.5]
CLEAN = [-63.0, -62.0, -61.0, -60.0, -60.0, -59.0, -58.0, -57.0]


def _rows(cell: int, emitter: int, values: list[float]) -> list[tuple[int, int, float]]:
    return [(cell, emitter, v) for v in values]


def _qc(rows: list[tuple[int, int, float]], **kwargs: Any) -> SignatureQC:
    cell = np.array([r[0] for r in rows], dtype=np.int64)
    emitter = np.array([r[1] for r in rows], dtype=np.int64)
    rssi = np.array([r[2] for r in rows], dtype=np.float64)
    return check_signatures(cell, emitter, rssi, **kwargs)


# ---------------------------------------------------------------- IV-D


def test_quality_check_drops_exactly_what_was_planted() -> None:
    rows: list[tuple[int, int, float]] = []
    # cell 7: six APs with clean readings; planted: two outliers, one weak reading
    for ap in range(6):
        rows += _rows(7, ap, CLEAN)
    planted_outliers = [len(rows), len(rows) + 1]
    rows += [(7, 0, -40.0), (7, 3, -80.0)]
    planted_weak = len(rows)
    rows += [(7, 2, -90.5)]
    rows += [(7, 2, -90.0)]  # exactly -90 dBm is not weak (and is an outlier of AP 2)
    # an AP with three readings in cell 7: too few, and the cell keeps its six APs
    planted_few = list(range(len(rows), len(rows) + 3))
    rows += _rows(7, 9, [-70.0, -71.0, -72.0])
    # cell 3: five APs only
    planted_poor = list(range(len(rows), len(rows) + 5 * 8))
    for ap in range(5):
        rows += _rows(3, ap, CLEAN)

    qc = _qc(rows)
    expected = np.full(len(rows), KEPT)
    expected[planted_outliers] = OUTLIER
    expected[planted_weak + 1] = OUTLIER  # the -90.0 reading of AP 2
    expected[planted_weak] = WEAK
    expected[planted_few] = FEW_READINGS
    expected[planted_poor] = FEW_APS
    np.testing.assert_array_equal(qc.reason, expected)
    assert qc.counts == {"kept": 48, "weak": 1, "few_readings": 3, "few_aps": 40, "outlier": 3}
    assert qc.cells.tolist() == [3, 7]
    assert qc.cell_n_aps.tolist() == [5, 6]
    assert qc.cell_kept.tolist() == [False, True]
    assert int(qc.keep.sum()) == 48


def test_fence_edges_are_kept() -> None:
    base = [-64.0, -62.0, -60.0, -58.0]
    group = [0] * 5
    # x the largest: Q1 = -62, Q3 = -58, IQR = 4, top of the fence -52
    assert iqr_inliers(group, [*base, -52.0]).all()
    assert iqr_inliers(group, [*base, -51.99]).tolist() == [True] * 4 + [False]
    # x the smallest: Q1 = -64, Q3 = -60, bottom of the fence -70
    assert iqr_inliers(group, [-70.0, *base]).all()
    assert iqr_inliers(group, [-70.01, *base]).tolist() == [False] + [True] * 4
    rows = []
    for ap in range(6):
        rows += _rows(0, ap, [*base, -52.0])
    assert _qc(rows).counts["outlier"] == 0


def test_parameters() -> None:
    rows = []
    for ap in range(4):
        rows += _rows(0, ap, [-70.0, -70.0, -71.0])
    qc = _qc(rows, min_readings=2, min_aps=4, min_rssi_dbm=-70.5)
    assert qc.counts == {"kept": 8, "weak": 4, "few_readings": 0, "few_aps": 0, "outlier": 0}
    assert _qc(rows, min_readings=2, min_aps=5).counts["few_aps"] == 12
    assert _qc(rows, min_readings=4, min_aps=1).counts["few_readings"] == 12


@given(
    data=st.lists(
        st.tuples(st.integers(0, 4), st.floats(-100.0, -30.0, allow_nan=False)),
        max_size=80,
    ),
    k=st.sampled_from([0.0, 0.5, 1.5, 3.0]),
)
def test_iqr_matches_numpy_percentiles(data: list[tuple[int, float]], k: float) -> None:
    group = np.array([g for g, _ in data], dtype=np.int64)
    values = np.array([v for _, v in data])
    inside = iqr_inliers(group, values, k)
    for g in np.unique(group):
        v = values[group == g]
        q1, q3 = np.percentile(v, [25, 75])
        lo, hi = q1 - k * (q3 - q1), q3 + k * (q3 - q1)
        np.testing.assert_array_equal(inside[group == g], (v >= lo) & (v <= hi))


@given(st.permutations(list(range(40))))
def test_quality_check_is_order_independent(order: list[int]) -> None:
    rng = np.random.default_rng(0)
    cell = rng.integers(0, 2, 40)
    emitter = rng.integers(0, 7, 40)
    rssi = rng.normal(-70, 10, 40).round()
    base = check_signatures(cell, emitter, rssi, min_readings=2)
    o = np.array(order)
    shuffled = check_signatures(cell[o], emitter[o], rssi[o], min_readings=2)
    np.testing.assert_array_equal(shuffled.reason, base.reason[o])


def test_quality_check_bad_input() -> None:
    assert _qc([]).counts["kept"] == 0
    with pytest.raises(ValueError, match="emitter must have shape"):
        check_signatures([0, 1], [0], [-60.0, -61.0])
    with pytest.raises(ValueError, match="rssi_dbm must be finite"):
        check_signatures([0], [0], [math.nan])
    with pytest.raises(ValueError, match="cell must hold integers"):
        check_signatures([0.5], [0], [-60.0])


# ---------------------------------------------------------------- IV-E1


def _readings(
    emitter: int,
    days: int,
    xy: np.ndarray,
    rssi_dbm: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Readings of one emitter on ``days`` consecutive days at the positions ``xy``."""
    n = xy.shape[0]
    t = T0 + (np.arange(n) % days) * DAY + rng.integers(0, 3_600_000, n)
    return np.full(n, emitter), np.full(n, rssi_dbm) + rng.normal(0, 1, n), t, xy


def _stack(*parts: tuple[np.ndarray, ...]) -> list[np.ndarray]:
    return [np.concatenate([p[i] for p in parts]) for i in range(4)]


def test_stationary_ap_is_fixed_moving_or_recent_ones_are_not() -> None:
    rng = np.random.default_rng(5)
    near = np.array([10.0, 20.0]) + rng.normal(0, 1.0, (40, 2))  # strong within ~1 m
    along = np.column_stack([np.linspace(0, 40, 40), np.full(40, 5.0)])  # carried 40 m
    weak_rows = _readings(4, 5, near, -70.0, rng)
    emitter, rssi, t, xy = _stack(
        _readings(0, 4, near, -45.0, rng),  # stationary, 4 days: fixed
        _readings(1, 4, along, -45.0, rng),  # moving: spread
        _readings(2, 2, near, -45.0, rng),  # stationary but only 2 days
        _readings(3, 3, near, -45.0, rng),  # 3 days is not more than three
        weak_rows,  # 5 days, never above -55 dBm: another floor or building
    )
    result = identify_fixed_aps(emitter, rssi, t, xy, n_emitters=6)
    assert result.fixed.tolist() == [True, False, False, False, False, False]
    assert result.reason.tolist() == [FIXED, SPREAD, FEW_DAYS, FEW_DAYS, NOT_STRONG, NOT_HEARD]
    assert result.n_days.tolist() == [4, 4, 2, 3, 5, 0]
    assert result.counts == {
        "fixed": 1,
        "not_heard": 1,
        "few_days": 2,
        "weak": 1,
        "few_strong_positions": 0,
        "spread": 1,
    }
    np.testing.assert_allclose(result.centroid_xy_m[0], near.mean(axis=0))
    assert result.cluster_area_m2[0] < 20.0
    # 40 m of corridor: A = π L² / 6 for a uniform segment (here 40 points on it)
    assert result.cluster_area_m2[1] == pytest.approx(2 * np.pi * np.var(along[:, 0]))
    assert result.cluster_area_m2[1] > 800.0
    assert math.isnan(result.max_rssi_dbm[5])
    assert math.isnan(result.cluster_area_m2[5])


def test_cluster_area_by_hand_and_its_threshold() -> None:
    # four corners of a 2 m square: mean squared distance 2 m², A = 4π
    xy = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
    t = T0 + np.arange(4) * DAY
    emitter = np.zeros(4, dtype=np.int64)
    rssi = np.full(4, -50.0)
    result = identify_fixed_aps(emitter, rssi, t, xy)
    assert result.cluster_area_m2[0] == pytest.approx(4 * np.pi)
    np.testing.assert_allclose(result.centroid_xy_m, [[1.0, 1.0]])
    area = float(result.cluster_area_m2[0])
    at = identify_fixed_aps(emitter, rssi, t, xy, params=FixedApParams(max_area_m2=area))
    assert at.reason.tolist() == [SPREAD]  # "within 100 m²": strictly below
    above = FixedApParams(max_area_m2=float(np.nextafter(area, math.inf)))
    assert identify_fixed_aps(emitter, rssi, t, xy, params=above).fixed.tolist() == [True]


def test_strength_threshold_is_strict_and_positions_may_be_missing() -> None:
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [np.nan, np.nan]])
    t = T0 + np.arange(4) * DAY
    emitter = np.zeros(4, dtype=np.int64)
    at = identify_fixed_aps(emitter, np.full(4, -55.0), t, xy)
    assert at.reason.tolist() == [NOT_STRONG]  # "greater than -55 dBm"
    r = np.array([-54.9, -54.9, -60.0, -40.0])  # the strongest reading has no position
    result = identify_fixed_aps(emitter, r, t, xy)
    assert result.n_cluster.tolist() == [2]
    assert result.reason.tolist() == [FEW_STRONG_POSITIONS]
    loose = FixedApParams(min_cluster_readings=2, cluster_dbm=-65.0)
    assert identify_fixed_aps(emitter, r, t, xy, params=loose).fixed.tolist() == [True]


def test_days_follow_the_local_midnight() -> None:
    # 23:30 and 00:30 UTC around four midnights: 5 UTC days, 4 days at UTC-1
    nights = T0 - T0 % DAY + np.arange(4) * DAY
    t = np.concatenate([nights - 1_800_000, nights + 1_800_000])
    n = t.size
    xy = np.zeros((n, 2))
    e = np.zeros(n, dtype=np.int64)
    r = np.full(n, -40.0)
    assert identify_fixed_aps(e, r, t, xy).n_days.tolist() == [5]
    shifted = FixedApParams(day_offset_ms=-3_600_000)
    assert identify_fixed_aps(e, r, t, xy, params=shifted).n_days.tolist() == [4]


@given(
    shift=st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)),
    angle=st.floats(-math.pi, math.pi),
)
def test_cluster_area_ignores_where_and_how_the_floor_is_drawn(
    shift: tuple[float, float], angle: float
) -> None:
    rng = np.random.default_rng(1)
    xy = rng.normal(0, 3, (25, 2))
    c, s = math.cos(angle), math.sin(angle)
    moved = xy @ np.array([[c, s], [-s, c]]) + np.array(shift)
    t = T0 + np.arange(25) * DAY
    e = np.zeros(25, dtype=np.int64)
    r = np.full(25, -50.0)
    a = identify_fixed_aps(e, r, t, xy).cluster_area_m2[0]
    b = identify_fixed_aps(e, r, t, moved).cluster_area_m2[0]
    assert b == pytest.approx(a, rel=1e-9)


def test_fixed_ap_bad_input() -> None:
    empty = identify_fixed_aps([], [], [], np.empty((0, 2)))
    assert empty.fixed.size == 0
    with pytest.raises(ValueError, match="xy_m must have shape"):
        identify_fixed_aps([0], [-50.0], [T0], [1.0, 2.0])
    with pytest.raises(ValueError, match="emitter must be in"):
        identify_fixed_aps([3], [-50.0], [T0], [[1.0, 2.0]], n_emitters=2)
    with pytest.raises(ValueError, match="t_ms must be finite"):
        identify_fixed_aps([0], [-50.0], [math.nan], [[1.0, 2.0]])
    with pytest.raises(ValueError, match="max_area_m2"):
        FixedApParams(max_area_m2=0.0)
