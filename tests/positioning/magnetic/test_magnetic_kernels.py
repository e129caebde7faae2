"""The compiled map sampling and sequence distances (``magnetic_kernels``) against their
numpy references, on random inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.magnetic import magnetic_kernels
from server.positioning.magnetic.field_grid import MIN_CORNER_WEIGHT, MagneticGrid, _bilinear
from server.positioning.magnetic.sequence_distance import dtw_distance, mmse


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_bilinear_matches_the_numpy_sampling(seed: int) -> None:
    rng = np.random.default_rng(seed)
    ny, nx = rng.integers(1, 12, 2)
    field = rng.uniform(20, 60, (ny, nx))
    field[rng.random((ny, nx)) < 0.3] = np.nan  # unknown cells
    grid = MagneticGrid(
        origin_m=(1.0, -2.0),
        cell_m=0.5,
        magnitude=field.astype(np.float32),
        var=np.zeros((ny, nx), np.float32),
        count=np.ones((ny, nx), np.int32),
        horizontal=None,
        vertical=None,
    )
    pts = rng.uniform([0, -3], [1 + 0.5 * nx + 1, -2 + 0.5 * ny + 1], (300, 2))
    filled, known = grid.sampling_arrays("magnitude")
    got = magnetic_kernels.bilinear(
        pts, 1.0, -2.0, 0.5, int(nx), int(ny), filled, known, MIN_CORNER_WEIGHT
    )
    np.testing.assert_allclose(got, _bilinear(grid, pts, "magnitude"), rtol=0, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), w=st.integers(2, 6))
def test_mmse_matches_eq_b(seed: int, w: int) -> None:
    rng = np.random.default_rng(seed)
    obs = rng.uniform(30, 60, w)
    cand = rng.uniform(30, 60, (200, w))
    cand[rng.random((200, w)) < 0.05] = np.nan
    np.testing.assert_allclose(magnetic_kernels.mmse(obs, cand), mmse(obs, cand), rtol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), w=st.integers(1, 12), m=st.integers(1, 12))
def test_dtw_matches_the_numpy_distance(seed: int, w: int, m: int) -> None:
    rng = np.random.default_rng(seed)
    obs = rng.uniform(30, 60, w)
    cand = rng.uniform(30, 60, (100, m))
    cand[rng.random((100, m)) < 0.02] = np.nan
    np.testing.assert_allclose(magnetic_kernels.dtw(obs, cand), dtw_distance(obs, cand), rtol=1e-12)
