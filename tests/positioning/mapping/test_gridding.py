"""Gridding labelled fingerprints: statistics by hand, order independence, cell merging."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.mapping.gridding import build_radio_map, fold_radio_maps
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap

NAN = float("nan")
EMITTERS = ("wifi:a", "wifi:b", "wifi:c", "ble:never")


def test_statistics_by_hand() -> None:
    xy = [(0.1, 0.2), (0.5, 0.9), (0.9, 0.4), (3.5, 0.5)]
    rssi = [
        [-50.0, -70.0, -60.0, NAN],
        [-52.0, NAN, -60.0, NAN],
        [NAN, NAN, -60.0, NAN],
        [-80.0, NAN, NAN, NAN],
    ]
    m = build_radio_map(xy, np.zeros(4, dtype=int), rssi, EMITTERS, cell_m=1.0)
    assert m.emitters == EMITTERS  # a column heard nowhere is kept
    assert m.rp_floor.tolist() == [0, 0]
    np.testing.assert_allclose(m.rp_xy, [[0.5, 0.5], [3.5, 0.5]], rtol=1e-6)
    assert m.count.tolist() == [[2, 1, 3, 0], [1, 0, 0, 0]]
    np.testing.assert_allclose(
        m.mean_dbm,
        [[-51.0, -70.0, -60.0, MISSING_DBM], [-80.0, MISSING_DBM, MISSING_DBM, MISSING_DBM]],
    )
    # a: (1 + 1) / 1 = 2; b: one reading -> default 16; c: 0 -> floor 1; not heard -> 0
    np.testing.assert_allclose(m.var_db2, [[2.0, 16.0, 1.0, 0.0], [16.0, 0.0, 0.0, 0.0]])
    assert m.rp_xy.dtype == np.float32
    assert m.rp_floor.dtype == np.int32
    assert m.mean_dbm.dtype == np.float32
    assert m.var_db2.dtype == np.float32
    assert m.count.dtype == np.int32


def test_unbiased_variance_and_parameters() -> None:
    values = [-40.0, -44.0, -48.0]
    m = build_radio_map(
        [(2.2, 2.2)] * 3,
        [1, 1, 1],
        [[v] for v in values],
        ("wifi:a",),
        cell_m=2.0,
        default_var_db2=9.0,
        min_var_db2=20.0,
    )
    assert m.var_db2[0, 0] == pytest.approx(max(np.var(values, ddof=1), 20.0))
    one = build_radio_map([(0.0, 0.0)], [0], [[-40.0]], ("wifi:a",), default_var_db2=9.0)
    assert one.var_db2[0, 0] == pytest.approx(9.0)


def test_rps_are_ordered_by_floor_row_column() -> None:
    xy = [(0.5, 0.5), (5.5, 0.5), (0.5, 5.5), (-0.5, 0.5), (0.5, -0.5)]
    floor = [1, 0, 0, 0, 0]
    m = build_radio_map(xy, floor, np.full((5, 1), -50.0), ("wifi:a",))
    # floor 0: row -1 (y=-0.5); row 0: col -1 (x=-0.5) then col 5; row 5; then floor 1
    np.testing.assert_allclose(
        m.rp_xy, [(0.5, -0.5), (-0.5, 0.5), (5.5, 0.5), (0.5, 5.5), (0.5, 0.5)]
    )
    assert m.rp_floor.tolist() == [0, 0, 0, 0, 1]


def test_same_cell_on_two_floors_stays_apart() -> None:
    m = build_radio_map([(0.5, 0.5), (0.5, 0.5)], [0, 1], [[-50.0], [-70.0]], ("wifi:a",))
    assert m.rp_floor.tolist() == [0, 1]
    assert m.mean_dbm[:, 0].tolist() == [-50.0, -70.0]


def test_empty_input_gives_an_empty_map() -> None:
    m = build_radio_map(np.zeros((0, 2)), np.zeros(0, dtype=int), np.zeros((0, 2)), ("a", "b"))
    assert m.rp_xy.shape == (0, 2)
    assert m.mean_dbm.shape == (0, 2)
    assert m.emitters == ("a", "b")


@pytest.mark.parametrize(
    ("xy", "floor", "rssi", "cell", "message"),
    [
        (np.zeros((2, 3)), [0, 0], np.zeros((2, 1)), 1.0, "xy_m"),
        (np.zeros((2, 2)), [0], np.zeros((2, 1)), 1.0, "floor"),
        (np.zeros((2, 2)), [0.5, 1.0], np.zeros((2, 1)), 1.0, "integers"),
        (np.zeros((2, 2)), [0, 0], np.zeros((2, 2)), 1.0, "rssi_dbm"),
        (np.full((2, 2), np.nan), [0, 0], np.zeros((2, 1)), 1.0, "finite"),
        (np.zeros((2, 2)), [0, 0], np.zeros((2, 1)), 0.0, "cell_m"),
    ],
)
def test_bad_input_is_refused(
    xy: NDArray[np.float64],
    floor: list[float],
    rssi: NDArray[np.float64],
    cell: float,
    message: str,
) -> None:
    with pytest.raises(ValueError, match=message):
        build_radio_map(xy, np.asarray(floor), rssi, ("wifi:a",), cell_m=cell)


point = st.tuples(
    st.floats(-6.0, 6.0),
    st.floats(-6.0, 6.0),
    st.integers(0, 2),
    st.lists(st.one_of(st.just(NAN), st.floats(-99.0, -30.0)), min_size=3, max_size=3),
)


def _build(points: list[tuple[float, float, int, list[float]]], cell_m: float) -> RadioMap:
    return build_radio_map(
        np.array([(p[0], p[1]) for p in points], dtype=np.float64).reshape(-1, 2),
        np.array([p[2] for p in points], dtype=np.int64),
        np.array([p[3] for p in points], dtype=np.float64).reshape(-1, 3),
        ("wifi:a", "wifi:b", "ble:c"),
        cell_m=cell_m,
    )


@settings(max_examples=150, deadline=None)
@given(
    points=st.lists(point, min_size=1, max_size=30),
    cell_m=st.sampled_from([0.5, 1.0, 2.5]),
    data=st.data(),
)
def test_map_is_independent_of_point_order(
    points: list[tuple[float, float, int, list[float]]], cell_m: float, data: st.DataObject
) -> None:
    shuffled = data.draw(st.permutations(points))
    a, b = _build(points, cell_m), _build(shuffled, cell_m)
    np.testing.assert_array_equal(a.rp_floor, b.rp_floor)
    np.testing.assert_array_equal(a.count, b.count)
    # sums in another order may differ in the last float64 bit
    np.testing.assert_allclose(a.rp_xy, b.rp_xy, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(a.mean_dbm, b.mean_dbm, rtol=1e-6)
    np.testing.assert_allclose(a.var_db2, b.var_db2, rtol=1e-4, atol=1e-4)
    # every heard cell statistic obeys the rules
    heard = a.count > 0
    assert np.all(a.var_db2[heard] >= 1.0)
    assert np.all(a.var_db2[~heard] == 0.0)
    assert np.all(a.mean_dbm[~heard] == MISSING_DBM)
    assert a.count.sum() == sum(1 for p in points for v in p[3] if not np.isnan(v))


@settings(max_examples=100, deadline=None)
@given(
    offsets=st.lists(
        st.tuples(st.floats(0.0, 1.999), st.floats(0.0, 1.999)), min_size=1, max_size=20
    ),
    cell=st.tuples(st.integers(-5, 5), st.integers(-5, 5)),
)
def test_points_in_one_cell_merge(
    offsets: list[tuple[float, float]], cell: tuple[int, int]
) -> None:
    xy = np.array(offsets) + 2.0 * np.array(cell)
    rssi = np.full((len(offsets), 1), -60.0)
    m = build_radio_map(xy, np.zeros(len(offsets), dtype=int), rssi, ("wifi:a",), cell_m=2.0)
    assert m.rp_xy.shape == (1, 2)
    np.testing.assert_allclose(m.rp_xy[0], xy.mean(axis=0), rtol=1e-6, atol=1e-5)
    assert m.count[0, 0] == len(offsets)


def _columns(m: RadioMap, emitters: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The map's statistics with its columns put in the order of ``emitters``."""
    idx = [m.emitters.index(k) for k in emitters]
    return m.count[:, idx], m.mean_dbm[:, idx], m.var_db2[:, idx]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_parts=st.integers(2, 4))
def test_folding_parts_equals_gridding_all_points(seed: int, n_parts: int) -> None:
    rng = np.random.default_rng(seed)
    n, n_em = 120, 6
    xy = rng.uniform(0.0, 6.0, (n, 2))
    floor = rng.integers(0, 2, n)
    rssi = rng.normal(-70.0, 6.0, (n, n_em))
    rssi[rng.random((n, n_em)) < 0.4] = np.nan
    names = tuple(f"wifi:ap{i}" for i in range(n_em))
    # no variance floor here, so the fold must be exact (the floor is tested by hand above)
    whole = build_radio_map(xy, floor, rssi, names, min_var_db2=0.0)
    parts = np.array_split(rng.permutation(n), n_parts)
    # each part hears only some of the emitters: columns come and go between parts
    folded = None
    for part in parts:
        keep = np.array([j for j in range(n_em) if not np.all(np.isnan(rssi[part, j]))])
        piece = build_radio_map(
            xy[part],
            floor[part],
            rssi[np.ix_(part, keep)],
            tuple(names[j] for j in keep),
            min_var_db2=0.0,
        )
        folded = piece if folded is None else fold_radio_maps(folded, piece, min_var_db2=0.0)
    assert folded is not None
    np.testing.assert_array_equal(folded.rp_floor, whole.rp_floor)
    np.testing.assert_allclose(folded.rp_xy, whole.rp_xy, atol=1e-5)
    assert folded.rp_points is not None
    np.testing.assert_array_equal(folded.rp_points, whole.rp_points)
    heard = tuple(k for k in names if k in folded.emitters)
    count, mean, var = _columns(folded, heard)
    w_count, w_mean, w_var = _columns(whole, heard)
    np.testing.assert_array_equal(count, w_count)
    np.testing.assert_allclose(mean, w_mean, atol=1e-3)
    two = w_count >= 2
    np.testing.assert_allclose(var[two], w_var[two], rtol=1e-3, atol=1e-3)
    np.testing.assert_array_equal(var[w_count == 1], 16.0)


def test_folding_needs_point_counts() -> None:
    m = build_radio_map([(0.5, 0.5)], [0], [[-60.0]], ("wifi:a",))
    bare = RadioMap(m.rp_xy, m.rp_floor, m.mean_dbm, m.var_db2, m.count, m.emitters)
    with pytest.raises(ValueError, match="rp_points"):
        fold_radio_maps(bare, m)


def test_a_mean_on_a_cells_edge_stays_in_its_cell_through_folds() -> None:
    """999.99999 m rounds to 1000.0 in float32: the RP must stay in cell 999, so the next
    fold adds to it rather than overwriting a neighbour."""
    edge = 1000.0 - 1e-5
    first = build_radio_map([(edge, 0.5), (edge, 0.5)], [0, 0], [[-60.0], [-62.0]], ("wifi:a",))
    assert np.floor(first.rp_xy[0, 0]) == 999.0
    second = build_radio_map([(999.5, 0.5)], [0], [[-70.0]], ("wifi:a",))
    folded = fold_radio_maps(first, second)
    assert folded.rp_xy.shape[0] == 1
    assert folded.count[0, 0] == 3
    assert folded.mean_dbm[0, 0] == pytest.approx(-64.0)
