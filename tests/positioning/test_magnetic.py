"""Magnetic grids and sequence distances: statistics by hand, bilinear exactness, DTW."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.magnetic import (
    MagneticGrid,
    MagneticSamples,
    dtw_distance,
    grid_from_samples,
    grid_from_sources,
    merge_grids,
    mmse,
    sample,
    sample_many,
    samples_along_line,
)

NAN = float("nan")


def test_gridding_by_hand() -> None:
    # cells of 1 m over [0, 3) x [0, 2): three samples in (0, 0), one in (1, 2)
    xy = [(0.2, 0.2), (0.7, 0.4), (0.5, 0.9), (2.5, 1.5)]
    g = grid_from_samples(
        xy,
        [40.0, 42.0, 47.0, 50.0],
        horizontal=[20.0, NAN, 24.0, NAN],
        cell_m=1.0,
        extent=(0.0, 0.0, 3.0, 2.0),
    )
    assert g.origin_m == (0.0, 0.0)
    assert g.cell_m == 1.0
    assert g.count.tolist() == [[3, 0, 0], [0, 0, 1]]
    np.testing.assert_array_equal(g.magnitude, [[43.0, NAN, NAN], [NAN, NAN, 50.0]])
    # (9 + 1 + 16) / 2 = 13; a single sample has no variance
    np.testing.assert_array_equal(g.var, [[13.0, NAN, NAN], [NAN, NAN, NAN]])
    assert g.horizontal is not None
    np.testing.assert_array_equal(g.horizontal, [[22.0, NAN, NAN], [NAN, NAN, NAN]])
    assert g.vertical is None
    assert not np.any(g.magnitude == 0.0)
    assert g.magnitude.dtype == np.float32
    assert g.var.dtype == np.float32
    assert g.count.dtype == np.int32
    assert not g.magnitude.flags.writeable


def test_min_count_and_samples_outside_the_extent() -> None:
    g = grid_from_samples(
        [(0.1, 0.1), (0.2, 0.2), (1.2, 0.2), (5.0, 0.2), (-0.1, 0.2)],
        [40.0, 44.0, 50.0, 60.0, 70.0],
        cell_m=1.0,
        extent=(0.0, 0.0, 2.0, 1.0),
        min_count=2,
    )
    assert g.count.tolist() == [[2, 1]]  # the two samples outside are not counted
    np.testing.assert_array_equal(g.magnitude, [[42.0, NAN]])
    np.testing.assert_array_equal(g.var, [[8.0, NAN]])


def test_derived_extent_is_on_the_cell_lattice_with_a_margin() -> None:
    g = grid_from_samples([(1.3, 2.1), (2.6, 2.4)], [45.0, 46.0])
    assert g.origin_m == (0.5, 1.5)
    # rows: the cell [2.0, 2.5) plus margins; columns: [1.0, 3.0) plus margins
    assert g.magnitude.shape == (3, 6)
    assert g.count.sum() == 2
    assert g.count[1, 1] == 1
    assert g.count[1, 4] == 1


def test_variance_is_stable_on_a_large_mean() -> None:
    rng = np.random.default_rng(3)
    values = 1e6 + rng.normal(0.0, 0.1, size=200)
    g = grid_from_samples(np.full((200, 2), 0.25), values, extent=(0.0, 0.0, 0.5, 0.5))
    assert g.var[0, 0] == pytest.approx(np.var(values, ddof=1), rel=1e-4)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_gridding_is_order_independent(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 3.0, size=(40, 2))
    mag = rng.normal(45.0, 3.0, size=40)
    extent = (0.0, 0.0, 3.0, 3.0)
    a = grid_from_samples(xy, mag, extent=extent)
    p = rng.permutation(40)
    b = grid_from_samples(xy[p], mag[p], extent=extent)
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_allclose(a.magnitude, b.magnitude, rtol=1e-6)
    np.testing.assert_allclose(a.var, b.var, rtol=1e-4, atol=1e-6)


def _grid_parts(seed: int, n_parts: int) -> tuple[MagneticGrid, list[MagneticGrid]]:
    rng = np.random.default_rng(seed)
    n = 200
    xy = rng.uniform(-3.0, 6.0, (n, 2))
    mag = rng.normal(48.0, 3.0, n)
    horizontal = np.where(rng.random(n) < 0.5, rng.normal(20.0, 2.0, n), np.nan)
    whole = grid_from_samples(xy, mag, horizontal=horizontal)
    cuts = np.sort(rng.choice(np.arange(1, n), n_parts - 1, replace=False))
    parts = [
        grid_from_samples(xy[i], mag[i], horizontal=horizontal[i])
        for i in np.split(rng.permutation(n), cuts)
    ]
    return whole, parts


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_parts=st.integers(2, 5))
def test_merged_parts_equal_the_grid_of_all_samples(seed: int, n_parts: int) -> None:
    whole, parts = _grid_parts(seed, n_parts)
    merged = parts[0]
    for part in parts[1:]:
        merged = merge_grids(merged, part)
    assert merged.origin_m == pytest.approx(whole.origin_m)
    assert merged.magnitude.shape == whole.magnitude.shape
    np.testing.assert_array_equal(merged.count, whole.count)
    np.testing.assert_allclose(merged.magnitude, whole.magnitude, rtol=1e-5, equal_nan=True)
    np.testing.assert_allclose(merged.var, whole.var, rtol=1e-3, atol=1e-4, equal_nan=True)
    assert merged.horizontal is not None
    assert whole.horizontal is not None
    # components merge by magnitude counts: equal to the whole where each part's cell
    # had the component on all or none of its samples; always finite where the whole is
    assert np.array_equal(np.isfinite(merged.horizontal), np.isfinite(whole.horizontal))


def test_merge_is_order_independent_and_refuses_other_lattices() -> None:
    _, (a, b, c) = _grid_parts(7, 3)
    left = merge_grids(merge_grids(a, b), c)
    right = merge_grids(c, merge_grids(b, a))
    np.testing.assert_allclose(left.magnitude, right.magnitude, rtol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(left.count, right.count)
    shifted = grid_from_samples([(0.1, 0.1)], [50.0], extent=(0.25, 0.0, 2.25, 2.0))
    with pytest.raises(ValueError, match="lattice"):
        merge_grids(a, shifted)
    coarse = grid_from_samples([(0.1, 0.1)], [50.0], cell_m=1.0)
    with pytest.raises(ValueError, match="cell sizes"):
        merge_grids(a, coarse)


def test_sources_are_gridded_together() -> None:
    points = MagneticSamples(xy=[(0.1, 0.1)], magnitude=[40.0], vertical=[30.0])
    line = MagneticSamples(xy=[(0.2, 0.2), (0.8, 0.3)], magnitude=[42.0, 50.0])
    g = grid_from_sources([points, line], cell_m=0.5, extent=(0.0, 0.0, 1.0, 0.5))
    direct = grid_from_samples(
        [(0.1, 0.1), (0.2, 0.2), (0.8, 0.3)],
        [40.0, 42.0, 50.0],
        vertical=[30.0, NAN, NAN],
        cell_m=0.5,
        extent=(0.0, 0.0, 1.0, 0.5),
    )
    for field in ("magnitude", "var", "count", "vertical"):
        np.testing.assert_array_equal(getattr(g, field), getattr(direct, field))
    assert g.horizontal is None
    assert g.count.tolist() == [[2, 1]]
    np.testing.assert_array_equal(g.var, [[2.0, NAN]])
    with pytest.raises(ValueError, match=r"sources\[1\].magnitude must have shape \(2,\)"):
        grid_from_sources([points, MagneticSamples(xy=[(0, 0), (1, 0)], magnitude=[40.0])])
    with pytest.raises(ValueError, match="extent is required"):
        grid_from_sources([])


def test_bad_samples_are_refused() -> None:
    with pytest.raises(ValueError, match="magnitude must be finite"):
        grid_from_samples([(0.0, 0.0)], [NAN])
    with pytest.raises(ValueError, match="xy must have shape"):
        grid_from_samples([0.0, 0.0], [40.0])
    with pytest.raises(ValueError, match="extent must be"):
        grid_from_samples([(0.0, 0.0)], [40.0], extent=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="min_count"):
        grid_from_samples([(0.0, 0.0)], [40.0], min_count=0)


def _plane_grid(nx: int = 6, ny: int = 5) -> tuple[MagneticGrid, tuple[float, float, float]]:
    """A grid whose cell means lie on the plane a + b x + c y (one sample per centre)."""
    a, b, c = 45.0, 1.5, -0.75
    origin = (10.0, -3.0)
    cols, rows = np.meshgrid(np.arange(nx), np.arange(ny))
    centres = np.column_stack(
        [origin[0] + (cols.ravel() + 0.5) * 0.5, origin[1] + (rows.ravel() + 0.5) * 0.5]
    )
    g = grid_from_samples(
        centres,
        a + b * centres[:, 0] + c * centres[:, 1],
        extent=(origin[0], origin[1], origin[0] + nx * 0.5, origin[1] + ny * 0.5),
    )
    return g, (a, b, c)


def test_bilinear_sampling_is_exact_on_a_plane() -> None:
    g, (a, b, c) = _plane_grid()
    rng = np.random.default_rng(0)
    # anywhere between the outermost centres, including the centres themselves
    xy = np.column_stack([rng.uniform(10.25, 12.75, 500), rng.uniform(-2.75, -0.75, 500)])
    xy = np.vstack([xy, [(10.25, -2.75), (12.75, -0.75), (12.75, -2.75)]])
    np.testing.assert_allclose(sample(g, xy), a + b * xy[:, 0] + c * xy[:, 1], rtol=1e-6)


def test_sampling_is_nan_outside_and_renormalised_next_to_unknown_cells() -> None:
    g, (a, b, c) = _plane_grid()
    inf = float("inf")
    outside = [(9.9, -2.0), (13.1, -2.0), (11.0, -3.1), (11.0, -0.4), (NAN, -2.0), (inf, -2.0)]
    outside += [(-inf, -2.0), (11.0, inf), (1e300, -1e300)]
    assert np.all(np.isnan(sample(g, outside)))
    # between the outermost centres and the grid's edge: the edge centres' values
    edge = sample(g, [(10.1, -2.0), (12.9, -0.6)])
    np.testing.assert_allclose(edge, [a + b * 10.25 + c * -2.0, a + b * 12.75 + c * -0.75])
    holed = grid_from_samples(
        [(0.25, 0.25), (0.75, 0.25), (1.25, 0.25), (0.25, 0.75), (0.75, 0.75)],
        [40.0, 41.0, 42.0, 43.0, 44.0],
        extent=(0.0, 0.0, 1.5, 1.0),
    )  # cell (row 1, col 2) unknown
    values = sample(holed, [(0.5, 0.5), (1.0, 0.5), (1.25, 0.75), (1.0, 0.25), (1.2, 0.7)])
    assert values[0] == pytest.approx((40.0 + 41.0 + 43.0 + 44.0) / 4)
    assert values[1] == pytest.approx((41.0 + 42.0 + 44.0) / 3)  # three known corners
    assert np.isnan(values[2])  # the centre of the unknown cell
    assert values[3] == pytest.approx(41.5)  # on the boundary row: two corners of weight
    assert 41.0 < values[4] < 44.0


def test_a_single_walked_line_can_be_sampled_along_its_width() -> None:
    xs = np.linspace(0.0, 10.0, 101)
    g = grid_from_samples(np.column_stack([xs, np.full(101, 2.0)]), 40.0 + xs)
    # the line fills one row of cells (centres at y = 2.25); closer to that row of centres
    # than to the next rows (y = 1.75, 2.75), a point samples the line's field
    for y in (1.76, 2.0, 2.24, 2.49):
        got = sample(g, np.column_stack([xs[5:-5], np.full(91, y)]))
        np.testing.assert_allclose(got, 40.0 + xs[5:-5], atol=0.3)
    assert np.all(np.isnan(sample(g, [(5.0, 1.2), (5.0, 2.8)])))


def test_sample_many_matches_sample_and_components() -> None:
    g, _ = _plane_grid()
    rng = np.random.default_rng(1)
    xy = np.stack([rng.uniform(10.0, 13.0, (7, 4)), rng.uniform(-3.0, -0.5, (7, 4))], axis=-1)
    many = sample_many(g, xy)
    assert many.shape == (7, 4)
    np.testing.assert_array_equal(many, sample(g, xy.reshape(-1, 2)).reshape(7, 4))
    with pytest.raises(ValueError, match="no horizontal component"):
        sample(g, [(11.0, -2.0)], component="horizontal")
    h = grid_from_samples(
        [(0.25, 0.25), (0.75, 0.25)], [40.0, 42.0], horizontal=[20.0, 22.0], extent=(0, 0, 1, 0.5)
    )
    assert sample(h, [(0.5, 0.25)], component="horizontal")[0] == pytest.approx(21.0)


def test_samples_along_line_by_hand() -> None:
    xy, values = samples_along_line(
        (0.0, 0.0),
        (4.0, 2.0),
        1000.0,
        3000.0,
        [900.0, 1000.0, 1500.0, 2500.0, 3000.0, 3100.0],
        [[40.0, 1.0], [41.0, 2.0], [42.0, 3.0], [43.0, 4.0], [44.0, 5.0], [45.0, 6.0]],
    )
    np.testing.assert_allclose(xy, [(0.0, 0.0), (1.0, 0.5), (3.0, 1.5), (4.0, 2.0)])
    np.testing.assert_array_equal(values, [[41.0, 2.0], [42.0, 3.0], [43.0, 4.0], [44.0, 5.0]])
    with pytest.raises(ValueError, match="t_end_ms must be after"):
        samples_along_line((0, 0), (1, 0), 5.0, 5.0, [5.0], [40.0])


def _reference_dtw(a: list[float], b: list[float]) -> float:
    D = [[math.inf] * (len(b) + 1) for _ in range(len(a) + 1)]
    D[0][0] = 0.0
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            D[i][j] = abs(a[i - 1] - b[j - 1]) + min(D[i - 1][j], D[i][j - 1], D[i - 1][j - 1])
    return D[len(a)][len(b)]


values_ut = st.floats(20.0, 70.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    observed=st.lists(values_ut, min_size=1, max_size=7),
    m=st.integers(1, 7),
    n=st.integers(1, 5),
    data=st.data(),
)
def test_dtw_equals_the_reference(
    observed: list[float], m: int, n: int, data: st.DataObject
) -> None:
    rows = [data.draw(st.lists(values_ut, min_size=m, max_size=m)) for _ in range(n)]
    got = dtw_distance(observed, rows)
    assert got.shape == (n,)
    np.testing.assert_allclose(got, [_reference_dtw(observed, r) for r in rows], rtol=1e-12)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), w=st.integers(1, 8))
def test_dtw_is_zero_on_itself_and_at_most_l1(seed: int, w: int) -> None:
    rng = np.random.default_rng(seed)
    observed = rng.normal(45.0, 5.0, w)
    candidates = np.vstack([observed, rng.normal(45.0, 5.0, (20, w))])
    d = dtw_distance(observed, candidates)
    assert d[0] == 0.0
    l1 = np.abs(candidates - observed).sum(axis=1)
    assert np.all(d <= l1 + 1e-9)


def test_dtw_handles_a_time_shift_better_than_l1() -> None:
    observed = np.array([40.0, 40.0, 44.0, 48.0, 52.0, 52.0])
    shifted = np.array([40.0, 44.0, 48.0, 52.0, 52.0, 52.0])  # one sample earlier
    l1 = np.abs(shifted - observed).sum()
    assert l1 == 12.0
    assert dtw_distance(observed, shifted[None, :])[0] == 0.0


def test_nan_rows_give_inf() -> None:
    observed = [40.0, 42.0, 41.0, 45.0]
    candidates = np.array([[40.0, 42.0, 41.0, 45.0], [40.0, NAN, 41.0, 45.0], [NAN] * 4])
    np.testing.assert_array_equal(dtw_distance(observed, candidates), [0.0, np.inf, np.inf])
    np.testing.assert_array_equal(mmse(observed, candidates), [0.0, np.inf, np.inf])
    with pytest.raises(ValueError, match="observed must be finite"):
        dtw_distance([40.0, NAN], candidates[:, :2])


def test_mmse_by_hand() -> None:
    observed = [40.0, 42.0, 41.0, 45.0]  # |Δ| = 2, 1, 4
    candidates = [
        [50.0, 52.0, 51.0, 55.0],  # offset by 10 µT: same changes, error 0
        [40.0, 40.0, 40.0, 40.0],  # |Δ| = 0, 0, 0 -> (2 + 1 + 4) / 3
        [45.0, 42.0, 40.0, 40.0],  # |Δ| = 3, 2, 0 -> (1 + 1 + 4) / 3
        [40.0, 38.0, 39.0, 35.0],  # mirrored changes have the same |Δ|
    ]
    np.testing.assert_allclose(mmse(observed, candidates), [0.0, 7.0 / 3.0, 2.0, 0.0])
    with pytest.raises(ValueError, match="candidates must have shape"):
        mmse(observed, [[40.0, 41.0, 42.0]])
    with pytest.raises(ValueError, match="at least two"):
        mmse([40.0], [[40.0]])


def _paper_window(rng: np.random.Generator, n: int) -> tuple[NDArray[np.float64], ...]:
    return rng.normal(45.0, 5.0, 4), rng.normal(45.0, 5.0, (n, 4))


def test_distances_rank_the_true_sequence_first() -> None:
    rng = np.random.default_rng(5)
    observed, candidates = _paper_window(rng, 3000)
    candidates[1234] = observed + 3.0  # a calibration offset: DTW sees it, eq (b) does not
    assert int(np.argmin(mmse(observed, candidates))) == 1234
    candidates[1234] = observed
    assert int(np.argmin(dtw_distance(observed, candidates))) == 1234
