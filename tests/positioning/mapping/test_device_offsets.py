"""Per-device RSS offsets: recovery on a synthetic field, the constraint, robustness,
invariances, the closed form for two devices, and the honesty of the uncertainty."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.mapping.device_offsets import (
    DeviceOffset,
    apply_offsets,
    cell_ids,
    estimate_offsets,
    row_offsets,
    scan_readings,
)

TRUE_DB = {"a": 0.0, "b": 6.0, "c": -4.0}

Readings = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.str_]]


def _survey(
    seed: int,
    offsets_db: dict[str, float] = TRUE_DB,
    *,
    n_cell: int = 200,
    n_em: int = 8,
    visit: float = 0.6,
    noise_db: float = 3.0,
) -> Readings:
    """A field uniform in [-80, -45] dBm over cells x emitters; each device visits a share
    of the cells and reads every emitter there once, with its offset and Gaussian noise."""
    rng = np.random.default_rng(seed)
    field = rng.uniform(-80.0, -45.0, (n_cell, n_em))
    cell, emitter, rssi, device = [], [], [], []
    for name, offset in offsets_db.items():
        visited = np.flatnonzero(rng.random(n_cell) < visit)
        c = np.repeat(visited, n_em)
        e = np.tile(np.arange(n_em), visited.size)
        cell.append(c)
        emitter.append(e)
        rssi.append(field[c, e] + offset + rng.normal(0.0, noise_db, c.size))
        device.append(np.full(c.size, name))
    return (
        np.concatenate(cell),
        np.concatenate(emitter),
        np.concatenate(rssi),
        np.concatenate(device),
    )


def _weighted_truth(device: NDArray[np.str_], offsets_db: dict[str, float]) -> dict[str, float]:
    """The true offsets under the default constraint: reading-weighted mean 0."""
    n = {d: int((device == d).sum()) for d in offsets_db}
    mean = sum(n[d] * o for d, o in offsets_db.items()) / sum(n.values())
    return {d: o - mean for d, o in offsets_db.items()}


def test_recovers_three_offsets_within_half_a_db() -> None:
    cell, emitter, rssi, device = _survey(0)
    got = estimate_offsets(cell, emitter, rssi, device)
    want = _weighted_truth(device, TRUE_DB)
    assert set(got) == set(TRUE_DB)
    for name, offset in want.items():
        assert got[name].offset_db == pytest.approx(offset, abs=0.5)
    n = {d: int((device == d).sum()) for d in TRUE_DB}
    assert sum(n[d] * got[d].offset_db for d in TRUE_DB) == pytest.approx(0.0, abs=1e-9)


def test_counts_co_located_pairs() -> None:
    cell, emitter, rssi, device = _survey(1)
    got = estimate_offsets(cell, emitter, rssi, device, min_rssi_dbm=-np.inf)
    # by hand: a device's (cell, emitter) pairs that some other device heard too
    pairs = {
        d: set(zip(cell[device == d].tolist(), emitter[device == d].tolist(), strict=True))
        for d in TRUE_DB
    }
    for d in TRUE_DB:
        others = set().union(*(pairs[o] for o in TRUE_DB if o != d))
        assert got[d].n_pairs == len(pairs[d] & others)


def test_reference_device_has_offset_zero() -> None:
    cell, emitter, rssi, device = _survey(2)
    got = estimate_offsets(cell, emitter, rssi, device, reference="b")
    assert got["b"].offset_db == 0.0
    assert got["a"].offset_db == pytest.approx(-6.0, abs=0.5)
    assert got["c"].offset_db == pytest.approx(-10.0, abs=0.5)


def test_unknown_or_unestimable_reference_is_refused() -> None:
    cell, emitter, rssi, device = _survey(2)
    with pytest.raises(ValueError, match="reference 'z'"):
        estimate_offsets(cell, emitter, rssi, device, reference="z")
    lonely = np.concatenate([device[:-1], ["z"]])
    with pytest.raises(ValueError, match="reference 'z' has fewer than min_pairs"):
        estimate_offsets(cell, emitter, rssi, lonely, reference="z")


def test_outliers_move_the_offsets_by_less_than_one_db() -> None:
    cell, emitter, rssi, device = _survey(3)
    clean = estimate_offsets(cell, emitter, rssi, device)
    rng = np.random.default_rng(33)
    bad = rng.random(rssi.size) < 0.10
    sign = rng.choice([-1.0, 1.0], rssi.size)
    dirty = estimate_offsets(
        cell, emitter, np.where(bad, rssi + 30.0 * sign, rssi), device, min_rssi_dbm=-np.inf
    )
    for name in TRUE_DB:
        assert abs(dirty[name].offset_db - clean[name].offset_db) < 1.0


def test_device_without_co_located_pairs_is_absent() -> None:
    cell, emitter, rssi, device = _survey(4)
    far = np.full(50, cell.max() + 1)  # a cell no one else visited
    got = estimate_offsets(
        np.concatenate([cell, far]),
        np.concatenate([emitter, np.arange(50)]),
        np.concatenate([rssi, np.full(50, -60.0)]),
        np.concatenate([device, np.full(50, "loner")]),
    )
    assert set(got) == set(TRUE_DB)


def test_device_below_min_pairs_is_absent_and_the_rest_unchanged() -> None:
    cell, emitter, rssi, device = _survey(5)
    few = (device == "c") & (cell < 3)  # c keeps a handful of co-located pairs only
    keep = (device != "c") | few
    got = estimate_offsets(cell[keep], emitter[keep], rssi[keep], device[keep], reference="a")
    assert set(got) == {"a", "b"}
    assert got["b"].offset_db == pytest.approx(6.0, abs=0.5)
    assert estimate_offsets(cell, emitter, rssi, device, min_pairs=10**6) == {}


def test_separate_groups_keep_only_the_one_with_most_readings() -> None:
    cell, emitter, rssi, device = _survey(6, {"a": 0.0, "b": 3.0})
    other = _survey(7, {"x": 0.0, "y": -3.0}, n_cell=50)
    got = estimate_offsets(
        np.concatenate([cell, other[0] + 10_000]),  # cells nobody of a, b visited
        np.concatenate([emitter, other[1]]),
        np.concatenate([rssi, other[2]]),
        np.concatenate([device, other[3]]),
    )
    assert set(got) == {"a", "b"}


def test_readings_below_the_cut_are_not_used() -> None:
    cell, emitter, rssi, device = _survey(8)
    weak = np.full(cell.size, -95.0)
    base = estimate_offsets(cell, emitter, rssi, device)
    with_weak = estimate_offsets(
        np.concatenate([cell, cell]),
        np.concatenate([emitter, emitter]),
        np.concatenate([rssi, weak]),
        np.concatenate([device, device]),
    )
    assert with_weak == base


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    shift=st.floats(-40.0, 40.0, allow_nan=False),
)
def test_adding_a_constant_to_every_reading_changes_no_offset(seed: int, shift: float) -> None:
    cell, emitter, rssi, device = _survey(seed, n_cell=40)
    base = estimate_offsets(cell, emitter, rssi, device, min_rssi_dbm=-90.0)
    moved = estimate_offsets(cell, emitter, rssi + shift, device, min_rssi_dbm=-90.0 + shift)
    assert set(moved) == set(base)
    for name in base:
        assert moved[name].offset_db == pytest.approx(base[name].offset_db, abs=1e-6)
        assert moved[name].std_db == pytest.approx(base[name].std_db, abs=1e-6)
        assert moved[name].n_pairs == base[name].n_pairs


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), shift=st.floats(-10.0, 10.0, allow_nan=False))
def test_shifting_one_device_shifts_its_offset(seed: int, shift: float) -> None:
    cell, emitter, rssi, device = _survey(seed, n_cell=40)
    base = estimate_offsets(cell, emitter, rssi, device, reference="a", min_rssi_dbm=-np.inf)
    moved = estimate_offsets(
        cell,
        emitter,
        np.where(device == "c", rssi + shift, rssi),
        device,
        reference="a",
        min_rssi_dbm=-np.inf,
    )
    assert moved["c"].offset_db == pytest.approx(base["c"].offset_db + shift, abs=0.01)
    assert moved["b"].offset_db == pytest.approx(base["b"].offset_db, abs=0.01)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_reading_order_does_not_matter(seed: int) -> None:
    cell, emitter, rssi, device = _survey(seed, n_cell=30)
    order = np.random.default_rng(seed).permutation(cell.size)
    assert estimate_offsets(cell, emitter, rssi, device) == estimate_offsets(
        cell[order], emitter[order], rssi[order], device[order]
    )


@settings(max_examples=40, deadline=None)
@given(
    diffs=st.lists(st.integers(-20, 20), min_size=3, max_size=40),
    base=st.integers(-85, -40),
)
def test_two_devices_differ_by_the_median_of_their_differences(diffs: list[int], base: int) -> None:
    # closed form of eq 3-4 for two devices: o_b - o_a = median_p (y_pb - y_pa)
    n = len(diffs)
    pairs = np.arange(n)
    y_a = base + (pairs % 7).astype(np.float64)
    y_b = y_a + np.array(diffs, dtype=np.float64)
    got = estimate_offsets(
        np.concatenate([pairs, pairs]),
        np.zeros(2 * n, dtype=np.int64),
        np.concatenate([y_a, y_b]),
        np.array(["a"] * n + ["b"] * n),
        reference="a",
        min_pairs=1,
        min_rssi_dbm=-np.inf,
    )
    assert got["b"].offset_db == pytest.approx(float(np.median(diffs)), abs=1e-3)
    assert got["a"].n_pairs == got["b"].n_pairs == n


def test_reported_uncertainty_matches_the_scatter_of_repeated_estimates() -> None:
    # std_db is for the offset against the reference's level (module docstring, eq 7)
    estimates: dict[str, list[float]] = {"b": [], "c": []}
    reported: dict[str, list[float]] = {"b": [], "c": []}
    for seed in range(40):
        cell, emitter, rssi, device = _survey(100 + seed, n_cell=40)
        got = estimate_offsets(cell, emitter, rssi, device, reference="a")
        for name in estimates:
            estimates[name].append(got[name].offset_db)
            reported[name].append(got[name].std_db)
    for name in estimates:
        scatter = float(np.std(estimates[name], ddof=1))
        assert 0.5 < float(np.mean(reported[name])) / scatter < 2.0


def test_apply_offsets_subtracts_and_keeps_missing() -> None:
    rssi = np.array([[-60.0, np.nan, -70.0], [-50.0, -55.0, np.nan]], dtype=np.float32)
    out = apply_offsets(rssi, np.array([[6.0], [np.nan]]))
    assert out.dtype == np.float32
    np.testing.assert_array_equal(
        out, np.array([[-66.0, np.nan, -76.0], [-50.0, -55.0, np.nan]], dtype=np.float32)
    )
    assert apply_offsets([-60, -70], 2.0).tolist() == [-62.0, -72.0]
    fortran = np.asfortranarray(rssi)
    assert apply_offsets(fortran, 1.0).flags.f_contiguous  # column gathers stay fast
    with pytest.raises(ValueError, match="offset_db"):
        apply_offsets(rssi, np.zeros(5))


def test_matrix_helpers_feed_the_estimator() -> None:
    xy = np.array([[0.2, 0.3], [0.8, 0.1], [5.5, 0.0], [0.5, 0.5]])
    group = np.array([[0, 1], [0, 1], [0, 1], [0, 2]])
    cells = cell_ids(xy, group, 1.0)
    assert cells[0] == cells[1]
    assert len(set(cells.tolist())) == 3  # another cell; the same square on another floor
    rssi = np.array([[-50.0, np.nan], [np.nan, -60.0], [-70.0, -71.0], [np.nan, np.nan]])
    c, e, r, d = scan_readings(rssi, cells, ["p", "q", "p", "q"])
    assert e.tolist() == [0, 1, 0, 1]
    assert r.tolist() == [-50.0, -60.0, -70.0, -71.0]
    assert d.tolist() == ["p", "q", "p", "p"]
    assert c.tolist() == [cells[0], cells[1], cells[2], cells[2]]
    offsets = {"p": DeviceOffset(2.0, 30, 0.1)}
    np.testing.assert_array_equal(row_offsets(["p", "x", "p"], offsets), [2.0, np.nan, 2.0])


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"cell": np.zeros((2, 2), dtype=np.int64)}, "cell"),
        ({"cell": np.zeros(4)}, "cell"),
        ({"emitter": np.zeros(2, dtype=np.int64)}, "emitter"),
        ({"rssi_dbm": np.zeros(5)}, "rssi_dbm"),
        ({"device": ["a", "b"]}, "device"),
        ({"min_pairs": 0}, "min_pairs"),
        ({"min_rssi_dbm": float("nan")}, "min_rssi_dbm"),
    ],
)
def test_bad_input_names_the_argument(kwargs: dict[str, object], name: str) -> None:
    args: dict[str, object] = {
        "cell": np.zeros(4, dtype=np.int64),
        "emitter": np.zeros(4, dtype=np.int64),
        "rssi_dbm": np.full(4, -60.0),
        "device": ["a", "b", "a", "b"],
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        estimate_offsets(**args)  # type: ignore[arg-type]
