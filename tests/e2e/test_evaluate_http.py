"""`indoorpos evaluate ilc --via-http` gives the figures of the in-process replay."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from server.cli.main import app
from server.positioning.radio.fix_error import DEFAULT_ERROR_68_M
from tests.support.admin_key import ADMIN_KEY

# each comparison runs once in `make test`: those through the api in the production shape
# (PostgreSQL + Redis), the crowd maps (built in process) on the embedded defaults
PRODUCTION = bool(os.environ.get("INDOORPOS_REDIS_URL"))
production_pass = pytest.mark.skipif(
    not PRODUCTION, reason="runs in the pass on PostgreSQL + Redis (INDOORPOS_REDIS_URL)"
)
embedded_pass = pytest.mark.skipif(PRODUCTION, reason="runs in the pass on the embedded defaults")

FLOOR = (
    Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ilc20-sample" / "site2" / "F4"
)


@production_pass
@pytest.mark.skipif(not FLOOR.is_dir(), reason="../shared/data is not beside the project")
def test_same_figures_through_the_api(worker_live_url: str, tmp_path: Path) -> None:
    """The service builds the maps the lab builds (its worker's fix-error table gives the
    radii), and its sessions draw the in-process random stream: every figure is equal,
    the particle filter's included."""
    runner = CliRunner()
    engines = ["wknn", "step_ekf", "pf_magnetic"]
    args = ["evaluate", "ilc", str(FLOOR), *(a for e in engines for a in ("--engine", e))]
    local = runner.invoke(app, [*args, "--json", str(tmp_path / "local.json")])
    assert local.exit_code == 0, local.output
    remote = runner.invoke(
        app,
        [
            *args,
            "--json",
            str(tmp_path / "http.json"),
            "--via-http",
            worker_live_url,
            "--admin-key",
            ADMIN_KEY,
        ],
    )
    assert remote.exit_code == 0, remote.output
    here = json.loads((tmp_path / "local.json").read_text())["runs"]
    there = json.loads((tmp_path / "http.json").read_text())["runs"]
    assert [r["engine"] for r in there] == engines
    for a, b in zip(here, there, strict=True):
        assert a["n_points"] > 0
        for key in ("n_points", "n_missing", "floor_hit_rate", "within_68", "within_95"):
            assert a[key] == b[key], (a["engine"], key)
        for key in ("mean_m", "p50_m", "p90_m", "max_m"):
            assert b[key] == pytest.approx(a[key], rel=1e-6), (a["engine"], key)
    # the radii come from the floor's learned fix-error table, far from the default's
    assert abs(here[0]["radio_error_68_m"] - DEFAULT_ERROR_68_M) > 5.0
    for engine in engines:
        ours = (tmp_path / f"local.{engine}.points.csv").read_text().splitlines()
        theirs = (tmp_path / f"http.{engine}.points.csv").read_text().splitlines()
        assert ours == theirs, engine  # every estimate, σ and 68 / 95 % radius


@embedded_pass
@pytest.mark.skipif(not FLOOR.is_dir(), reason="../shared/data is not beside the project")
def test_crowd_maps_come_close_to_the_survey_maps(tmp_path: Path) -> None:
    """The training walks go through the upload API keeping only their first and last
    waypoint; the service's worker places them by their steps and builds the maps."""
    runner = CliRunner()
    args = ["evaluate", "ilc", str(FLOOR), "--engine", "wknn", "--json"]
    survey = runner.invoke(app, [*args, str(tmp_path / "survey.json")])
    crowd = runner.invoke(app, [*args, str(tmp_path / "crowd.json"), "--map-source", "crowd"])
    assert survey.exit_code == 0, survey.output
    assert crowd.exit_code == 0, crowd.output
    a = json.loads((tmp_path / "survey.json").read_text())
    b = json.loads((tmp_path / "crowd.json").read_text())
    assert b["map_source"] == "crowd"
    statuses = b["uploads"]["status"]
    assert sum(statuses.values()) == a["train_paths"]
    assert statuses.get("done", 0) >= 0.8 * a["train_paths"]
    assert b["n_points"] == a["n_points"]
    assert b["mean_m"] < 1.6 * a["mean_m"]


@production_pass
@pytest.mark.skipif(not FLOOR.is_dir(), reason="../shared/data is not beside the project")
def test_a_parameter_reaches_the_sessions(worker_live_url: str, tmp_path: Path) -> None:
    """``--param`` with ``--via-http`` opens the sessions with those parameters: the same
    figures as the in-process replay with them, not those of the defaults."""
    runner = CliRunner()
    base = ["evaluate", "ilc", str(FLOOR), "--engine", "wknn", "--json"]
    runs = {
        "default": [*base, str(tmp_path / "default.json")],
        "local": [*base, str(tmp_path / "local.json"), "--param", "scan_k=1"],
        "http": [
            *base,
            str(tmp_path / "http.json"),
            "--param",
            "scan_k=1",
            "--via-http",
            worker_live_url,
            "--admin-key",
            ADMIN_KEY,
        ],
    }
    out = {}
    for name, args in runs.items():
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    assert out["http"]["mean_m"] == pytest.approx(out["local"]["mean_m"], rel=1e-6)
    assert out["http"]["mean_m"] != pytest.approx(out["default"]["mean_m"], rel=1e-3)
    refused = runner.invoke(app, [*base, str(tmp_path / "x.json"), "--param", "scan_k=0"])
    assert refused.exit_code != 0
    assert "scan_k: must be at least 1" in refused.output
