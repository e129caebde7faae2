"""Sampling magnetic grids: bilinear exactness on a plane, unknown cells, edges."""

from __future__ import annotations

import numpy as np
import pytest

from server.positioning.magnetic.field_grid import MagneticGrid, sample, sample_many
from server.positioning.mapping.magnetic_gridding import grid_from_samples

NAN = float("nan")


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
