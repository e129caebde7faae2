"""Figures on a floor's plan are written as PNG files of the expected size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from lab.floor_plots import plot_magnetic_grid
from server.positioning.mapping.magnetic_gridding import grid_from_samples
from tests.support.figures import PLAN, assert_png, walk


def test_magnetic_grid_on_a_plan_is_written(tmp_path: Path) -> None:
    _, est = walk()
    rng = np.random.default_rng(2)
    grid = grid_from_samples(
        est, rng.normal(48.0, 3.0, len(est)), extent=(0.0, 0.0, 30.0, 20.0)
    )  # a few known cells along the walk, the rest unknown (NaN)
    out = plot_magnetic_grid(
        tmp_path / "magnetic_F1.png", title="F1: 1% known", plan=PLAN, grid=grid
    )
    assert_png(out, 8.0, 6.0)
    empty = grid_from_samples(np.zeros((0, 2)), np.zeros(0), extent=(0.0, 0.0, 3.0, 2.0))
    assert_png(
        plot_magnetic_grid(tmp_path / "unknown.png", title="", plan=None, grid=empty), 8.0, 6.0
    )
