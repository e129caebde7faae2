"""Figures of evaluations are written as PNG files of the expected size, without pyplot
state."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from lab.datasets.ilc import read_site
from lab.evaluation_plots import (
    plot_error_cdf,
    plot_reliability,
    plot_track,
    write_ilc_plots,
)
from lab.ilc_evaluation import IlcEvaluation
from lab.scoring import summarize
from lab.split import split_site
from lab.training_maps import build_site_maps
from server.positioning.mapping import map_set
from tests.support.figures import PLAN, assert_png, walk

SITE2 = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ilc20-sample" / "site2"
needs_data = pytest.mark.skipif(
    not SITE2.is_dir(), reason="../shared/data is not beside the project"
)


def test_error_cdf_is_written(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    out = plot_error_cdf(
        {
            "wknn": np.abs(rng.normal(0.0, 4.0, 300)).tolist(),
            "step_ekf": [*np.abs(rng.normal(0.0, 2.0, 300)).tolist(), float("nan")],
            "nothing": [],
        },
        tmp_path / "figures" / "cdf.png",
        title="horizontal error",
    )
    assert out == tmp_path / "figures" / "cdf.png"
    assert_png(out, 7.0, 4.5)


def test_track_with_a_plan_is_written(tmp_path: Path) -> None:
    truth, est = walk()
    floor_ok = np.ones(len(est), dtype=bool)
    floor_ok[5:9] = False
    sigma = np.full(len(est), 1.5)
    sigma[0] = np.nan
    out = plot_track(
        tmp_path / "wknn" / "F1_path.png",
        title="wknn · F1 · path",
        plan=PLAN,
        truth_xy_m=truth,
        est_xy_m=est,
        est_floor_ok=floor_ok,
        waypoint_xy_m=truth,
        sigma_m=sigma,
    )
    assert_png(out, 8.0, 6.0)


def test_track_without_plan_or_estimates_is_written(tmp_path: Path) -> None:
    truth, _ = walk()
    out = plot_track(
        tmp_path / "empty.png",
        title="no fixes",
        plan=None,
        truth_xy_m=truth,
        est_xy_m=np.zeros((0, 2)),
        est_floor_ok=np.zeros(0, dtype=bool),
        sigma_m=np.zeros(0),
    )
    assert_png(out, 8.0, 6.0)


def test_track_refuses_mismatched_arrays(tmp_path: Path) -> None:
    truth, est = walk()
    with pytest.raises(ValueError, match="est_floor_ok"):
        plot_track(
            tmp_path / "x.png",
            title="",
            plan=None,
            truth_xy_m=truth,
            est_xy_m=est,
            est_floor_ok=[True],
        )
    with pytest.raises(ValueError, match="est_xy_m"):
        plot_track(tmp_path / "x.png", title="", plan=None, truth_xy_m=truth, est_xy_m=[1, 2, 3])


def test_many_figures_leave_no_pyplot_figures(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    truth, est = walk()
    for i in range(20):
        plot_track(tmp_path / f"{i}.png", title="", plan=PLAN, truth_xy_m=truth, est_xy_m=est)
        plot_error_cdf({"a": [1.0, 2.0]}, tmp_path / f"cdf{i}.png", title="")
    assert plt.get_fignums() == []


def test_missing_matplotlib_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(RuntimeError, match=r"indoorpos-lab\[plots\]"):
        plot_error_cdf({"a": [1.0]}, tmp_path / "cdf.png", title="")
    assert not (tmp_path / "cdf.png").exists()


@needs_data
def test_magnetic_maps_are_drawn_per_floor(tmp_path: Path) -> None:
    site = read_site(SITE2 / "F4")
    split = split_site(site, 0, 0.8)
    maps, _, _ = build_site_maps(site, split.train[:4], parts={map_set.FIX_ERROR, map_set.MAGNETIC})
    summary = summarize([], floor_names=["F4"], maps=maps, engine="pf_magnetic")
    coverage = summary["per_floor"]["F4"]["magnetic_coverage"]
    assert 0.0 < coverage < 1.0  # four walks cover some of the corridors
    run = IlcEvaluation(site, maps, split, (), summary)
    written = write_ilc_plots([run], tmp_path)
    assert written[2:] == [tmp_path / "magnetic_F4.png"]
    assert written[2].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_reliability_plot_draws_each_engine(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    sigma = rng.uniform(1.0, 5.0, 400)
    calibrated = np.hypot(*(rng.normal(0.0, 1.0, (2, 400)) * sigma))
    out = plot_reliability(
        {
            "calibrated": (calibrated.tolist(), sigma.tolist()),
            "bold": ([9.0] * 400, sigma.tolist()),
        },
        tmp_path / "reliability.png",
        title="t",
    )
    png = out.read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(png) > 10_000
