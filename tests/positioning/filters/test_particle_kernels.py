"""The compiled move ends, weight update and whole filter step (``particle_kernels``)
against their numpy references, on random inputs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.filters import particle_kernels
from server.positioning.filters.particle import step, step_on_floor
from server.positioning.filters.particle_cloud import ParticleParams, from_points
from server.positioning.filters.particle_move import move_ends_reference
from server.positioning.filters.particle_weight_update import (
    mass_centered_update,
    mass_centered_update_reference,
)
from server.positioning.magnetic.field_grid import MagneticGrid, _bilinear
from server.positioning.plan.floor_plan import valid_moves_reference
from tests.support.toy_plans import room


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_step_ends_match_the_numpy_move(seed: int) -> None:
    """Same float64 arithmetic; sin and cos may differ in the last bit between numpy and
    the compiled math library, so the float32 ends agree to one float32 step."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-500, 500, (1000, 2)).astype(np.float32).astype(np.float64)
    noise = rng.standard_normal((2, 1000))
    params = ParticleParams()
    got = particle_kernels.step_ends(a, noise, 0.7, 1.3, params.step_sd_m, params.heading_sd_rad)
    expected = move_ends_reference(a, noise, 0.7, 1.3, params)
    assert got.dtype == expected.dtype == np.float32
    np.testing.assert_array_max_ulp(got, expected, maxulp=1)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dead=st.sampled_from([0.0, 0.1]), count=st.integers(0, 4))
def test_mass_centered_weights_match_the_numpy_update(seed: int, dead: float, count: int) -> None:
    """Random clouds with dead particles and unknown map cells, windows filling up."""
    rng = np.random.default_rng(seed)
    params = ParticleParams(n=500, window=3)
    cloud = from_points(rng.uniform(0, 20, (500, 2)), 0, params.window)
    log_w = rng.normal(0, 1, 500)
    log_w[rng.random(500) < dead] = -np.inf
    mags = rng.uniform(30, 60, cloud.mags.shape).astype(np.float32)
    mags[rng.random(mags.shape) < 0.05] = np.nan
    cloud = replace(
        cloud,
        log_w=log_w.astype(np.float32),
        mags=mags,
        observed=rng.uniform(30, 60, 4).astype(np.float32),
        count=count,
    )

    def sample_map(_floor: object, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        m: NDArray[np.float64] = 40 + np.sin(xy[:, 0]) * 5
        m[xy[:, 1] > 18] = np.nan
        return m

    got = mass_centered_update(cloud, 44.0, sample_map, params)
    expected = mass_centered_update_reference(cloud, 44.0, sample_map, params)
    np.testing.assert_array_equal(got.mags, expected.mags)
    np.testing.assert_array_equal(got.observed, expected.observed)
    assert got.count == expected.count
    np.testing.assert_array_max_ulp(got.log_w, expected.log_w, maxulp=2)


def _grid(rng: np.random.Generator, unknown: float) -> MagneticGrid:
    """A field over the toy room (and a little beyond), some cells unknown."""
    ny, nx = 24, 44
    field = rng.uniform(30, 60, (ny, nx))
    field[rng.random((ny, nx)) < unknown] = np.nan
    return MagneticGrid(
        origin_m=(-1.0, -1.0),
        cell_m=0.5,
        magnitude=field.astype(np.float32),
        var=np.zeros((ny, nx), np.float32),
        count=np.ones((ny, nx), np.int32),
        horizontal=None,
        vertical=None,
    )


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    dead=st.sampled_from([0.0, 0.1, 1.0]),
    count=st.integers(0, 4),
    weigh=st.booleans(),
    maps=st.sampled_from(["both", "plan", "grid", "none"]),
    ess_fraction=st.sampled_from([0.5, 1.0]),
)
def test_step_on_floor_matches_the_numpy_filter_step(
    seed: int, dead: float, count: int, weigh: bool, maps: str, ess_fraction: float
) -> None:
    """The fused step against ``step`` with every part in numpy: random clouds in the toy
    room (dead particles, unknown map cells), steps long enough to meet the walls, with
    and without a plan, a map and a measured field, resampling or not."""
    rng = np.random.default_rng(seed)
    params = ParticleParams(n=600, window=3, resample_ess_fraction=ess_fraction)
    plan = room() if maps in ("both", "plan") else None
    grid = _grid(rng, 0.1) if maps in ("both", "grid") else None
    cloud = from_points(rng.uniform([0.2, 0.2], [19.8, 9.8], (600, 2)), 0, params.window)
    log_w = rng.normal(0, 1, 600)
    log_w[rng.random(600) < dead] = -np.inf
    mags = rng.uniform(30, 60, cloud.mags.shape).astype(np.float32)
    cloud = replace(
        cloud,
        log_w=log_w.astype(np.float32),
        mags=mags,
        observed=rng.uniform(30, 60, 4).astype(np.float32),
        count=count,
    )
    length, heading = float(rng.uniform(0.3, 2.5)), float(rng.uniform(-4, 4))
    observed = 44.0 if weigh else None

    def valid_move(_f: object, a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.bool_]:
        if plan is None:
            return np.asarray(np.isfinite(b).all(axis=1), dtype=np.bool_)
        return valid_moves_reference(plan, a, b)

    def sample_map(_f: object, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.full(len(xy), np.nan) if grid is None else _bilinear(grid, xy, "magnitude")

    expected = step(
        cloud, length, heading, observed, np.random.default_rng([seed, 1]), params,
        valid_move, sample_map, compiled=False,
    )  # fmt: skip
    got = step_on_floor(
        cloud, length, heading, observed, np.random.default_rng([seed, 1]), params, plan, grid
    )
    np.testing.assert_array_equal(got.xy, expected.xy)
    np.testing.assert_array_equal(got.floor, expected.floor)
    np.testing.assert_array_equal(got.mags, expected.mags)
    np.testing.assert_array_equal(got.observed, expected.observed)
    assert got.count == expected.count
    np.testing.assert_array_max_ulp(got.log_w, expected.log_w, maxulp=2)


def test_the_cache_is_dropped_when_a_called_kernel_s_file_changes(tmp_path: Path) -> None:
    """numba checks a cached kernel against its own file only; the stamp of the files whose
    kernels these call catches an edit of them."""
    callees = (tmp_path / "move_test_kernels.py", tmp_path / "magnetic_kernels.py")
    for f in callees:
        f.write_text("# kernels\n")
    stamps = tmp_path / "cache"
    assert particle_kernels.drop_stale_caches(callees, stamps)  # no stamp yet
    assert not particle_kernels.drop_stale_caches(callees, stamps)
    callees[1].write_text("# kernels, edited\n")
    assert particle_kernels.drop_stale_caches(callees, stamps)
    assert not particle_kernels.drop_stale_caches(callees, stamps)
