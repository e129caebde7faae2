"""The harness's commands under ``indoorpos`` (the ``indoorpos.commands`` entry point of
this distribution): ``demo`` and ``simulate`` (the simulator against the service),
``evaluate`` (recorded datasets through the engines), ``bench`` (the particle filter, the
map build, the service under load) and ``plan-survey``; ``reports`` holds their progress
bars and tables, ``embedded`` the service some of them run in this process."""

from __future__ import annotations

import typer

from lab.cli import bench, evaluate, simulate, survey


def register(app: typer.Typer) -> None:
    """Add the harness's commands to the service's ``indoorpos`` command."""
    app.command()(simulate.demo)
    app.command()(simulate.simulate)
    app.add_typer(evaluate.evaluate_app, name="evaluate")
    app.add_typer(bench.bench_app, name="bench")
    app.add_typer(survey.plan_survey_app, name="plan-survey")
