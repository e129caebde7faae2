"""Gridding magnetic samples: statistics by hand, order independence, merging, walked lines."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.mapping.magnetic_gridding import (
    MagneticSamples,
    grid_from_samples,
    grid_from_sources,
    merge_grids,
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
