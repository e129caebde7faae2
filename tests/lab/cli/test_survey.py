"""``indoorpos plan-survey``: a floor's placement plan from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lab.datasets.ilc import read_site
from server.cli.main import app
from server.positioning.plan.floor_plan import walkable_at
from server.positioning.plan.geojson_plan import plan_from_geojson
from tests.support.datasets import DATA_DIR

SITE2 = DATA_DIR / "ilc20-sample" / "site2"


@pytest.mark.skipif(not SITE2.is_dir(), reason="../shared/data is not beside the project")
def test_plan_of_an_ilc_floor_is_drawn_and_lies_in_walkable_space(tmp_path: Path) -> None:
    out = tmp_path / "plan.geojson"
    result = CliRunner().invoke(
        app,
        [
            "plan-survey",
            "ilc",
            str(SITE2 / "F8"),
            "--floor",
            "F8",
            "--json",
            str(out),
            "--plots",
            str(tmp_path),
        ],
    )
    assert result.exit_code == 0, result.output
    assert (tmp_path / "survey_plan_F8.png").stat().st_size > 10_000
    body = json.loads(out.read_text())
    xy = np.array([f["geometry"]["coordinates"] for f in body["features"]])
    assert xy.shape[0] == body["properties"]["n_points"] > 50
    geojson = read_site(SITE2 / "F8").floors[0].plan
    assert geojson is not None
    plan = plan_from_geojson(geojson)
    assert walkable_at(plan, xy).all()
    assert body["properties"]["noise_source"] == "map"
    assert body["properties"]["n_access_points"] > 0


def test_unknown_floor_names_the_field(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("INDOORPOS_DATA_DIR", str(tmp_path))  # the embedded database, if used
    result = CliRunner().invoke(app, ["plan-survey", "floor", "0" * 32])
    assert result.exit_code == 1
    assert "floor_id" in result.output
